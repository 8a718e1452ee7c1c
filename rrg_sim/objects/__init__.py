"""The paper's 10 objects as composites of collision primitives, with goal regions and WRTs."""

from rrg_sim.objects.object_model import GoalRegion, ObjectModel

from .catalogue import OBJECT_NAMES, get_object
from .primitives import Primitive, signed_distance, union_bounds

__all__ = [
    "OBJECT_NAMES",
    "GoalRegion",
    "ObjectModel",
    "Primitive",
    "get_object",
    "signed_distance",
    "union_bounds",
]
