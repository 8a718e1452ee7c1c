"""The hardware bridge node's parameters (rrg_common.ros.parameters): the drivers' names, the
sensors' sources, the E-stop, and the safety layer's settings (design §9)."""

from __future__ import annotations

from collections.abc import Callable

from rrg_common.ros.parameters import Param
from rrg_models.config import SENSING

from ..arm_limits import DEFAULT_ARM_LIMITS, load_arm_limits
from ..bridge_core import EFFORT_KINDS, BridgeOptions
from ..config import BRIDGE
from ..contact_guard import DEFAULT_PAD_SOURCE, PAD_SOURCES
from ..rdt import DEFAULT_COUNTS_PER_FORCE, DEFAULT_COUNTS_PER_TORQUE, RDT_RATE_RANGE_HZ

#: The driver's arm joint names (a ros2_control WAM description's).
DEFAULT_ARM_DRIVER_JOINTS = [f"wam_j{i}_joint" for i in range(1, 8)]
#: The arm backends: a ros2_control FollowJointTrajectory controller, or Barrett's wam_node.
ARM_BACKENDS = ("follow_joint_trajectory", "wam_node")
#: wam_node's arm joint names in /joint_states (barrett-ros2-pkg wam_publishers.h: "q" + (i + 1)),
#: used with arm_backend 'wam_node' while arm_joint_names keeps its default.
WAM_NODE_ARM_JOINTS = [f"q{i}" for i in range(1, 8)]
#: Barrett's URDF names: spread j11 (finger 1) and j21 (finger 2), proximal j12 j22 j32,
#: distal j13 j23 j33.
DEFAULT_HAND_DRIVER_JOINTS = [
    "bhand_j11_joint",
    "bhand_j21_joint",
    "bhand_j12_joint",
    "bhand_j22_joint",
    "bhand_j32_joint",
    "bhand_j13_joint",
    "bhand_j23_joint",
    "bhand_j33_joint",
]


#: The node's parameters (rrg_common.ros.parameters).
PARAMETERS: tuple[Param, ...] = (
    Param(
        "arm_backend",
        ARM_BACKENDS[0],
        (
            "The arm's driver: a ros2_control FollowJointTrajectory controller (arm_action) or "
            "Barrett's wam_node (wam_rt_joint_topic, wam_hold_service)"
        ),
        read_only=True,
        choices=tuple(ARM_BACKENDS),
    ),
    Param(
        "arm_action",
        "/arm_controller/follow_joint_trajectory",
        "FollowJointTrajectory action of the arm's controller",
        read_only=True,
    ),
    Param(
        "wam_rt_joint_topic",
        "/wam/RTJointPositionCMD",
        "wam_node's real-time joint position topic (wam_msgs/RTJointPositions)",
        read_only=True,
    ),
    Param(
        "wam_hold_service",
        "/wam/holdJointPosition",
        "wam_node's joint position hold service (std_srvs/SetBool)",
        read_only=True,
    ),
    Param(
        "driver_joint_states",
        "/joint_states",
        "The drivers' sensor_msgs/JointState topic",
        read_only=True,
    ),
    Param(
        "effort_kind",
        EFFORT_KINDS[0],
        (
            "What the arm's joint efforts are: the motors' joint torques, gravity and motion "
            "included (ros2_control's effort interface, wam_node's torques; the bridge "
            "subtracts the WAM model's with a momentum observer), or external torques a "
            "driver already estimated"
        ),
        read_only=True,
        choices=tuple(EFFORT_KINDS),
    ),
    Param(
        "arm_joint_names",
        DEFAULT_ARM_DRIVER_JOINTS,
        "The driver's 7 arm joint names, J1-J7 (arm_backend wam_node: q1-q7 unless set)",
        read_only=True,
    ),
    Param(
        "hand_joint_names",
        DEFAULT_HAND_DRIVER_JOINTS,
        "The driver's hand joint names: spread f1, spread f2, proximal f1-f3, distal f1-f3",
        read_only=True,
    ),
    Param(
        "hand_service_prefix",
        "/bhand",
        "Namespace of Barrett's BarrettHand services",
        read_only=True,
    ),
    Param(
        "wrench_source",
        "rdt",
        "Where the fingertip wrenches come from",
        read_only=True,
        choices=("rdt", "topics"),
    ),
    Param(
        "rdt_hosts",
        ["127.0.0.2", "127.0.0.3", "127.0.0.4"],
        "Net F/T box addresses of fingers 1-3 (RDT over UDP)",
        read_only=True,
    ),
    Param("rdt_port", 49152, "RDT UDP port", read_only=True),
    Param(
        "netft_http_port",
        80,
        (
            "HTTP port of the Net F/T boxes' netftapi2.xml, read for each box's "
            "counts per force and torque and its RDT rate (0: not read; counts_per_force "
            "and counts_per_torque then hold for every box)"
        ),
        read_only=True,
    ),
    Param(
        "rdt_rate",
        0.0,
        (
            "RDT output rate [Hz] each Net F/T box is set to (comm.cgi) before its records are "
            "used; needs netft_http_port (0: the boxes' own setting)"
        ),
        read_only=True,
        low=0.0,
        high=RDT_RATE_RANGE_HZ[1],
    ),
    Param(
        "counts_per_force",
        DEFAULT_COUNTS_PER_FORCE,
        "Net F/T counts per N of every box when netft_http_port is 0",
        read_only=True,
        low=1.0,
        high=1e9,
    ),
    Param(
        "counts_per_torque",
        DEFAULT_COUNTS_PER_TORQUE,
        "Net F/T counts per N m of every box when netft_http_port is 0",
        read_only=True,
        low=1.0,
        high=1e9,
    ),
    Param(
        "wrench_topics",
        ["/fingertip1/netft/wrench", "/fingertip2/netft/wrench", "/fingertip3/netft/wrench"],
        "geometry_msgs/WrenchStamped topics of fingers 1-3 (wrench_source 'topics')",
        read_only=True,
    ),
    Param(
        "pad_source",
        DEFAULT_PAD_SOURCE,
        (
            "Where the pad forces come from: Barrett's tactile pucks (wam_msgs/"
            "TactilePressureArray), an rrg_msgs/ContactPads topic (an adapter of the lab's), or "
            "derived from the fingertip sensors"
        ),
        read_only=True,
        choices=tuple(PAD_SOURCES),
    ),
    Param(
        "tactile_topic",
        "/bhand/tactile_states",
        "wam_msgs/TactilePressureArray topic of Barrett's BarrettHand node",
        read_only=True,
    ),
    Param(
        "pads_topic",
        "/bhand/contact_pads",
        "rrg_msgs/ContactPads topic (pad_source topic)",
        read_only=True,
    ),
    Param(
        "estop_topic", "/rrg/estop", "Latched E-stop (std_msgs/Bool, true = stop)", read_only=True
    ),
    Param(
        "estop_latch_file",
        "~/.ros/rrg_hw_bridge_estop.latched",
        "File that carries a latched E-stop over a restart of the bridge (empty: none)",
        read_only=True,
    ),
    Param(
        "estop_heartbeat_timeout",
        0.0,
        "Silence [s] of the E-stop topic that latches the E-stop (a deadman; 0: off)",
        read_only=True,
        low=0.0,
        high=60.0,
    ),
    Param(
        "arm_on_start",
        False,
        (
            "Arm at start, unless the latch file holds an E-stop (the emulated "
            "drivers; on a real arm, arm with bridge/reset_estop)"
        ),
        read_only=True,
    ),
    Param(
        "limits_file",
        "",
        "Per-arm limits YAML (empty: Barrett's published WAM limits)",
        read_only=True,
    ),
    Param(
        "publish_frames",
        True,
        (
            "Publish RRG's WAM and BarrettHand model on /robot_description, "
            "/tf_static and /tf from the measured joint states (false where the lab's own "
            "robot_state_publisher already publishes the robot's frames)"
        ),
        read_only=True,
    ),
    Param(
        "confirm_stops",
        True,
        (
            "A lone pad stops a guarded move only when the next pad sample "
            "agrees (a Nano17 or a joint effort stops it at once)"
        ),
        read_only=True,
    ),
    Param("dry_run", False, "Validate and publish every plan, command nothing", read_only=True),
    Param(
        "speed_scale",
        1.0,
        (
            "Speed-scaling cap: every trajectory runs at this fraction of its speed; may be "
            "lowered at run time, never raised above its start value"
        ),
        read_only=False,
        low=0.01,
        high=1.0,
    ),
    Param(
        "spread_sign",
        1,
        (
            "Sign of the driver's bhand_j11 (finger 1 spread) reading: 1, or -1 "
            "where it is flipped (the hand run without the WAM)"
        ),
        read_only=True,
        low=-1,
        high=1,
        step=2,
    ),
    Param(
        "retime",
        True,
        (
            "Slow a trajectory over the velocity or acceleration limits down "
            "uniformly (up to max_slowdown) instead of refusing it"
        ),
        read_only=True,
    ),
    Param(
        "max_slowdown",
        BRIDGE.max_slowdown,
        "Largest time stretch retiming may apply before the trajectory is refused",
        read_only=True,
        low=1.0,
        high=100.0,
    ),
    Param(
        "watchdog_timeout",
        BRIDGE.watchdog_timeout,
        "Oldest joint state or wrench [s] before the arm holds",
        read_only=True,
        low=0.01,
        high=1.0,
    ),
    Param(
        "force_ceiling",
        BRIDGE.force_ceiling,
        "Fingertip force [N] that aborts any move",
        read_only=True,
        low=0.1,
        high=1000.0,
    ),
    Param(
        "torque_ceiling",
        BRIDGE.torque_ceiling,
        "Fingertip torque [N m] that aborts any move",
        read_only=True,
        low=0.001,
        high=100.0,
    ),
    Param(
        "effort_threshold",
        SENSING.arm_torque_threshold,
        "Change of an arm joint's effort [N m] that stops a guarded move (0: off)",
        read_only=True,
        low=0.0,
        high=100.0,
    ),
    Param(
        "state_rate",
        BRIDGE.state_rate,
        "Rate [Hz] of the upward joint states, wrenches and pads",
        read_only=True,
        low=1.0,
        high=1000.0,
    ),
)


def bridge_options(p: Callable[[str], object]) -> BridgeOptions:
    """The core's settings from the parameters (p(name): a parameter's value)."""
    arm_joints = tuple(p("arm_joint_names"))
    if p("arm_backend") == "wam_node" and list(arm_joints) == DEFAULT_ARM_DRIVER_JOINTS:
        arm_joints = tuple(WAM_NODE_ARM_JOINTS)
    hand_joints = tuple(p("hand_joint_names"))
    if len(arm_joints) != 7 or len(hand_joints) != 8:
        raise ValueError("arm_joint_names needs 7 names and hand_joint_names 8")
    return BridgeOptions(
        limits=load_arm_limits(p("limits_file") or DEFAULT_ARM_LIMITS),
        arm_driver_joints=arm_joints,
        hand_driver_joints=hand_joints,
        dry_run=bool(p("dry_run")),
        spread_sign=float(p("spread_sign")),
        watchdog_timeout=float(p("watchdog_timeout")),
        derive_pads=p("pad_source") == "derived",
        force_ceiling=p("force_ceiling"),
        torque_ceiling=p("torque_ceiling"),
        estop_heartbeat_timeout=p("estop_heartbeat_timeout"),
        estop_latch_file=p("estop_latch_file") or None,
        arm_on_start=bool(p("arm_on_start")),
        effort_kind=p("effort_kind"),
        effort_threshold=float(p("effort_threshold")),
        confirm_stops=bool(p("confirm_stops")),
        retime=bool(p("retime")),
        max_slowdown=float(p("max_slowdown")),
    )
