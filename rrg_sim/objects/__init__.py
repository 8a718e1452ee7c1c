"""The objects: folders of data (object.toml, measured studies) read into ObjectModels, the
paper's ten built in and the user's own (rrg_sim.objects.catalogue)."""

from rrg_sim.goal import GoalRegion
from rrg_sim.objects.object_model import ObjectModel

from .catalogue import (
    PAPER_OBJECTS,
    get_object,
    object_folders,
    object_names,
    unknown_object_message,
    user_objects_dir,
)
from .object_file import ObjectFileError, load_object_folder
from .primitives import Primitive, signed_distance, union_bounds

__all__ = [
    "PAPER_OBJECTS",
    "GoalRegion",
    "ObjectFileError",
    "ObjectModel",
    "Primitive",
    "get_object",
    "load_object_folder",
    "object_folders",
    "object_names",
    "signed_distance",
    "union_bounds",
    "unknown_object_message",
    "user_objects_dir",
]
