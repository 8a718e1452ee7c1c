"""A user copy of the box with a second goal grasp, for the tests of goal grasp sets."""

from __future__ import annotations

import shutil
from pathlib import Path

from rrg_models.objects.catalogue import BUILTIN_DIR

#: A second goal grasp of the box: its goal grasp, 6 cm along its length.
GOAL_END = """
[[goal_grasps]]
name = "goal_end"
approach = "top_down"
yaw_rad = 1.5707963267948966
through_m = [0.0, 0.06, 0.1]
description = "from above, across the width 6 cm along"
"""


def box_with_goal_end(parent: Path, name: str, extra: str = "") -> Path:
    """``parent``/``name``: the box renamed, with GOAL_END and ``extra`` appended."""
    folder = parent / name
    shutil.copytree(BUILTIN_DIR / "box", folder)
    text = (folder / "object.toml").read_text().replace('name = "box"', f'name = "{name}"')
    (folder / "object.toml").write_text(text + GOAL_END + extra)
    return folder
