"""The repository's Python packages, as pyproject.toml lists them for setuptools: the one list
the layout, colcon and docs tests share."""

from __future__ import annotations

import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())
PACKAGES = tuple(
    p.removesuffix("*") for p in PYPROJECT["tool"]["setuptools"]["packages"]["find"]["include"]
)

#: The node modules: the launcher's (rrg_bringup.graph.NODES) and the bag recorder.
NODE_MODULES = (
    "rrg_sim.ros.sim_node",
    "rrg_sim.executor.executor_node",
    "rrg_estimator.ros.estimator_node",
    "rrg_planner.ros.planner_node",
    "rrg_bags.recorder_node",
    "rrg_hw_bridge.ros.bridge_node",
    "rrg_fake_hw.fake_hw_node",
)
