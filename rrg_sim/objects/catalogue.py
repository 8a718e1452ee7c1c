"""The catalogue of the paper's 10 objects: ``OBJECT_NAMES`` and ``get_object``."""

from __future__ import annotations

from functools import cache

from rrg_sim.objects.object_model import ObjectModel

from .shapes import BUILDERS

#: The paper's objects (Fig. 5 and 6), in the paper's order.
OBJECT_NAMES: tuple[str, ...] = (
    "powerdrill",
    "brita_pitcher",
    "cooler",
    "taperoll",
    "can",
    "wooden_bowl",
    "cup",
    "teabox",
    "box",
    "giant_teacup",
)


@cache
def get_object(name: str) -> ObjectModel:
    """The catalogue object called ``name`` (built once, then cached)."""
    if name not in BUILDERS:
        raise KeyError(f"unknown object {name!r}; valid names: {', '.join(OBJECT_NAMES)}")
    return BUILDERS[name]()
