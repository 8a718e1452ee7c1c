r"""The hardware bridge node (design §7): RRG's arm/hand interface on the real drivers.

    python -m rrg_hw_bridge.ros.bridge_node [--ros-args -p dry_run:=true -p limits_file:=arm.yaml]

Upward it serves what the simulator node serves, under /rrg: ``guarded_move``
(rrg_msgs/GuardedMove), ``hand_command`` (rrg_msgs/HandCommand), ``joint_states``,
``fingertip{1,2,3}/wrench`` and ``contact_pads``, so the executor, estimator and planner run
unchanged. Downward it drives a FollowJointTrajectory arm controller (or, with ``arm_backend``
``wam_node``, Barrett's wam_node through its real-time joint stream), Barrett's BarrettHand
services and three Net F/T boxes over RDT (or WrenchStamped topics), all named by parameters.

Every command passes the safety layer (rrg_hw_bridge.safety): joint position, velocity and
acceleration limits and the workspace box before anything is sent; while a move runs, the
force/torque ceiling, the data watchdog (joint states and wrenches older than
``watchdog_timeout``, Net F/T sequence gaps and status errors) and the latched E-stop
(``/rrg/estop``, std_msgs/Bool; ``bridge/reset_estop`` clears it) cancel the controller's goal,
which holds the arm. A guarded move also stops on the first pad, fingertip or joint-effort
crossing. Every refusal and stop is logged and published on ``bridge/safety``
(diagnostic_msgs/DiagnosticStatus); every validated plan on ``bridge/plan``
(trajectory_msgs/JointTrajectory). ``dry_run`` validates and publishes, and commands nothing.
"""

from __future__ import annotations

import sys
import threading
import time
from collections import deque
from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import WrenchStamped
from rcl_interfaces.msg import (
    SetParametersResult,
)
from rclpy.action import GoalResponse
from rclpy.action.server import ServerGoalHandle
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool
from std_srvs.srv import Trigger
from trajectory_msgs.msg import JointTrajectory
from wam_msgs.msg import TactilePressureArray

from rrg_common.ros.arm_hand_interface import (
    START_TOLERANCE,
    GoalError,
    StatePublishers,
    check_hand_command,
    client_fraction,
    goal_via_points,
    serve_arm_hand_interface,
)
from rrg_common.ros.msg_conversions import (
    ARM_JOINT_NAMES,
    PROXIMAL_JOINT_NAMES,
    SPREAD_JOINT_NAME,
    tip_contacts_to_msg,
    vector_to_msg,
)
from rrg_common.ros.node_main import destroy_action_endpoints, keep_serving, run_node
from rrg_common.ros.parameters import Param, declare
from rrg_models.config import HAND, PHYSICS, SENSING, SENSOR_NAMES
from rrg_models.hand_sensing import FingerClosing
from rrg_msgs.action import GuardedMove
from rrg_msgs.msg import ContactPads
from rrg_msgs.srv import HandCommand

from ..arm_limits import DEFAULT_ARM_LIMITS, load_arm_limits
from ..config import BRIDGE
from ..contact_guard import (
    DEFAULT_PAD_SOURCE,
    DERIVED_PADS_UNSENSED,
    PAD_SOURCES,
    ContactGuard,
    HandState,
    Trip,
    VelocityEstimate,
    path_index,
)
from ..external_torque import ExternalTorqueObserver
from ..rdt import (
    DEFAULT_COUNTS_PER_FORCE,
    DEFAULT_COUNTS_PER_TORQUE,
    RDT_RATE_RANGE_HZ,
    Calibration,
)
from ..safety import (
    EStop,
    ForceCeiling,
    Refusal,
    SafetyCode,
    Watchdog,
    check_recovery,
    check_trajectory,
    limit_excess,
    slowdown_to_limits,
)
from ..safety import scale_time as scaled_times
from ..tactile import TACTILE_PADS_UNSENSED, TactileError, pads_from_pucks
from .drivers import (
    BarrettHandServices,
    DriverError,
    Latched,
    RdtSensors,
    TrajectoryArm,
    WamNodeArm,
    WrenchTopicSensors,
)

NODE_NAME = "hw_bridge"
#: arm_on_start arms the bridge this long [s] after its start, so that an E-stop a
#: transient-local publisher holds reaches it first (chosen: DDS discovery on one host takes
#: 0.1-0.5 s, measured by the bridge tests' startup; the message follows the match at once).
ARM_ON_START_DELAY_S = 1.0
#: What the driver's arm efforts are (parameter effort_kind).
EFFORT_KINDS = ("joint_torque", "external_torque")
NAMESPACE = "rrg"
R = GuardedMove.Result
H = HandCommand.Response
#: A close command moves the spread first only when it is this far from the request [rad]
#: (as the simulator node).
SPREAD_TOLERANCE = 0.01
#: A guarded move's effort baseline is the mean of the arm's last this many joint efforts (50 ms
#: of a 500 Hz driver). With one noisy sample as the baseline, the change between two samples
#: (σ√2 with the simulator's 0.2 N m effort noise) crosses the 1.2 N m threshold at 4.2σ: one
#: 3 s guarded move in free air in ten stopped on nothing (Monte Carlo, 500 Hz, 7 joints), where
#: the simulator, which compares one sample with 0, crosses it at 6σ. The mean brings it back to
#: 5.9σ.
EFFORT_BASELINE_SAMPLES = 25
#: A watchdog tick later than this fraction of watchdog_timeout after the previous one means the
#: bridge itself did not run meanwhile (its process descheduled, its threads starved): what the
#: drivers sent meanwhile waits unread in the Net F/T sockets and the joint-state subscription,
#: and rclpy's executor runs a ready timer before it takes a ready subscription. Such a tick
#: only looks (never two in a row); the next, a watchdog period later, judges. Measured on this
#: 2-core machine under load during a grasp: the bridge's receive threads saw records 0.14 s
#: apart whose boxes had sent them 1 ms apart.
WATCHDOG_SELF_STALL = 0.5
#: After a bias request the bridge tares on records that arrived this long [s] after it (chosen:
#: ten records at the boxes' 1 kHz, far beyond a LAN's sub-millisecond latency; a box applies
#: the bias to the samples after the request, so the records before it still carry the offset).
BIAS_SETTLE_S = 0.01
#: Longest wait [s] for those records before the bias is reported as failed.
BIAS_TIMEOUT_S = 1.0
#: QoS of the E-stop's second subscription: a publisher that keeps its last message
#: (transient local) hands an E-stop engaged before the bridge started to the bridge as it
#: joins. A volatile publisher (``ros2 topic pub`` by default) reaches the first, volatile one.
ESTOP_LATCHED_QOS = QoSProfile(
    depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL
)
#: A recovery move is stopped when a joint gets this much farther outside its limits than at
#: its start [rad] (chosen: above the WAM's encoder noise, well below a visible motion).
RECOVERY_SLACK = 0.01
#: Upward hand joint names (the simulator's): both spread joints, proximal, distal.
HAND_JOINT_NAMES = (
    SPREAD_JOINT_NAME,
    "bh_f2_spread",
    *PROXIMAL_JOINT_NAMES,
    *(f"bh_f{i}_dist" for i in (1, 2, 3)),
)
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


@dataclass
class Measured:
    """The newest driver joint state, in RRG's joint order."""

    arm_q: np.ndarray = field(default_factory=lambda: np.full(7, np.nan))
    arm_v: np.ndarray = field(default_factory=lambda: np.zeros(7))
    arm_effort: np.ndarray | None = None
    hand_q: np.ndarray = field(default_factory=lambda: np.full(8, np.nan))  # HAND_JOINT_NAMES
    hand_v: np.ndarray = field(default_factory=lambda: np.zeros(8))
    received_s: float = -np.inf  # monotonic time of arrival
    hand_count: int = 0  # driver joint states with hand joints received so far
    hand_stamp_s: float = -np.inf  # the newest one's driver stamp [s] (arrival when unstamped)


@dataclass
class HandMotion:
    """A hand command being executed, and why the safety layer stopped it (set once). While
    the hand closes, the force ceiling limits each finger's squeeze instead: a finger whose
    fingertip crosses it stops (``squeezed``) and the others close on."""

    closing: bool = False
    code: int | None = None
    message: str = ""
    squeezed: np.ndarray = field(default_factory=lambda: np.zeros(3, bool))


class HandStopped(RuntimeError):
    """The safety layer stopped a hand motion (its code and message)."""

    def __init__(self, code: int, message: str):
        super().__init__(message)
        self.code = code


@dataclass
class ActiveMove:
    """The guarded move being executed, and why it stops (set once)."""

    guard: ContactGuard | None
    handle: object | None = None  # the controller's ClientGoalHandle
    code: int | None = None
    message: str = ""
    trip: Trip | None = None
    stopped_s: float = np.nan
    #: a recovery move (joints outside their limits, brought back): how far outside they were
    #: at its start [rad]; None for any other move
    recovery_excess: float | None = None


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


class BridgeNode(Node):
    """The arm/hand interface on real drivers, behind a safety layer."""

    def __init__(self) -> None:
        super().__init__(NODE_NAME, namespace=NAMESPACE)
        declare(self, PARAMETERS)
        p = lambda name: self.get_parameter(name).value
        self.limits = load_arm_limits(p("limits_file") or DEFAULT_ARM_LIMITS)
        self.arm_driver_joints = tuple(p("arm_joint_names"))
        wam_node = p("arm_backend") == "wam_node"
        if wam_node and list(self.arm_driver_joints) == DEFAULT_ARM_DRIVER_JOINTS:
            self.arm_driver_joints = tuple(WAM_NODE_ARM_JOINTS)
        self.hand_driver_joints = tuple(p("hand_joint_names"))
        if len(self.arm_driver_joints) != 7 or len(self.hand_driver_joints) != 8:
            raise ValueError("arm_joint_names needs 7 names and hand_joint_names 8")
        self.dry_run = bool(p("dry_run"))
        self.speed_scale = float(p("speed_scale"))
        self.speed_scale_cap = self.speed_scale  # run-time changes may only lower it
        self.spread_sign = float(p("spread_sign"))
        self.add_on_set_parameters_callback(self.on_set_parameters)
        self.watchdog_timeout = float(p("watchdog_timeout"))
        pad_source = p("pad_source")
        derive = pad_source == "derived"
        self.hand = HandState(derive_pads=derive)
        self.ceiling = ForceCeiling(p("force_ceiling"), p("torque_ceiling"))
        self.estop = EStop(
            p("estop_heartbeat_timeout"), p("estop_latch_file") or None, time.monotonic()
        )
        #: when arm_on_start arms the bridge: after a transient-local E-stop could have arrived
        self._arm_at = time.monotonic() + ARM_ON_START_DELAY_S if p("arm_on_start") else None
        # a silent pad topic is a fault, not a hand that never touches anything
        streams = ("joint_states", "fingertip1", "fingertip2", "fingertip3")
        self.watchdog = Watchdog(self.watchdog_timeout, streams + (() if derive else ("pads",)))
        self._pad_count = 0
        self._lock = threading.Lock()
        self._measured = Measured()
        self._joint_event = threading.Condition()
        self._efforts: deque[np.ndarray] = deque(maxlen=EFFORT_BASELINE_SAMPLES)
        #: the arm's external torques from its joint torques (effort_kind joint_torque)
        self.observer = ExternalTorqueObserver() if p("effort_kind") == EFFORT_KINDS[0] else None
        #: per joint-name list, for drivers whose joint states carry no velocities
        self._velocity: dict[tuple[str, ...], VelocityEstimate] = {}
        self._move: ActiveMove | None = None
        self._hand_motion: HandMotion | None = None
        self._hand_command_lock = threading.RLock()  # the closing loop's commands vs a stop
        #: which interfaces the driver's joint states carry (finite values); what is missing is
        #: derived (velocities) or disables its guard (efforts)
        self.interfaces = {"arm_velocity": False, "arm_effort": False, "hand_velocity": False}
        self._interfaces_logged: dict = {}
        self._move_busy = threading.Lock()
        self._hand_busy = threading.Lock()
        self._sensor_fault_s = -np.inf
        self._latch_reset_s = np.full(3, -np.inf)  # per box: the last RESET_THRESHOLD_LATCH
        self._sensor_fault = ""
        self._stale: list[str] = []
        self._watchdog_tick_s = time.monotonic()
        self._watchdog_skipped = False
        self._limit_fault = ""
        group = ReentrantCallbackGroup()
        # The drivers' streams (joint states at 500 Hz, pads, the E-stop) and the periodic work
        # run on a second node spun by its own single-threaded executor: rclpy's
        # MultiThreadedExecutor cannot keep up with 500 Hz (28 Hz at 84 % of a core, measured),
        # its single-threaded one can (500 Hz at 13 %).
        self.io = Node(f"{NODE_NAME}_io", namespace=NAMESPACE, context=self.context)
        self._io_executor = SingleThreadedExecutor(context=self.context)
        self._io_executor.add_node(self.io)
        self._closing = threading.Event()

        # -------------------------------------------------------------- downward: drivers
        if wam_node:
            self.arm = WamNodeArm(
                self,
                self.arm_driver_joints,
                group,
                lambda: self.measured().arm_q,
                p("wam_rt_joint_topic"),
                p("wam_hold_service"),
                self.estop.run_if_released,
            )
            self.arm_text = self.arm.describe()
        else:
            self.arm = TrajectoryArm(
                self, p("arm_action"), self.arm_driver_joints, group, self.estop.run_if_released
            )
            self.arm_text = p("arm_action")
        self.hand_driver = BarrettHandServices(
            self, p("hand_service_prefix"), group, self.estop.run_if_released
        )
        self.io.create_subscription(JointState, p("driver_joint_states"), self.on_driver_joints, 50)
        if p("wrench_source") == "rdt":
            self.sensors = RdtSensors(
                list(p("rdt_hosts")),
                int(p("rdt_port")),
                Calibration(p("counts_per_force"), p("counts_per_torque")),
                self.on_wrench,
                self.on_sensor_fault,
                http_port=int(p("netft_http_port")),
                on_config=self.on_box_config,
                rdt_rate_hz=float(p("rdt_rate")),
            )
        else:
            self.sensors = WrenchTopicSensors(
                self.io, list(p("wrench_topics")), self.on_wrench, time.monotonic, None
            )
        if derive:
            self.get_logger().warning(
                "pad_source 'derived': the hand has no pad feedback; the distal pads read the "
                f"fingertip forces and {', '.join(DERIVED_PADS_UNSENSED)} never fire (the "
                "estimator and the planner leave them out: unsensed_sensors, set by rrg-launch)"
            )
        elif pad_source == "tactile":
            self.get_logger().info(
                f"pads from Barrett's tactile pucks on {p('tactile_topic')}: "
                f"{', '.join(TACTILE_PADS_UNSENSED)} have none and never fire"
            )
            self.io.create_subscription(
                TactilePressureArray, p("tactile_topic"), self.on_tactile, 10
            )
        else:
            self.get_logger().info(f"pads from rrg_msgs/ContactPads on {p('pads_topic')}")
            self.io.create_subscription(ContactPads, p("pads_topic"), self.on_driver_pads, 10)
        self.io.create_subscription(Bool, p("estop_topic"), self.on_estop, 10)
        self.io.create_subscription(Bool, p("estop_topic"), self.on_estop, ESTOP_LATCHED_QOS)

        # -------------------------------------------------------------- upward: RRG
        self.state_pubs = StatePublishers.create(self, frames=bool(p("publish_frames")))
        self.plan_pub = self.create_publisher(JointTrajectory, "bridge/plan", 10)
        self.safety_pub = self.create_publisher(DiagnosticStatus, "bridge/safety", 10)
        #: every status and safety event also goes on /diagnostics, as ROS drivers publish
        #: theirs (rqt_robot_monitor, Foxglove)
        self.diagnostics_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        serve_arm_hand_interface(
            self, self.execute_guarded_move, self.on_move_goal, self.on_hand_command, group
        )
        self.create_service(
            Trigger, "bridge/reset_estop", self.on_reset_estop, callback_group=group
        )
        self.create_service(Trigger, "bridge/bias", self.on_bias, callback_group=group)
        self.io.create_timer(BRIDGE.watchdog_period, self.on_watchdog)
        self.io.create_timer(1.0 / p("state_rate"), self.publish_state)
        self.status_pub = self.create_publisher(DiagnosticStatus, "bridge/status", 10)
        self._joint_count = 0
        self._status_last = (time.monotonic(), 0, 0)
        self.io.create_timer(1.0, self.publish_status)
        self._io_thread = threading.Thread(target=self._spin_io, name="bridge-io", daemon=True)
        self._io_thread.start()
        self.sensors.start()
        self.get_logger().info(
            f"bridge up{' (DRY RUN: nothing will be commanded)' if self.dry_run else ''}: arm "
            f"{self.arm_text}, hand {p('hand_service_prefix')}/*, fingertips "
            f"{self.sensors.describe()}, limits {self.limits.name}, speed scale "
            f"{self.speed_scale}, watchdog {self.watchdog_timeout * 1e3:.0f} ms"
        )
        self.get_logger().warning(
            f"E-stop latched, {self.estop.reason} (ros2 service call "
            f"/{NAMESPACE}/bridge/reset_estop std_srvs/srv/Trigger); nothing moves until then"
            + (
                f"; arm_on_start arms it in {ARM_ON_START_DELAY_S:.0f} s unless an E-stop comes"
                if self._arm_at is not None and self.estop.reason == EStop.NOT_ARMED
                else ""
            )
        )

    def on_set_parameters(self, params) -> SetParametersResult:
        """Run-time changes: ``speed_scale`` may be lowered, never raised above its start
        value (the descriptors refuse every read-only parameter)."""
        for prm in params:
            if prm.name != "speed_scale":
                continue
            value = float(prm.value)
            if not 0.0 < value <= self.speed_scale_cap:
                return SetParametersResult(
                    successful=False,
                    reason=f"speed_scale may only be lowered: {value} is not in "
                    f"(0, {self.speed_scale_cap}] (its start value)",
                )
            self.speed_scale = value
            self.get_logger().warning(
                f"speed_scale set to {value} (at most {self.speed_scale_cap})"
            )
        return SetParametersResult(successful=True)

    # ------------------------------------------------------------------ safety reports
    def report(self, code: int, check: str, message: str, refused: bool) -> None:
        """Log a refusal or a safety stop and publish it on bridge/safety."""
        what = "refused" if refused else "stopped"
        self.get_logger().error(f"{what} [{check}, code {code}]: {message}")
        status = DiagnosticStatus(
            level=DiagnosticStatus.ERROR,
            name=f"{NODE_NAME}/{check}",
            message=f"{what}: {message}",
            hardware_id="wam",
            values=[KeyValue(key="code", value=str(code)), KeyValue(key="what", value=what)],
        )
        self.safety_pub.publish(status)
        self.publish_diagnostics(status)

    def publish_diagnostics(self, status: DiagnosticStatus) -> None:
        """One status on /diagnostics (diagnostic_msgs/DiagnosticArray)."""
        array = DiagnosticArray(status=[status])
        array.header.stamp = self.get_clock().now().to_msg()
        self.diagnostics_pub.publish(array)

    def gate(self) -> Refusal | None:
        """Why no command may start now (the E-stop or a robot fault, the arm's driver missing,
        a sensor fault, stale data, a joint-limit fault). A recent sensor fault comes before
        stale data: a box reporting a status error also goes stale (its records are not used),
        and the status error is the cause."""
        reason = self.estop.reason
        if reason.startswith(EStop.ROBOT_FAULT):
            return Refusal(SafetyCode.CONTROLLER_FAILED, "controller", f"{reason}; reset first")
        if reason:
            return Refusal(SafetyCode.ESTOP, "estop", f"the E-stop is latched ({reason})")
        if not self.dry_run and not self.arm.ready():
            return Refusal(
                SafetyCode.CONTROLLER_FAILED,
                "controller",
                f"the arm's driver ({self.arm_text}) is not available (yet)",
            )
        if time.monotonic() - self._sensor_fault_s < BRIDGE.sensor_fault_hold:
            return Refusal(SafetyCode.SENSOR_FAULT, "sensor", self._sensor_fault)
        stale = self.watchdog.stale(time.monotonic())
        if stale:
            return Refusal(
                SafetyCode.STALE_DATA,
                "watchdog",
                self.stale_message(stale),
            )
        if self._limit_fault:
            return Refusal(SafetyCode.JOINT_LIMITS, "joint_limits", self._limit_fault)
        return None

    def describe_interfaces(self) -> str:
        """What the driver's joint states carry, and what the missing interfaces disable."""
        i, effort = self.interfaces, self.get_parameter("effort_threshold").value
        parts = [
            "arm velocities " + ("measured" if i["arm_velocity"] else "derived from positions"),
            "hand velocities "
            + ("measured" if i["hand_velocity"] else "derived from positions (stall detection)"),
        ]
        if i["arm_effort"]:
            parts.append(
                "arm efforts measured ("
                + (
                    f"joint torques: the external torque from a momentum observer, gain "
                    f"{self.observer.gain_per_s:.0f}/s"
                    if self.observer is not None
                    else "external torques"
                )
                + ")"
            )
        elif effort > 0.0:
            parts.append(
                f"NO arm efforts (missing or NaN): the effort guard ({effort} N m) cannot run, "
                "and guarded moves are refused until effort_threshold:=0.0"
            )
        else:
            parts.append("no arm efforts (the effort guard is off)")
        return "; ".join(parts)

    def stale_message(self, stale: list[str]) -> str:
        unread = self.sensors.unread()
        why = "".join(f" ({name}: {unread[name]})" for name in stale if name in unread)
        return (
            f"no fresh data from {', '.join(stale)} within {self.watchdog_timeout * 1e3:.0f} ms"
            + why
        )

    def on_box_config(self, finger: int, config, error: str) -> None:
        """A Net F/T box's netftapi2.xml was read (config), or could not be (error)."""
        name = f"fingertip{finger + 1}"
        if config is not None:
            self.get_logger().info(f"{name}: {config.describe()}")
        else:
            self.get_logger().warning(
                f"{name}: {error}; its records are not used until it is read",
                throttle_duration_sec=10.0,
            )

    def stop_move(
        self,
        code: int,
        check: str,
        message: str,
        trip: Trip | None = None,
        only: ActiveMove | None = None,
        spare=None,
    ) -> None:
        """Stop the running move (once): cancel the controller's goal, which holds the arm.
        The move is the one running when the lock is taken: with ``only``, only if it is that
        move; with ``spare`` (a predicate on it), not if it spares it."""
        with self._lock:
            move = self._move
            if move is None or move.code is not None:
                return
            if (only is not None and move is not only) or (spare is not None and spare(move)):
                return
            move.code, move.message, move.trip = code, message, trip
            move.stopped_s = time.monotonic()
            handle = move.handle
        if handle is not None:
            handle.cancel_goal_async()
        if code not in (R.NONE, R.CANCELED):  # a contact's trip (NONE) is no safety event
            self.report(code, check, message, refused=False)

    def stop_hand(self, code: int, check: str, message: str) -> bool:
        """Stop the running hand command (once): every hand motor stops at once. False when
        no hand command was running (or it had been stopped already)."""
        with self._lock:
            motion = self._hand_motion
            if motion is None or motion.code is not None:
                return False
            motion.code, motion.message = code, message
        with self._hand_command_lock:  # no finger command of the closing loop follows it
            self.hand_driver.stop(self.measured().hand_q[0])
        self.report(code, check, f"hand command: {message}", refused=False)
        return True

    def stop_all(self, code: int, check: str, message: str) -> None:
        """Stop the arm's move and the hand's motion."""
        self.stop_move(code, check, message)
        self.stop_hand(code, check, message)

    # ------------------------------------------------------------------ driver callbacks
    def on_driver_joints(self, msg: JointState) -> None:
        now = time.monotonic()
        index = {n: i for i, n in enumerate(msg.name)}
        try:
            arm = [index[n] for n in self.arm_driver_joints]
        except KeyError:
            arm = None
        hand = [index.get(n) for n in self.hand_driver_joints]
        # when the driver measured it, on its clock (arrival when it does not stamp)
        stamp = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec or self.ros_time()
        pos = np.asarray(msg.position, dtype=float)
        vel, eff = np.asarray(msg.velocity, dtype=float), np.asarray(msg.effort, dtype=float)
        # A driver without velocities (wam_node), or with NaN for a joint that lacks the
        # interface (ros2_control's joint_state_broadcaster): differentiate the positions.
        measured_v = len(vel) == len(pos)
        if not measured_v or not np.isfinite(vel).all():
            estimate = self._velocity.setdefault(tuple(msg.name), VelocityEstimate(len(pos)))
            derived = estimate.update(pos, stamp)
            vel = np.where(np.isfinite(vel), vel, derived) if measured_v else derived
        has_effort = len(eff) == len(pos)
        if arm is not None:
            self.interfaces.update(
                arm_velocity=measured_v and bool(np.isfinite(msg.velocity[arm[0]])),
                arm_effort=has_effort and bool(np.isfinite(eff[arm]).all()),
                hand_velocity=measured_v
                and all(np.isfinite(msg.velocity[i]) for i in hand if i is not None),
            )
        with self._lock:
            m = self._measured
            for k, i in enumerate(hand):
                if i is not None:
                    sign = self.spread_sign if k == 0 else 1.0  # bhand_j11's reading
                    m.hand_q[k] = sign * pos[i]
                    m.hand_v[k] = sign * vel[i]
            if any(i is not None for i in hand):
                m.hand_count += 1
                m.hand_stamp_s = stamp
            if arm is not None:
                m.arm_q = pos[arm]
                m.arm_v = vel[arm]
                m.arm_effort = eff[arm] if self.interfaces["arm_effort"] else None
                if m.arm_effort is not None and self.observer is not None:
                    m.arm_effort = self.observer.update(
                        stamp, m.arm_q, m.arm_v, m.arm_effort, m.hand_q, m.hand_v
                    )
                if m.arm_effort is not None:
                    self._efforts.append(m.arm_effort)
            m.received_s = now
            move = self._move
            arm_q, effort, hand_q = m.arm_q.copy(), m.arm_effort, m.hand_q.copy()
        if arm is None:
            with self._joint_event:
                self._joint_event.notify_all()
            return
        if self.interfaces != self._interfaces_logged:
            self._interfaces_logged = dict(self.interfaces)
            self.get_logger().info(f"driver joint states: {self.describe_interfaces()}")
        self._joint_count += 1
        self.watchdog.feed("joint_states", now)
        self.hand.set_hand_joints(hand_q[0], hand_q[2:5])
        outside = (arm_q < self.limits.lower) | (arm_q > self.limits.upper)
        if outside.any():
            j = int(np.argmax(outside))
            self._limit_fault = (
                f"measured joint {j + 1} at {arm_q[j]:.3f} rad is outside its limits "
                f"[{self.limits.lower[j]}, {self.limits.upper[j]}] rad"
            )
            excess = float(limit_excess(arm_q, self.limits).max())
            recovering = lambda mv: (
                mv.recovery_excess is not None and excess <= mv.recovery_excess + RECOVERY_SLACK
            )
            # judged on the move running when the stop is made: a recovery move registered
            # since this message arrived is spared
            self.stop_move(
                SafetyCode.JOINT_LIMITS, "joint_limits", self._limit_fault, spare=recovering
            )
            if move is None or not recovering(move):
                self.stop_hand(SafetyCode.JOINT_LIMITS, "joint_limits", self._limit_fault)
        else:
            self._limit_fault = ""
        if move is not None and move.guard is not None and effort is not None:
            trip = move.guard.check_effort(effort)
            if trip is not None:
                self.stop_move(R.NONE, "contact", trip.describe(SENSOR_NAMES), trip, only=move)
        with self._joint_event:
            self._joint_event.notify_all()

    def on_wrench(self, finger: int, wrench: np.ndarray, received_s: float) -> None:
        """A fingertip sample (load on the fingertip, sensor frame) from a box or a topic."""
        tips = self.hand.set_tip(finger, wrench)
        self.watchdog.feed(f"fingertip{finger + 1}", received_s)
        move, motion = self._move, self._hand_motion
        if move is None and motion is None:
            return
        loads = self.hand.loads()  # the ceiling limits the load itself, whatever the tare
        over = self.ceiling.check(loads)
        if over is not None and move is None and motion.closing and np.isfinite(loads).all():
            motion.squeezed |= self.ceiling.over(loads)  # the squeeze's limit: that finger stops
        elif over is not None:
            # a guarded move stopped by the ceiling stopped on a contact too (its trip names
            # the sensors that crossed; the result's sensors are those firing at the hold)
            trip = None
            if move is not None and move.guard is not None and over.code == R.FORCE_LIMIT:
                trip = Trip(move.guard.fired(self.hand.pads(), tips))
            self.stop_move(over.code, over.check, over.message, trip)
            self.stop_hand(over.code, over.check, over.message)
        elif move is not None and move.guard is not None:  # derived pads: read afresh per sample
            trip = move.guard.check_sensors(self.hand.pads(), tips, self.hand.derive_pads)
            if trip is not None:
                self.stop_move(R.NONE, "contact", trip.describe(SENSOR_NAMES), trip, only=move)

    def on_sensor_fault(self, finger: int, kind: str, detail: str) -> None:
        """A Net F/T fault: the arm holds and the hand stops. A status word is first answered
        with RESET_THRESHOLD_LATCH (a latched threshold bit clears; goals run again once the
        stream has been clean for BRIDGE.sensor_fault_hold); one that persists after the reset
        is a real condition of the box, and the refusal says so."""
        now = time.monotonic()
        message = f"fingertip{finger + 1} Net F/T {kind}: {detail}"
        if kind == "status":
            since_reset = now - self._latch_reset_s[finger]
            if since_reset > BRIDGE.sensor_fault_hold:
                self._latch_reset_s[finger] = now
                self.sensors.reset_latch(finger)
                message += " (RESET_THRESHOLD_LATCH sent)"
            else:
                message += (
                    f", still there {since_reset:.2f} s after RESET_THRESHOLD_LATCH: a condition "
                    "of the box, not a latched threshold (its status page says which)"
                )
        self.sensor_fault(message)

    def sensor_fault(self, message: str) -> None:
        """A sensor stream's fault: the arm holds, the hand stops, and commands are refused
        until the stream has been clean for BRIDGE.sensor_fault_hold."""
        self._sensor_fault_s = time.monotonic()
        self._sensor_fault = message
        self.get_logger().warning(message, throttle_duration_sec=1.0)
        self.stop_all(SafetyCode.SENSOR_FAULT, "sensor", message)

    def on_tactile(self, msg: TactilePressureArray) -> None:
        """Barrett's tactile pucks → the pads (rrg_hw_bridge.tactile); a malformed message is
        a sensor fault."""
        try:
            pads = pads_from_pucks([puck.pressure for puck in msg.tactile_pressures])
        except TactileError as exc:
            topic = self.get_parameter("tactile_topic").value
            self.sensor_fault(f"tactile pucks on {topic}: {exc}")
            return
        self.on_pads(pads)

    def on_driver_pads(self, msg: ContactPads) -> None:
        self.on_pads(np.asarray(msg.force, dtype=float))

    def on_pads(self, forces: np.ndarray) -> None:
        """A pad sample (7,) [N]: fed to the watchdog, and to the running guarded move."""
        self.watchdog.feed("pads", time.monotonic())
        self._pad_count += 1
        self.hand.set_pads(forces)
        move = self._move
        if move is not None and move.guard is not None:
            trip = move.guard.check_sensors(self.hand.pads(), self.hand.tips(), True)
            if trip is not None:
                self.stop_move(R.NONE, "contact", trip.describe(SENSOR_NAMES), trip, only=move)

    def on_estop(self, msg: Bool) -> None:
        latched = self.estop.on_message(bool(msg.data), time.monotonic())
        if msg.data:
            self.emergency_stop("E-stop engaged", latched)

    def emergency_stop(self, why: str, latched: bool) -> None:
        """The E-stop latched (``latched``: just now): the arm holds and every hand motor
        stops, whether or not a command runs."""
        self.stop_move(SafetyCode.ESTOP, "estop", why)
        if latched:
            if not self.stop_hand(SafetyCode.ESTOP, "estop", why):  # no command ran: stop anyway
                self.hand_driver.stop(self.measured().hand_q[0])
            self.report(SafetyCode.ESTOP, "estop", f"{why}: holding", refused=False)

    def on_watchdog(self) -> None:
        now = time.monotonic()
        stalled = now - self._watchdog_tick_s > WATCHDOG_SELF_STALL * self.watchdog_timeout
        self._watchdog_tick_s = now
        if stalled and not self._watchdog_skipped:  # the bridge was not running: read first
            self._watchdog_skipped = True
            self.estop.resumed(now)  # a heartbeat that stalled with it gets a whole timeout
            return
        self._watchdog_skipped = False
        if self._arm_at is not None and now >= self._arm_at:
            self._arm_at = None
            if self.estop.reason == EStop.NOT_ARMED:  # no E-stop came meanwhile
                armed, message = self.estop.reset(now)
                if armed:
                    self.get_logger().info("armed (arm_on_start)")
                else:
                    self.get_logger().warning(f"arm_on_start did not arm: {message}")
        if self.estop.check_heartbeat(now):
            self.emergency_stop(self.estop.reason, True)
        stale = self.watchdog.stale(now)
        if stale and stale != self._stale:
            self.get_logger().error(f"watchdog: no fresh data from {', '.join(stale)}")
        elif not stale and self._stale:
            self.get_logger().info("watchdog: every stream is fresh again")
        self._stale = stale
        if stale:
            self.stop_all(SafetyCode.STALE_DATA, "watchdog", self.stale_message(stale))

    # ------------------------------------------------------------------ upward state
    def measured(self) -> Measured:
        with self._lock:
            m = self._measured
            return Measured(
                m.arm_q.copy(),
                m.arm_v.copy(),
                m.arm_effort,
                m.hand_q.copy(),
                m.hand_v.copy(),
                m.received_s,
                m.hand_count,
                m.hand_stamp_s,
            )

    def effort_baseline(self) -> np.ndarray | None:
        """(7,) mean of the arm's recent joint efforts [N m] (EFFORT_BASELINE_SAMPLES), or None
        when the driver reports none."""
        with self._lock:
            if self._measured.arm_effort is None or not self._efforts:
                return None
            return np.mean(self._efforts, axis=0)

    def joint_state(self) -> JointState:
        m = self.measured()
        msg = JointState(
            name=[*ARM_JOINT_NAMES, *HAND_JOINT_NAMES],
            position=np.r_[m.arm_q, m.hand_q].tolist(),
            velocity=np.r_[m.arm_v, m.hand_v].tolist(),
        )
        msg.header.stamp = self.get_clock().now().to_msg()
        return msg

    def publish_state(self) -> None:
        m = self.measured()
        if not np.isfinite(m.arm_q).all():
            return
        js = self.joint_state()
        self.state_pubs.publish_joints(js)
        tips = self.hand.tips()
        for i, pub in enumerate(self.state_pubs.wrenches):
            w = WrenchStamped()
            w.header.stamp, w.header.frame_id = js.header.stamp, f"bh_f{i + 1}_tip"
            w.wrench.force, w.wrench.torque = vector_to_msg(tips[i, :3]), vector_to_msg(tips[i, 3:])
            pub.publish(w)
        pads = self.hand.pads()
        msg = ContactPads(in_contact=[bool(f) for f in self.hand.fired()[:7]], force=pads.tolist())
        msg.header.stamp, msg.header.frame_id = js.header.stamp, "bh_palm"
        self.state_pubs.pads.publish(msg)

    def publish_status(self) -> None:
        """Once a second on bridge/status: the drivers' stream rates and the safety state; a
        silent Net F/T box is asked to stream again."""
        revived = self.sensors.revive(BRIDGE.rdt_revive_after)
        if revived:
            self.get_logger().warning(
                f"no data from {', '.join(revived)}: asked again to stream",
                throttle_duration_sec=10.0,
            )
        now, count, pads = time.monotonic(), self._joint_count, self._pad_count
        then, before, pads_before = self._status_last
        self._status_last = (now, count, pads)
        values = {
            "joint_states": f"{(count - before) / (now - then):.0f} Hz",
            "pads": "derived from the fingertips"
            if self.hand.derive_pads
            else f"{(pads - pads_before) / (now - then):.0f} Hz",
            **self.sensors.status(),
            "estop": self.estop.reason or "armed",
            "stale": ", ".join(self.watchdog.stale(now)) or "none",
            "dry_run": str(self.dry_run),
            "speed_scale": f"{self.speed_scale:g}",
            "interfaces": self.describe_interfaces(),
        }
        refusal = self.gate()
        status = DiagnosticStatus(
            level=DiagnosticStatus.OK if refusal is None else DiagnosticStatus.WARN,
            name=f"{NODE_NAME}/status",
            message="ready" if refusal is None else refusal.message,
            hardware_id="wam",
            values=[KeyValue(key=k, value=v) for k, v in values.items()],
        )
        self.status_pub.publish(status)
        self.publish_diagnostics(status)

    def wait_joint_state(self, timeout: float) -> None:
        with self._joint_event:
            self._joint_event.wait(timeout)

    def ros_time(self) -> float:
        """The node's clock now [s] (the time drivers stamp their messages with)."""
        return self.get_clock().now().nanoseconds * 1e-9

    def hand_states(
        self, since_s: float, timeout_s: float, what: str
    ) -> Iterator[tuple[float, Measured]]:
        """Each driver joint state with hand joints measured since ``since_s`` (the node's
        clock [s]: when the command went out), with the time [s] on the driver's clock since
        the one before (0 for the first). A hand loop counts stalls in the driver's time on
        states that can show its command's effect, so a late, queued or bursty stream cannot
        fake a stall. A state that arrives BRIDGE.hand_stamp_grace after the start counts
        whatever its stamp (a driver whose clock is behind). Checks the safety layer's stops
        meanwhile; TimeoutError after ``timeout_s`` [s] of wall time."""
        start = time.monotonic()
        last = self.measured()
        first = True
        while time.monotonic() < start + timeout_s:
            self.wait_joint_state(0.02)
            self.check_hand_motion()
            m = self.measured()
            if m.hand_count == last.hand_count:
                continue
            if first and m.hand_stamp_s < since_s:
                if m.received_s - start < BRIDGE.hand_stamp_grace:
                    last = m
                    continue  # measured before the command: it cannot show its effect
            yield (0.0 if first else max(m.hand_stamp_s - last.hand_stamp_s, 0.0)), m
            first, last = False, m
        raise TimeoutError(f"the hand did not {what} within {timeout_s:.1f} s")

    # ------------------------------------------------------------------ guarded move
    def on_move_goal(self, goal: GuardedMove.Goal) -> GoalResponse:
        if self._move_busy.locked():
            self.get_logger().warning("guarded_move goal rejected: a move is running")
            return GoalResponse.REJECT
        return GoalResponse.ACCEPT

    def plan(self, goal: GuardedMove.Goal) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
        """(q (K,7), t (K,) [s, speed-scaled], the kept points' indices into the followed
        points, the client's point count) of a goal, refusing it (GoalError) when invalid."""
        q0 = self.measured().arm_q
        q, t = goal_via_points(goal, q0)
        keep = [0]
        for k in range(1, len(t)):
            # A point less than one control period after the last kept one is the same instant:
            # dropped if it is where that one is, refused if it jumps.
            if t[k] - t[keep[-1]] >= BRIDGE.min_segment_time:
                keep.append(k)
            elif np.abs(q[k] - q[keep[-1]]).max() > START_TOLERANCE:
                raise GoalError(
                    f"points {keep[-1]} and {k} are {np.abs(q[k] - q[keep[-1]]).max():.3f} rad "
                    f"apart within {BRIDGE.min_segment_time * 1e3:.0f} ms",
                    R.INVALID_TRAJECTORY,
                )
        if len(keep) < 2:
            raise GoalError("the trajectory does not move the arm", R.INVALID_TRAJECTORY)
        keep = np.asarray(keep)
        return q[keep], scaled_times(t[keep], self.speed_scale), keep, len(t) - 1

    def retime(self, q: np.ndarray, t: np.ndarray) -> np.ndarray:
        """Times t stretched uniformly until the velocity and acceleration limits hold (when
        ``retime`` is on and the stretch is at most ``max_slowdown``; otherwise unchanged, and
        the check refuses the trajectory)."""
        k = slowdown_to_limits(q, t, self.limits)
        if k <= 1.0 or not self.get_parameter("retime").value:
            return t
        if k > self.get_parameter("max_slowdown").value:
            return t
        self.get_logger().info(
            f"retimed: {len(q) - 1} via-points slowed {k:.2f}x to the arm's velocity and "
            f"acceleration limits ({t[-1]:.2f} s → {t[-1] * k:.2f} s)"
        )
        return t * k * (1.0 + 1e-9)

    def publish_plan(self, q: np.ndarray, t: np.ndarray) -> None:
        self.plan_pub.publish(self.arm.goal(q[1:], t[1:], BRIDGE.goal_time_tolerance).trajectory)

    def execute_guarded_move(self, handle: ServerGoalHandle) -> GuardedMove.Result:
        goal, result = handle.request, GuardedMove.Result()

        def fail(code: int, message: str, check: str, refused: bool = True):
            result.error_code, result.error_msg = int(code), message
            if refused:
                self.report(int(code), check, message, refused=True)
            handle.abort()
            return result

        with self._move_busy:
            refusal = self.gate()
            # a measured joint outside its limits refuses every goal but a slow recovery
            recovery = refusal is not None and refusal.check == "joint_limits"
            if refusal is not None and not recovery:
                return fail(refusal.code, refusal.message, refusal.check)
            try:
                q, t, keep, n_client = self.plan(goal)
            except GoalError as exc:
                return fail(exc.code, str(exc), "goal")
            if recovery:
                refusal = check_recovery(q, t, self.limits)
                if refusal is not None:
                    message = f"{self._limit_fault}; {refusal.message}"
                    return fail(refusal.code, message, refusal.check)
                self.get_logger().warning(f"recovery move: {self._limit_fault}; moving it back")
            else:
                t = self.retime(q, t)
                refusal = check_trajectory(q, t, self.limits)
                if refusal is not None:
                    return fail(refusal.code, refusal.message, refusal.check)
            self.publish_plan(q, t)
            if self.dry_run:
                return fail(
                    R.DRY_RUN,
                    f"dry run: {len(q) - 1} via-points over {t[-1]:.2f} s "
                    "validated and published on bridge/plan",
                    "dry_run",
                    refused=False,
                )
            guard = None
            effort_threshold = self.get_parameter("effort_threshold").value
            no_effort = not self.interfaces["arm_effort"]
            if goal.stop_on_contact and effort_threshold > 0.0 and no_effort:
                return fail(
                    SafetyCode.SENSOR_FAULT,
                    f"the effort guard ({effort_threshold} N m) cannot run: the driver's joint "
                    "states carry no arm efforts (missing or NaN); set effort_threshold:=0.0 "
                    "to guard on the fingertips and pads alone",
                    "effort_guard",
                )
            if goal.stop_on_contact:
                self.hand.tare()
                guard = ContactGuard(
                    goal.tip_force_threshold
                    if goal.tip_force_threshold > 0
                    else SENSING.tip_force_threshold,
                    goal.pad_force_threshold
                    if goal.pad_force_threshold > 0
                    else SENSING.pad_force_threshold,
                    self.get_parameter("effort_threshold").value,
                    bool(self.get_parameter("confirm_stops").value),
                )
                guard.start(self.effort_baseline())
            move = ActiveMove(guard)
            if recovery:
                move.recovery_excess = float(limit_excess(q[0], self.limits).max())
            with self._lock:
                self._move = move
            try:
                return self._run_move(handle, move, q, t, keep, n_client, result)
            finally:
                with self._lock:
                    self._move = None

    def _run_move(self, handle, move, q, t, keep, n_client, result) -> GuardedMove.Result:
        # The move is registered before the goal goes out, and the goal goes out through the
        # E-stop's gate: a latch either comes first (nothing is sent) or finds this move and
        # marks it, and the goal is canceled as soon as the controller has accepted it.
        try:
            arm_handle = self.arm.send(self.arm.goal(q[1:], t[1:], BRIDGE.goal_time_tolerance))
        except Latched as exc:
            result.error_code, result.error_msg = R.ESTOP, f"the E-stop is latched ({exc})"
            self.report(R.ESTOP, "estop", result.error_msg, refused=True)
            handle.abort()
            return result
        except DriverError as exc:
            result.error_code, result.error_msg = R.CONTROLLER_FAILED, str(exc)
            self.report(R.CONTROLLER_FAILED, "controller", str(exc), refused=True)
            handle.abort()
            return result
        if self.estop.engaged:  # latched while the controller accepted the goal
            self.stop_move(SafetyCode.ESTOP, "estop", "E-stop engaged")
        with self._lock:
            move.handle = arm_handle
            stopped = move.code is not None
        if stopped:  # a stop arrived while the goal was on its way
            arm_handle.cancel_goal_async()
        answer = arm_handle.get_result_async()
        deadline = time.monotonic() + t[-1] + BRIDGE.goal_time_tolerance + 5.0
        escalated = False
        while not answer.done():
            if handle.is_cancel_requested or not self.context.ok():
                self.stop_move(R.CANCELED, "canceled", "canceled by the client")
            if time.monotonic() > deadline:
                self.stop_move(R.TIMEOUT, "timeout", "the controller did not finish in time")
            self.wait_joint_state(0.01)
            since_stop = time.monotonic() - move.stopped_s
            if move.code is not None and since_stop > BRIDGE.cancel_escalation and not escalated:
                escalated = True
                self.escalate(move)
            if move.code is not None and since_stop > BRIDGE.cancel_escalation + 2.0:
                break  # the controller answers neither its cancel nor the hold
        self.settle()
        m = self.measured()
        index = path_index(q, m.arm_q)
        original = float(np.interp(index, np.arange(len(keep)), keep))
        result.path_fraction = client_fraction(original, n_client)
        reading = self.hand.reading()
        result.sensors = [bool(f) for f in reading.fired]
        result.tip_contacts = tip_contacts_to_msg(
            reading.tip_points, reading.tip_normals, self.hand.tips()
        )
        result.final_joint_state = self.joint_state()
        result.stopped_on_contact = move.trip is not None
        controller = answer.result().result if answer.done() else None
        if move.code is None and controller is not None and controller.error_code != 0:
            result.error_code = R.CONTROLLER_FAILED
            result.error_msg = (
                f"the controller aborted ({controller.error_code}): {controller.error_string}"
            )
            self.report(R.CONTROLLER_FAILED, "controller", result.error_msg, refused=False)
            handle.abort()
        elif move.code is None or move.code == R.NONE:
            if move.guard is not None:
                result.unconfirmed_stops = move.guard.confirmation.rejected
                if move.guard.effort_threshold > 0.0 and move.trip is None:
                    self.get_logger().info(
                        f"guarded move: peak effort change {move.guard.peak_effort_change:.2f}"
                        f" N m (joint {move.guard.peak_effort_joint + 1}) of the "
                        f"{move.guard.effort_threshold} N m threshold"
                    )
            if move.trip is not None:
                self.get_logger().info(
                    f"guarded move stopped at {result.path_fraction:.2f} of its path: "
                    f"{move.message}"
                )
            handle.succeed()
        elif move.code == R.CANCELED:
            result.error_code, result.error_msg = R.CANCELED, "canceled"
            handle.canceled()
        else:
            result.error_code, result.error_msg = int(move.code), move.message
            handle.abort()
        return result

    def escalate(self, move: ActiveMove) -> None:
        """The controller has not ended a canceled goal in time: hold the arm where it is
        measured, and declare a robot fault that refuses every command until reset."""
        self.arm.hold(self.measured().arm_q, BRIDGE.hold_time)
        what = (
            f"the controller ignored a cancel ({move.message}) for "
            f"{BRIDGE.cancel_escalation:.1f} s; a hold was sent"
        )
        self.estop.latch_fault(what, time.monotonic())
        move.message = f"{move.message}; {what}: robot fault, reset to go on"
        self.report(SafetyCode.CONTROLLER_FAILED, "controller", what, refused=False)

    def settle(self) -> None:
        """Wait until the arm has stopped (every joint slower than BRIDGE.settle_speed)."""
        deadline = time.monotonic() + BRIDGE.settle_timeout
        while time.monotonic() < deadline:
            if np.abs(self.measured().arm_v).max() < BRIDGE.settle_speed:
                return
            self.wait_joint_state(0.01)

    # ------------------------------------------------------------------ hand
    @keep_serving
    def on_hand_command(
        self, req: HandCommand.Request, resp: HandCommand.Response
    ) -> HandCommand.Response:
        Q = HandCommand.Request
        proximal = np.asarray(req.proximal, dtype=float)
        if check_hand_command(req, resp):
            refusal = self.gate()
            if refusal is not None:
                resp.error_code, resp.error_msg = H.REFUSED, refusal.message
                self.report(refusal.code, refusal.check, f"hand command: {refusal.message}", True)
            elif self.dry_run:
                resp.error_code, resp.error_msg = H.REFUSED, "dry run: the hand is not commanded"
        if resp.error_code != H.NONE:
            self.get_logger().warning(f"hand_command refused: {resp.error_msg}")
            return resp
        with self._hand_busy:
            motion = HandMotion()
            with self._lock:
                self._hand_motion = motion
            try:
                if req.mode == Q.MODE_POSITION:
                    self.move_hand(req.spread, proximal)
                elif req.mode == Q.MODE_OPEN:
                    self.move_hand(req.spread, np.zeros(3))
                else:
                    m = self.measured()
                    if abs(req.spread - m.hand_q[0]) > SPREAD_TOLERANCE:
                        self.move_hand(req.spread, m.hand_q[2:5])
                    touched = self.close_hand(req.mode == Q.MODE_CLOSE_GUARDED)
                    resp.touched = [bool(f) for f in touched]
            except HandStopped as exc:  # the answer still says where the hand stopped
                resp.error_code, resp.error_msg = H.STOPPED, str(exc)
            except Latched as exc:
                resp.error_code, resp.error_msg = H.REFUSED, str(exc)
                self.report(SafetyCode.ESTOP, "estop", f"hand command: {exc}", refused=True)
                return resp
            except DriverError as exc:
                resp.error_code, resp.error_msg = H.DRIVER_FAILED, str(exc)
                self.get_logger().error(f"hand_command failed: {exc}")
                return resp
            except TimeoutError as exc:
                resp.error_code, resp.error_msg = H.TIMEOUT, str(exc)
                return resp
            finally:
                with self._lock:
                    self._hand_motion = None
        reading = self.hand.reading()
        resp.sensors = [bool(f) for f in reading.fired]
        resp.tip_contacts = tip_contacts_to_msg(
            reading.tip_points, reading.tip_normals, self.hand.tips()
        )
        resp.joint_state = self.joint_state()
        return resp

    def move_hand(self, spread: float, proximal: np.ndarray) -> None:
        """Move the spread and the proximal joints to their targets [rad] and wait until they
        are there or have stopped (e.g. on the object) for BRIDGE.hand_still_time of the
        driver's time."""
        since = self.ros_time()
        self.hand_driver.move_spread(spread)
        self.hand_driver.move_fingers(proximal)
        target = np.r_[spread, proximal]
        travel = np.abs(target - self.measured().hand_q[[0, 2, 3, 4]])
        speed = np.r_[PHYSICS.spread_speed, np.full(3, HAND.close_speed)]
        timeout = float(np.max(travel / speed)) + 2.0
        still = 0.0  # [s] of driver time every commanded joint has been slow
        what = f"reach {np.round(target, 3).tolist()} rad"
        for dt, m in self.hand_states(since, timeout, what):
            q, v = m.hand_q[[0, 2, 3, 4]], m.hand_v[[0, 2, 3, 4]]
            if np.all(np.abs(q - target) < BRIDGE.hand_position_tolerance):
                return
            still = still + dt if np.all(np.abs(v) < PHYSICS.stall_speed) else 0.0
            if still > BRIDGE.hand_still_time:
                return

    def close_hand(self, guarded: bool) -> np.ndarray:
        """Close every finger until it stops (rrg_models.hand_sensing.FingerClosing, as the
        simulator's closing, fed each driver joint state on the driver's clock); returns the
        sensors (10,) fired at any time while closing."""
        closing = FingerClosing(guarded)
        self._hand_motion.closing = True  # the ceiling now limits each finger's squeeze
        velocity = np.full(3, closing.speed)
        since = self.ros_time()
        self.command_fingers(velocity, wait=True)
        sent = time.monotonic()
        # the driver's clock bounds the closing; the wall clock only a driver that stalls
        states = self.hand_states(since, 2.0 * closing.timeout + 2.0, "finish closing")
        try:
            for dt, m in states:
                now = time.monotonic()
                new = closing.update(dt, m.hand_v[2:5], self.hand.fired())
                squeezed = self._hand_motion.squeezed & ~closing.stopped
                if squeezed.any():
                    self.get_logger().info(
                        f"fingers {(np.nonzero(squeezed)[0] + 1).tolist()} stopped at the force "
                        "ceiling while closing"
                    )
                    closing.stopped |= squeezed
                    new = new | squeezed
                if closing.done or closing.elapsed >= closing.timeout:
                    break
                if new.any():
                    velocity[closing.stopped] = 0.0
                    self.command_fingers(velocity, wait=False)
                    sent = now
                elif now - sent > BRIDGE.finger_command_period:
                    self.command_fingers(velocity, wait=False)
                    sent = now
        finally:
            states.close()
            self.hand_driver.finger_velocities(np.zeros(3))
        return closing.touched

    def command_fingers(self, velocity: np.ndarray, wait: bool) -> None:
        """Send the closing loop's finger velocities, unless the safety layer has stopped the
        hand: checked and sent under the lock a stop takes, so no command follows a stop."""
        with self._hand_command_lock:
            self.check_hand_motion()
            self.hand_driver.finger_velocities(velocity, wait=wait)

    def check_hand_motion(self) -> None:
        """HandStopped when the safety layer stopped the running hand command (the E-stop, the
        force ceiling, the watchdog, a sensor fault or a joint-limit fault)."""
        motion = self._hand_motion
        if motion is not None and motion.code is not None:
            raise HandStopped(motion.code, f"stopped by the safety layer: {motion.message}")
        if self.estop.engaged:  # a latch that came before this motion registered
            self.stop_hand(SafetyCode.ESTOP, "estop", f"E-stop latched ({self.estop.reason})")
            raise HandStopped(SafetyCode.ESTOP, f"the E-stop is latched ({self.estop.reason})")

    # ------------------------------------------------------------------ services
    @keep_serving
    def on_reset_estop(self, req: Trigger.Request, resp: Trigger.Response) -> Trigger.Response:
        resp.success, resp.message = self.estop.reset()
        # one severity per call site: rclpy raises "Logger severity cannot be changed between
        # calls" when one line logs at two
        if resp.success:
            self.get_logger().info(f"E-stop reset: {resp.message}")
        else:
            self.get_logger().warning(f"E-stop reset: {resp.message}")
        return resp

    @keep_serving
    def on_bias(self, req: Trigger.Request, resp: Trigger.Response) -> Trigger.Response:
        if self._move is not None:
            resp.success, resp.message = False, "a move is running; bias only an unloaded hand"
        else:
            requested_s = time.monotonic()
            self.sensors.bias()
            if self.sensors.biased_by_box:  # tare on records that carry the box's new bias
                fresh_s = requested_s + BIAS_SETTLE_S
                names = [f"fingertip{i + 1}" for i in range(3)]
                deadline = time.monotonic() + BIAS_TIMEOUT_S
                while time.monotonic() < deadline and any(
                    self.watchdog.newest(n) < fresh_s for n in names
                ):
                    time.sleep(0.002)
                late = [n for n in names if self.watchdog.newest(n) < fresh_s]
                if late:
                    resp.success = False
                    resp.message = (
                        f"biased, but no record from {', '.join(late)} within "
                        f"{BIAS_TIMEOUT_S:.1f} s after it: not tared"
                    )
            if not resp.message:
                self.hand.tare()
                resp.success, resp.message = True, f"biased {self.sensors.describe()}"
        self.get_logger().info(f"bias: {resp.message}")
        return resp

    def _spin_io(self) -> None:
        """Spin the I/O node until shutdown. A callback that fails is logged and the spinning
        goes on (the watchdog and the E-stop run here); during shutdown its publishers' context
        is gone (RCLError), which ends the loop quietly."""
        while not self._closing.is_set() and self.context.ok():
            try:
                self._io_executor.spin_once(timeout_sec=0.05)
            except (ExternalShutdownException, KeyboardInterrupt):
                break
            except Exception as exc:
                if self._closing.is_set() or not self.context.ok():
                    break
                self.get_logger().error(f"I/O callback failed: {type(exc).__name__}: {exc}")

    def destroy_node(self) -> None:
        self._closing.set()
        self._io_thread.join(timeout=1.0)
        self.sensors.stop()
        self._io_executor.shutdown(timeout_sec=1.0)
        self.io.destroy_node()
        destroy_action_endpoints(self)
        super().destroy_node()


def main(argv: list[str] | None = None) -> int:
    return run_node(BridgeNode, multi_threaded=True, argv=argv)


if __name__ == "__main__":
    sys.exit(main())
