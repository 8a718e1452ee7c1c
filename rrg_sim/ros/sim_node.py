r"""The simulated arm/hand interface (design §7): the MuJoCo world behind the same ROS interface a
hardware bridge offers, plus simulation-only reset and evaluation.

    python -m rrg_sim.ros.sim_node \
        [--ros-args -p object_name:=powerdrill -p seed:=0 -p real_time_factor:=0.0]

Publishes (every 1/state_rate s of wall time, also during motions): ``/rrg/joint_states``
(sensor_msgs/JointState, arm and hand), ``/rrg/fingertip{1,2,3}/wrench``
(geometry_msgs/WrenchStamped, each Nano17 in its own frame), ``/rrg/contact_pads``
(rrg_msgs/ContactPads), and, for evaluation only (the estimator never reads it),
``/rrg/eval/object_pose`` (geometry_msgs/PoseStamped, the true object pose). These state
readings are noise-free; guarded moves and hand commands use the noisy sensors.

Serves ``/rrg/guarded_move`` (rrg_msgs/GuardedMove: timed joint via-points, stopping at the
first pad or Nano17 over its threshold; cancellable), ``/rrg/hand_command``
(rrg_msgs/HandCommand), and, simulation only, ``/rrg/reset_sim`` (rrg_msgs/ResetSim: place an
object, arm home) and ``/rrg/eval/judge_grasp`` (std_srvs/Trigger: lift and hold the grasp
the last goal WRT on ``/rrg/observation`` left, judge it against the ground truth, and publish
the judgement on ``/rrg/eval/grasp_outcome``, rrg_msgs/GraspOutcome).

The world is stepped inside the action and service callbacks under one lock; a
MultiThreadedExecutor keeps the node responsive meanwhile, and the state topics are published
from inside the stepping loop.
"""

from __future__ import annotations

import sys
import threading
import time
from collections.abc import Callable

import numpy as np
from geometry_msgs.msg import PoseStamped, WrenchStamped
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.action.server import ServerGoalHandle
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_msgs.msg import Header
from std_srvs.srv import Trigger

from rrg_msgs.action import GuardedMove
from rrg_msgs.msg import ContactPads, GraspOutcome
from rrg_msgs.msg import Observation as ObservationMsg
from rrg_msgs.srv import HandCommand, ResetSim
from rrg_sim.executor.trajectory import DensePath, sample_times
from rrg_sim.ros_common.msg_conversions import (
    ARM_JOINT_NAMES,
    WORLD_FRAME,
    observation_from_msg,
    planar_from_msg,
    planar_to_msg,
    pose_to_msg,
    tip_contacts_to_msg,
    vector_to_msg,
)
from rrg_sim.ros_common.node_main import keep_serving, run_node

from .. import wam
from ..config import HAND, PHYSICS, SENSING, WORLD
from ..objects import OBJECT_NAMES
from ..physics.judge import judge_grasp
from ..physics.mjcf_robot import TIP_BODIES
from ..physics.sensing import HandSensors
from ..physics.world import PhysicsWorld

NODE_NAME = "sim"
NAMESPACE = "rrg"
#: Largest distance [rad] between the arm and a trajectory's first via-point at time 0.
START_TOLERANCE = 0.05
#: A close command moves the spread first only when it is this far from the request [rad].
SPREAD_TOLERANCE = 0.01
#: Control periods between checks of pacing, publishing and cancellation (20 ms simulated).
CHECK_EVERY = 10


def client_fraction(index: float, n: int) -> float:
    """Fraction [0, 1] of a client's n via-points done at fractional index ``index`` of the
    followed points (the arm's configuration prepended to the client's)."""
    return float(np.clip(index if n == 1 else (index - 1.0) / (n - 1), 0.0, 1.0))


def ros_joint_name(mujoco_name: str) -> str:
    """'wam/j1' → 'wam_j1' (ROS joint names carry no slashes)."""
    return mujoco_name.replace("/", "_")


class SimNode(Node):
    """One PhysicsWorld behind the arm/hand interface."""

    def __init__(self) -> None:
        super().__init__(NODE_NAME, namespace=NAMESPACE)
        self.declare_parameter(
            "object_name",
            "powerdrill",
            ParameterDescriptor(
                description=f"Object in the scene at start ({', '.join(OBJECT_NAMES)}); "
                "reset_sim may change it"
            ),
        )
        self.declare_parameter(
            "seed",
            0,
            ParameterDescriptor(
                description="Seed of the sensor noise",
                read_only=True,
                integer_range=[IntegerRange(from_value=0, to_value=2**31 - 1, step=1)],
            ),
        )
        self.declare_parameter(
            "sensor_noise",
            1.0,
            ParameterDescriptor(
                description="Scale of every sensor's noise sigma (1: config values, 0: noiseless)",
                read_only=True,
                floating_point_range=[FloatingPointRange(from_value=0.0, to_value=10.0)],
            ),
        )
        self.declare_parameter(
            "state_rate",
            50.0,
            ParameterDescriptor(
                description="Rate [Hz, wall time] of joint states, wrenches, pads "
                "and the true pose",
                floating_point_range=[FloatingPointRange(from_value=1.0, to_value=500.0)],
            ),
        )
        self.declare_parameter(
            "real_time_factor",
            0.0,
            ParameterDescriptor(
                description="Simulated seconds per wall second (1: real time); "
                "0: as fast as it steps",
                floating_point_range=[FloatingPointRange(from_value=0.0, to_value=100.0)],
            ),
        )
        self.frame_id = WORLD_FRAME
        self._lock = threading.Lock()
        self._move_active = False
        self._last_observation: ObservationMsg | None = None
        self.world = self._make_world(self.get_parameter("object_name").value)
        group = ReentrantCallbackGroup()
        self.joint_pub = self.create_publisher(JointState, "joint_states", 10)
        self.wrench_pubs = [
            self.create_publisher(WrenchStamped, f"fingertip{i}/wrench", 10) for i in (1, 2, 3)
        ]
        self.pads_pub = self.create_publisher(ContactPads, "contact_pads", 10)
        self.truth_pub = self.create_publisher(PoseStamped, "eval/object_pose", 10)
        self.outcome_pub = self.create_publisher(GraspOutcome, "eval/grasp_outcome", 10)
        self.create_subscription(
            ObservationMsg, "observation", self.on_observation, 10, callback_group=group
        )
        self.create_service(ResetSim, "reset_sim", self.on_reset_sim, callback_group=group)
        self.create_service(HandCommand, "hand_command", self.on_hand_command, callback_group=group)
        self.create_service(Trigger, "eval/judge_grasp", self.on_judge_grasp, callback_group=group)
        ActionServer(
            self,
            GuardedMove,
            "guarded_move",
            execute_callback=self.execute_guarded_move,
            goal_callback=self.on_move_goal,
            cancel_callback=lambda _: CancelResponse.ACCEPT,
            callback_group=group,
        )
        self.create_timer(
            1.0 / self.get_parameter("state_rate").value, self.on_idle_timer, callback_group=group
        )
        self.get_logger().info(
            f"simulator ready: {self.world.obj.name} at "
            f"{np.round(self.world.true_object_pose(), 3).tolist()}"
        )

    def _make_world(self, object_name: str) -> PhysicsWorld:
        world = PhysicsWorld(
            object_name,
            seed=self.get_parameter("seed").value,
            sensor_noise=self.get_parameter("sensor_noise").value,
        )
        m = world.model
        robot = [j for j in range(m.njnt) if m.joint(j).name.startswith(("wam/", "bh/"))]
        self._joint_names = [ros_joint_name(m.joint(j).name) for j in robot]
        self._qadr = np.array([m.jnt_qposadr[j] for j in robot])
        self._vadr = np.array([m.jnt_dofadr[j] for j in robot])
        self._state_sensors = HandSensors(m, world.data, np.random.default_rng(0), noise=0.0)
        return world

    # ------------------------------------------------------------------ state
    def joint_state(self) -> JointState:
        msg = JointState(
            name=self._joint_names,
            position=self.world.data.qpos[self._qadr].tolist(),
            velocity=self.world.data.qvel[self._vadr].tolist(),
        )
        msg.header.stamp = self.get_clock().now().to_msg()
        return msg

    def publish_state(self) -> None:
        """Joint states, fingertip wrenches, pads and the true object pose (call under the lock)."""
        stamp = self.get_clock().now().to_msg()
        js = self.joint_state()
        js.header.stamp = stamp
        self.joint_pub.publish(js)
        self._state_sensors.bias = self.world.sensors.bias  # the same tare as the guarded moves
        pads, wrench = self._state_sensors.read()
        for i, pub in enumerate(self.wrench_pubs):
            w = WrenchStamped()
            w.header.stamp, w.header.frame_id = stamp, ros_joint_name(TIP_BODIES[i])
            w.wrench.force, w.wrench.torque = (
                vector_to_msg(wrench[i, :3]),
                vector_to_msg(wrench[i, 3:]),
            )
            pub.publish(w)
        p = ContactPads(
            in_contact=[bool(f) for f in pads > SENSING.pad_force_threshold], force=pads.tolist()
        )
        p.header.stamp, p.header.frame_id = stamp, ros_joint_name("bh/palm")
        self.pads_pub.publish(p)
        truth = PoseStamped(pose=pose_to_msg(self.world.object_pose()))
        truth.header.stamp, truth.header.frame_id = stamp, self.frame_id
        self.truth_pub.publish(truth)

    def on_idle_timer(self) -> None:
        if self._lock.acquire(blocking=False):  # a running motion publishes by itself
            try:
                self.publish_state()
            finally:
                self._lock.release()

    def monitor(
        self,
        interrupted: Callable[[], bool] | None = None,
        on_tick: Callable[[], None] | None = None,
    ) -> Callable[[], bool]:
        """The per-period callback of a motion: every CHECK_EVERY periods it paces the
        simulation (real_time_factor), publishes the state (state_rate) and asks
        ``interrupted()`` whether to stop."""
        rtf = self.get_parameter("real_time_factor").value
        period = 1.0 / self.get_parameter("state_rate").value
        wall0, sim0 = time.monotonic(), self.world.sim_time
        last = [0.0]
        count = [0]

        def check() -> bool:
            count[0] += 1
            if count[0] % CHECK_EVERY:
                return False
            now = time.monotonic()
            if rtf > 0.0:
                ahead = (self.world.sim_time - sim0) / rtf - (now - wall0)
                if ahead > 0.0:
                    time.sleep(ahead)
            if now - last[0] >= period:
                last[0] = now
                self.publish_state()
                if on_tick is not None:
                    on_tick()
            return bool(interrupted and interrupted())

        return check

    # ------------------------------------------------------------------ guarded move
    def on_move_goal(self, goal: GuardedMove.Goal) -> GoalResponse:
        if self._move_active:
            self.get_logger().warn("guarded_move goal rejected: a move is running")
            return GoalResponse.REJECT
        return GoalResponse.ACCEPT

    def via_points(self, goal: GuardedMove.Goal) -> tuple[np.ndarray, np.ndarray]:
        """(q (M,7), t (M,)) of a goal, the arm's current configuration prepended at t = 0;
        ValueError (with the GuardedMove error code as args[1]) when invalid."""
        R = GuardedMove.Result
        traj = goal.trajectory
        if sorted(traj.joint_names) != sorted(ARM_JOINT_NAMES) or len(traj.joint_names) != 7:
            raise ValueError(
                f"joint_names must be the 7 arm joints {list(ARM_JOINT_NAMES)}, got "
                f"{list(traj.joint_names)}",
                R.INVALID_TRAJECTORY,
            )
        if not traj.points:
            raise ValueError("the trajectory has no points", R.INVALID_TRAJECTORY)
        if any(len(p.positions) != 7 for p in traj.points):
            raise ValueError("every point needs 7 positions", R.INVALID_TRAJECTORY)
        order = [list(traj.joint_names).index(n) for n in ARM_JOINT_NAMES]
        q = np.array([np.asarray(p.positions)[order] for p in traj.points])
        t = np.array(
            [p.time_from_start.sec + 1e-9 * p.time_from_start.nanosec for p in traj.points]
        )
        if not np.all(np.isfinite(q)):
            raise ValueError("non-finite positions", R.INVALID_TRAJECTORY)
        if not np.all(wam.within_limits(q)):
            bad = int(np.argmin(wam.within_limits(q)))
            raise ValueError(
                f"point {bad} is outside the joint limits: {np.round(q[bad], 3).tolist()}",
                R.JOINT_LIMITS,
            )
        if np.any(np.diff(t) < 0.0):
            raise ValueError("time_from_start must not decrease", R.INVALID_TRAJECTORY)
        q0 = self.world.arm_q()
        q = np.vstack([q0, q])
        if not np.any(t > 0.0):  # no timing: the server's default speeds
            return q, sample_times(DensePath(wam.fk(q), q, np.zeros(len(q), int)))
        if t[0] == 0.0 and np.abs(q[1] - q0).max() > START_TOLERANCE:
            raise ValueError(
                "the first point is away from the arm's configuration at time 0",
                R.INVALID_TRAJECTORY,
            )
        return q, np.r_[0.0, t]

    def execute_guarded_move(self, handle: ServerGoalHandle) -> GuardedMove.Result:
        goal, result = handle.request, GuardedMove.Result()
        for name, value, default in (
            ("tip_force_threshold", goal.tip_force_threshold, SENSING.tip_force_threshold),
            ("pad_force_threshold", goal.pad_force_threshold, SENSING.pad_force_threshold),
        ):
            if value > 0.0 and not np.isclose(value, default):
                result.error_code = GuardedMove.Result.INVALID_TRAJECTORY
                result.error_msg = (
                    f"{name}: the simulator's thresholds are fixed at {default} N (config.SENSING)"
                )
                handle.abort()
                return result
        self._move_active = True
        canceled = False
        try:
            with self._lock:
                try:
                    q, t = self.via_points(goal)
                except ValueError as exc:
                    result.error_code, result.error_msg = exc.args[1], exc.args[0]
                    handle.abort()
                    return result
                n, start = len(q) - 1, self.world.sim_time  # n: the client's points

                def feedback() -> None:
                    index = float(np.interp(self.world.sim_time - start, t, np.arange(len(t))))
                    handle.publish_feedback(
                        GuardedMove.Feedback(
                            path_fraction=client_fraction(index, n),
                            current_point=min(n - 1, int(np.ceil(index - 1))),
                        )
                    )

                interrupted = lambda: handle.is_cancel_requested or not self.context.ok()
                stop = self.world.follow(
                    q, t, guard=goal.stop_on_contact, monitor=self.monitor(interrupted, feedback)
                )
                canceled = stop is not None and interrupted()
                result.path_fraction = client_fraction(len(q) - 1.0 if stop is None else stop, n)
                result.stopped_on_contact = stop is not None and not canceled
                self.fill_hand(result)
                result.final_joint_state = self.joint_state()
                self.publish_state()
        except Exception as exc:
            result.error_code, result.error_msg = (
                GuardedMove.Result.UNKNOWN,
                f"{type(exc).__name__}: {exc}",
            )
            self.get_logger().error(f"guarded_move failed: {result.error_msg}")
            handle.abort()
            return result
        finally:
            self._move_active = False
        if canceled:
            result.error_code, result.error_msg = GuardedMove.Result.CANCELED, "canceled"
            handle.canceled()
        else:
            handle.succeed()
        return result

    def fill_hand(self, resp) -> None:
        """Sensors and fingertip contacts of a GuardedMove result or HandCommand response."""
        reading = self.world.reading()
        _, wrench = self._state_sensors.read()
        resp.sensors = [bool(f) for f in reading.fired]
        resp.tip_contacts = tip_contacts_to_msg(reading.tip_points, reading.tip_normals, wrench)

    # ------------------------------------------------------------------ hand, reset, judge
    @keep_serving
    def on_hand_command(
        self, req: HandCommand.Request, resp: HandCommand.Response
    ) -> HandCommand.Response:
        R = HandCommand.Response
        proximal = np.asarray(req.proximal, dtype=float)
        lo, hi = HAND.proximal_range
        if req.mode not in (
            HandCommand.Request.MODE_POSITION,
            HandCommand.Request.MODE_OPEN,
            HandCommand.Request.MODE_CLOSE,
            HandCommand.Request.MODE_CLOSE_GUARDED,
        ):
            resp.error_code, resp.error_msg = R.INVALID_MODE, f"unknown mode {req.mode}"
        elif not HAND.spread_range[0] <= req.spread <= HAND.spread_range[1]:
            resp.error_code, resp.error_msg = (
                R.OUT_OF_RANGE,
                f"spread {req.spread} outside {HAND.spread_range} rad",
            )
        elif req.mode == HandCommand.Request.MODE_POSITION and not np.all(
            (proximal >= lo) & (proximal <= hi)
        ):
            resp.error_code, resp.error_msg = (
                R.OUT_OF_RANGE,
                f"proximal {proximal.tolist()} outside {(lo, hi)} rad",
            )
        if resp.error_code != R.NONE:
            self.get_logger().warn(f"hand_command refused: {resp.error_msg}")
            return resp
        with self._lock:
            monitor = self.monitor()
            if req.mode == HandCommand.Request.MODE_POSITION:
                self.world.move_hand(req.spread, proximal, monitor)
            elif req.mode == HandCommand.Request.MODE_OPEN:
                self.world.move_hand(req.spread, 0.0, monitor)
            else:
                if abs(req.spread - self.world.hand_angles()[0]) > SPREAD_TOLERANCE:
                    self.world.move_hand(req.spread, self.world.finger_angles(), monitor)
                touched = self.world.close_hand(
                    monitor, guarded=req.mode == HandCommand.Request.MODE_CLOSE_GUARDED
                )
                resp.touched = [bool(t) for t in touched]
            self.fill_hand(resp)
            resp.joint_state = self.joint_state()
            self.publish_state()
        return resp

    @keep_serving
    def on_reset_sim(self, req: ResetSim.Request, resp: ResetSim.Response) -> ResetSim.Response:
        pose = planar_from_msg(req.pose)
        if req.object_name not in OBJECT_NAMES:
            resp.error_code = ResetSim.Response.UNKNOWN_OBJECT
            resp.error_msg = f"unknown object {req.object_name!r}; valid: {list(OBJECT_NAMES)}"
        elif not (
            np.all(np.isfinite(pose))
            and WORLD.table_x[0] <= pose[0] <= WORLD.table_x[1]
            and WORLD.table_y[0] <= pose[1] <= WORLD.table_y[1]
        ):
            resp.error_code = ResetSim.Response.INVALID_POSE
            resp.error_msg = (
                f"pose {pose.tolist()} is not on the table (x {WORLD.table_x} m, "
                f"y {WORLD.table_y} m)"
            )
        if resp.error_code != ResetSim.Response.NONE:
            self.get_logger().warn(f"reset_sim refused: {resp.error_msg}")
            return resp
        with self._lock:
            if req.object_name != self.world.obj.name:
                self.world = self._make_world(req.object_name)
            self.world.reset(pose)
            self._last_observation = None
            self.publish_state()
        self.get_logger().info(
            f"reset: {req.object_name} at {np.round(pose, 4).tolist()}, arm home"
        )
        return resp

    def on_observation(self, msg: ObservationMsg) -> None:
        self._last_observation = msg

    @keep_serving
    def on_judge_grasp(self, req: Trigger.Request, resp: Trigger.Response) -> Trigger.Response:
        obs = self._last_observation
        obj = self.world.obj
        kind = (
            None
            if obs is None
            else next((w.kind for w in obj.wrts() if w.name == obs.wrt_name), None)
        )
        if obs is None:
            resp.message = "nothing to judge: no WRT observation since the last reset"
        elif obs.object_name != obj.name or kind != "goal":
            resp.message = (
                f"nothing to judge: the last WRT was {obs.object_name}/{obs.wrt_name}, "
                "not a goal grasp"
            )
        else:
            with self._lock:
                ok, info = judge_grasp(
                    self.world, obj, planar_from_msg(obs.estimate), observation_from_msg(obs)
                )
                self.publish_state()
            resp.success = bool(ok)
            resp.message = (
                f"{'SUCCESS' if ok else 'FAILURE'}: in goal region {info['in_region']} "
                f"(offset {np.round(info['delta'], 4).tolist()}), {info['fingers']} fingers in "
                f"contact, required sensors {info['required_ok']}, held {info['held']} "
                f"(lifted {info['lift_dz']:.3f} m of {PHYSICS.lift_height} m, "
                f"slip {info['slip']:.4f} m)"
            )
            self.outcome_pub.publish(
                GraspOutcome(
                    header=Header(stamp=self.get_clock().now().to_msg(), frame_id=WORLD_FRAME),
                    object_name=obj.name,
                    wrt_name=obs.wrt_name,
                    success=bool(ok),
                    in_region=bool(info["in_region"]),
                    offset=planar_to_msg(info["delta"]),
                    fingers_in_contact=int(info["fingers"]),
                    required_contacts=bool(info["required_ok"]),
                    held=bool(info["held"]),
                    lift_feasible=bool(info["lift_feasible"]),
                    lift_dz=float(info["lift_dz"]),
                    slip=float(info["slip"]),
                    early_contact=bool(info["early_contact"]),
                    true_pose=planar_to_msg(info["w_true"]),
                    message=resp.message,
                )
            )
        if resp.success:
            self.get_logger().info(f"judge_grasp: {resp.message}")
        else:
            self.get_logger().warn(f"judge_grasp: {resp.message}")
        return resp


def main(argv: list[str] | None = None) -> int:
    return run_node(SimNode, multi_threaded=True, argv=argv)


if __name__ == "__main__":
    sys.exit(main())
