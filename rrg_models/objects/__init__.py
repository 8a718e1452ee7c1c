"""The objects: folders of data (object.toml, measured studies) read into ObjectModels, the
paper's ten built in and the user's own (rrg_models.objects.catalogue)."""

from rrg_models.goal import GoalRegion
from rrg_models.objects.catalogue import (
    PAPER_OBJECTS,
    get_object,
    object_folders,
    object_names,
    unknown_object_message,
    user_objects_dir,
)
from rrg_models.objects.object_file import ObjectFileError, load_object_folder
from rrg_models.objects.object_model import ObjectModel
from rrg_models.objects.primitives import Primitive, signed_distance, union_bounds

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
