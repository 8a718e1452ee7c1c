"""The planner node's parameters (rrg_common.ros.parameters): the levels and objects it loads,
the graph client's timeouts, the world it assumes, and its restart state."""

from __future__ import annotations

from rclpy.parameter import Parameter

from rrg_common.ros.parameters import Param
from rrg_estimator.config import LEVELS
from rrg_sim.config import WORLD_PROFILES

#: The node's parameters (rrg_common.ros.parameters).
PARAMETERS: tuple[Param, ...] = (
    Param(
        "levels",
        list(LEVELS),
        ("Uncertainty levels whose tables are loaded (beliefs must use one of their grids)"),
        read_only=True,
    ),
    Param(
        "preload",
        Parameter.Type.STRING_ARRAY,
        (
            "Objects whose planning models are loaded before the services start "
            "(a first build takes ~1 min per object)"
        ),
        read_only=True,
    ),
    Param(
        "reset_timeout",
        300.0,
        ("Longest wait [s] for the estimator's reset (it may load or build tables)"),
        low=1.0,
        high=3600.0,
    ),
    Param(
        "execute_timeout",
        300.0,
        "Longest wait [s] for one WRT execution or retreat",
        low=1.0,
        high=3600.0,
    ),
    Param(
        "belief_timeout",
        120.0,
        ("Longest wait [s] for the estimator's belief after an observation or a retreat"),
        low=0.1,
        high=3600.0,
    ),
    Param(
        "restart_timeout",
        60.0,
        (
            "Longest wait [s] for a node that died (the executor or the "
            "estimator) to be back before the grasp fails"
        ),
        low=1.0,
        high=3600.0,
    ),
    Param(
        "world_profile",
        "nominal",
        (
            "World profile the planner assumes the robot acts in "
            f"(rrg_sim.config.world_profile: {', '.join(WORLD_PROFILES)}, …): its calibration "
            "error values a goal grasp from a belief in another posture's frame"
        ),
        read_only=True,
    ),
    Param(
        "state_file",
        "",
        (
            "File the running grasp's progress is written to after every step, "
            "for a restarted planner to resume it ('' = none)"
        ),
        read_only=True,
    ),
)
