"""Per-arm limits for the safety layer, loaded from a YAML file (``arms/*.yaml``).

The file names the driver's joints in chain order (J1 … J7) with each joint's position range
[rad], velocity limit [rad/s] and acceleration limit [rad/s²], a workspace box [m] in the world
frame of ``rrg_models.wam`` (the WAM base frame: J1's axis is z, the table top at
``WORLD.table_top_z``), and a ``source`` for every quantity. Layout::

    name: barrett_wam7
    joints:
      wam_j1_joint: {lower: -2.6, upper: 2.6, max_velocity: 1.5, max_acceleration: 10.0}
      ...
    source: {lower: ..., upper: ..., max_velocity: ..., max_acceleration: ...}
    workspace:
      min: [x, y, z]
      max: [x, y, z]
      source: {x: ..., y: ..., z_min: ..., z_max: ...}
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

#: The limits file of the default arm (a Barrett WAM 7-DOF).
DEFAULT_ARM_LIMITS = Path(__file__).parent / "arms" / "barrett_wam7.yaml"

#: Joints of the arm the safety layer checks (rrg_models.wam's kinematics: a 7-DOF WAM).
N_JOINTS = 7
#: Per-joint keys of the ``joints`` entries, in the order of ``ArmLimits``.
JOINT_KEYS = ("lower", "upper", "max_velocity", "max_acceleration")
#: Keys of the workspace's ``source`` mapping.
WORKSPACE_SOURCE_KEYS = ("x", "y", "z_min", "z_max")
AXES = ("x", "y", "z")


def _readonly(values) -> np.ndarray:
    a = np.array(values, dtype=float)
    a.setflags(write=False)
    return a


@dataclass(frozen=True, eq=False)
class ArmLimits:
    """Limits of one arm: driver joint names, position range lower/upper [rad], max_velocity
    [rad/s] and max_acceleration [rad/s²] per joint (7,), and the workspace box
    workspace_min/workspace_max (3,) [m] (x, y, z in rrg_models.wam's world frame)."""

    joint_names: tuple[str, ...]
    lower: np.ndarray
    upper: np.ndarray
    max_velocity: np.ndarray
    max_acceleration: np.ndarray
    workspace_min: np.ndarray
    workspace_max: np.ndarray
    name: str

    def __post_init__(self) -> None:
        for field in (
            "lower",
            "upper",
            "max_velocity",
            "max_acceleration",
            "workspace_min",
            "workspace_max",
        ):
            object.__setattr__(self, field, _readonly(getattr(self, field)))
        object.__setattr__(self, "joint_names", tuple(self.joint_names))


def _require(mapping: dict, key: str, where: str) -> Any:
    if not isinstance(mapping, dict):
        raise ValueError(f"{where}: expected a mapping, got {type(mapping).__name__}")
    if key not in mapping:
        raise ValueError(f"{where}: missing key {key!r}")
    return mapping[key]


def _number(value: Any, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError(f"{where}: expected a number, got {value!r}")
    if not math.isfinite(value):
        raise ValueError(f"{where}: {value} is not a finite number")
    return float(value)


def _source(value: Any, where: str) -> str:
    if not isinstance(value, str) or not value.strip():
        raise ValueError(f"{where}: expected a non-empty text saying where the numbers come from")
    return value


def _vector3(value: Any, where: str) -> np.ndarray:
    if not isinstance(value, list) or len(value) != 3:
        raise ValueError(f"{where}: expected 3 numbers [x, y, z] in m, got {value!r}")
    return np.array([_number(v, f"{where}[{axis}]") for v, axis in zip(value, AXES)])


def parse_arm_limits(data: Any, origin: str = "arm limits") -> ArmLimits:
    """Validate the parsed YAML document ``data`` → ArmLimits; ValueError naming the key (and
    joint) of the first problem, prefixed with ``origin``."""
    try:
        return _parse(data)
    except ValueError as exc:
        raise ValueError(f"{origin}: {exc}") from None


def _parse(data: Any) -> ArmLimits:
    name = _require(data, "name", "top level")
    if not isinstance(name, str) or not name.strip():
        raise ValueError(f"name: expected a non-empty text, got {name!r}")
    joints = _require(data, "joints", "top level")
    if not isinstance(joints, dict):
        raise ValueError("joints: expected a mapping of driver joint name → limits")
    if len(joints) != N_JOINTS:
        raise ValueError(
            f"joints: {len(joints)} entries, expected {N_JOINTS} (J1 … J7 in chain order)"
        )
    values = {key: [] for key in JOINT_KEYS}
    for joint, entry in joints.items():
        if not isinstance(joint, str) or not joint:
            raise ValueError(f"joints: joint name {joint!r} is not a text")
        for key in JOINT_KEYS:
            where = f"joints.{joint}.{key}"
            values[key].append(_number(_require(entry, key, f"joints.{joint}"), where))
        lo, hi = values["lower"][-1], values["upper"][-1]
        if lo >= hi:
            raise ValueError(f"joints.{joint}: lower {lo} rad must be below upper {hi} rad")
        for key, unit in (("max_velocity", "rad/s"), ("max_acceleration", "rad/s²")):
            if values[key][-1] <= 0:
                raise ValueError(f"joints.{joint}.{key}: {values[key][-1]} {unit} must be > 0")
    source = _require(data, "source", "top level")
    for key in JOINT_KEYS:
        _source(_require(source, key, "source"), f"source.{key}")
    box = _require(data, "workspace", "top level")
    lo = _vector3(_require(box, "min", "workspace"), "workspace.min")
    hi = _vector3(_require(box, "max", "workspace"), "workspace.max")
    for axis, a, b in zip(AXES, lo, hi):
        if a >= b:
            raise ValueError(f"workspace: min {axis} = {a} m must be below max {axis} = {b} m")
    box_source = _require(box, "source", "workspace")
    for key in WORKSPACE_SOURCE_KEYS:
        _source(_require(box_source, key, "workspace.source"), f"workspace.source.{key}")
    return ArmLimits(
        joint_names=tuple(joints),
        lower=values["lower"],
        upper=values["upper"],
        max_velocity=values["max_velocity"],
        max_acceleration=values["max_acceleration"],
        workspace_min=lo,
        workspace_max=hi,
        name=name,
    )


def load_arm_limits(path: str | Path = DEFAULT_ARM_LIMITS) -> ArmLimits:
    """Read and validate an arm limits file (module doc) → ArmLimits; ValueError naming the
    file, the key and the joint of the first problem."""
    import yaml  # only the loader needs PyYAML

    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8"))
    except yaml.YAMLError as exc:
        raise ValueError(f"{path}: not valid YAML: {exc}") from None
    return parse_arm_limits(data, str(path))
