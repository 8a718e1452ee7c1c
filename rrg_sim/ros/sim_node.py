r"""The simulated arm/hand interface (design §7): the MuJoCo world behind the same ROS interface a
hardware bridge offers, plus simulation-only reset and evaluation.

    python -m rrg_sim.ros.sim_node \
        [--ros-args -p object_name:=powerdrill -p seed:=0 -p real_time_factor:=0.0]

Publishes (every 1/state_rate s of wall time, also during motions): ``/rrg/joint_states``
(sensor_msgs/JointState, arm and hand), ``/rrg/fingertip{1,2,3}/wrench``
(geometry_msgs/WrenchStamped, each Nano17 in its own frame), ``/rrg/contact_pads``
(rrg_msgs/ContactPads), and, for evaluation only (the estimator never reads it),
``/rrg/eval/object_pose`` (geometry_msgs/PoseStamped, the true object pose). These state
readings are noise-free; guarded moves and hand commands use the noisy sensors. Its health
goes on ``/diagnostics`` once a second (``sim: status``, rrg_common.ros.diagnostics).

Serves ``/rrg/guarded_move`` (rrg_msgs/GuardedMove: timed joint via-points, stopping at the
first pad or Nano17 over its threshold; cancellable), ``/rrg/hand_command``
(rrg_msgs/HandCommand), and, simulation only, ``/rrg/reset_sim`` (rrg_msgs/ResetSim: place an
object, arm home) and ``/rrg/eval/judge_grasp`` (std_srvs/Trigger: lift and hold the grasp
the last goal WRT on ``/rrg/observation`` left, judge it against the ground truth, and publish
the judgement on ``/rrg/eval/grasp_outcome``, rrg_msgs/GraspOutcome): rrg_sim.ros.eval_services,
which the emulated hardware drivers share.

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
from geometry_msgs.msg import WrenchStamped
from rclpy.action import GoalResponse
from rclpy.action.server import ServerGoalHandle
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.node import Node
from sensor_msgs.msg import JointState

from rrg_common.ros.arm_hand_interface import (
    StatePublishers,
    check_hand_command,
    goal_via_points,
    serve_arm_hand_interface,
)
from rrg_common.ros.diagnostics import Health, NodeDiagnostics
from rrg_common.ros.msg_conversions import tip_contacts_to_msg, vector_to_msg
from rrg_common.ros.node_main import destroy_action_endpoints, keep_serving, run_node
from rrg_common.ros.parameters import Param, declare
from rrg_models import wam
from rrg_models.config import SENSING
from rrg_models.description.mjcf_robot import TIP_BODIES
from rrg_models.description.urdf_robot import ros_name
from rrg_models.trajectory import GoalError, client_fraction
from rrg_msgs.action import GuardedMove
from rrg_msgs.msg import ContactPads
from rrg_msgs.srv import HandCommand
from rrg_sim.config import WORLD_PROFILES, world_profile
from rrg_sim.physics.sensing import HandSensors
from rrg_sim.physics.world import PhysicsWorld, WorldsByObject
from rrg_sim.ros.eval_services import EvalServices

NODE_NAME = "sim"
NAMESPACE = "rrg"
#: A close command moves the spread first only when it is this far from the request [rad].
SPREAD_TOLERANCE = 0.01
#: Control periods between checks of pacing, publishing and cancellation (20 ms simulated).
CHECK_EVERY = 10


#: The node's parameters (rrg_common.ros.parameters).
PARAMETERS: tuple[Param, ...] = (
    Param(
        "object_name",
        "powerdrill",
        ("Installed object in the scene at start (rrg-object list); reset_sim may change it"),
    ),
    Param("seed", 0, "Seed of the sensor noise", read_only=True, low=0, high=2**31 - 1),
    Param(
        "sensor_noise",
        1.0,
        "Scale of every sensor's noise sigma (1: config values, 0: noiseless)",
        read_only=True,
        low=0.0,
        high=10.0,
    ),
    Param(
        "world_profile",
        "nominal",
        (
            "World profile (rrg_sim.config.WORLD_PROFILES: "
            f"{', '.join(WORLD_PROFILES)}); its per-trial draws come from the seed"
        ),
        read_only=True,
    ),
    Param(
        "state_rate",
        50.0,
        ("Rate [Hz, wall time] of joint states, wrenches, pads and the true pose"),
        low=1.0,
        high=500.0,
    ),
    Param(
        "real_time_factor",
        0.0,
        ("Simulated seconds per wall second (1: real time); 0: as fast as it steps"),
        low=0.0,
        high=100.0,
    ),
)


class SimNode(Node):
    """One PhysicsWorld behind the arm/hand interface."""

    def __init__(self) -> None:
        super().__init__(NODE_NAME, namespace=NAMESPACE)
        declare(self, PARAMETERS)
        self._lock = threading.Lock()
        self._move_active = False
        profile = self.get_parameter("world_profile").value
        world_profile(profile)  # ValueError for an unknown spec
        self._worlds = WorldsByObject(
            seed=self.get_parameter("seed").value,
            sensor_noise=self.get_parameter("sensor_noise").value,
            profile=profile,
        )
        self.world = self._world_of(self.get_parameter("object_name").value)
        group = ReentrantCallbackGroup()
        self.state_pubs = StatePublishers.create(self)
        self.eval = EvalServices(
            self,
            world=lambda: self.world,
            exclusive=lambda: self._lock,
            reset_world=self.reset_world,
            group=group,
            on_change=self.publish_state,
        )
        serve_arm_hand_interface(
            self, self.execute_guarded_move, self.on_move_goal, self.on_hand_command, group
        )
        self.create_timer(
            1.0 / self.get_parameter("state_rate").value, self.on_idle_timer, callback_group=group
        )
        self._paced: tuple[PhysicsWorld, float, float] | None = None  # (world, sim, wall) [s]
        self.diagnostics = NodeDiagnostics(self, self.health)
        self.get_logger().info(
            f"simulator ready: {self.world.obj.name} at "
            f"{np.round(self.world.true_object_pose(), 3).tolist()}"
        )

    def destroy_node(self) -> None:
        destroy_action_endpoints(self)
        super().destroy_node()

    def health(self) -> Health:
        """For /diagnostics: the object, the simulated time since the reset, the real-time
        factor since the last report (simulated over wall seconds; 0 while nothing moves) and
        the pace asked for, and whether a guarded move runs. Read without the lock: a
        snapshot."""
        world, wall = self.world, time.monotonic()
        sim = world.sim_time
        last, self._paced = self._paced, (world, sim, wall)
        rtf = "none yet"
        if last is not None and last[0] is world and sim >= last[1] and wall > last[2]:
            rtf = f"{(sim - last[1]) / (wall - last[2]):.2f}"
        pace = self.get_parameter("real_time_factor").value
        return Health(
            values={
                "object": world.obj.name,
                "world profile": self.get_parameter("world_profile").value,
                "simulated time since reset [s]": f"{sim:.3f}",
                "real-time factor since the last report": rtf,
                "real_time_factor parameter": f"{pace:g}" if pace else "0 (as fast as it steps)",
                "guarded move running": str(self._move_active),
            }
        )

    def _world_of(self, object_name: str) -> PhysicsWorld:
        """The (kept) world of ``object_name``, with this node's joint indices into it."""
        world = self._worlds(object_name)
        m = world.model
        robot = [j for j in range(m.njnt) if m.joint(j).name.startswith(("wam/", "bh/"))]
        self._arm_rows = np.array(
            [k for k, j in enumerate(robot) if m.joint(j).name.startswith("wam/")]
        )
        self._joint_names = [ros_name(m.joint(j).name) for j in robot]
        self._qadr = np.array([m.jnt_qposadr[j] for j in robot])
        self._vadr = np.array([m.jnt_dofadr[j] for j in robot])
        self._state_sensors = HandSensors(m, world.data, np.random.default_rng(0), noise=0.0)
        return world

    # ------------------------------------------------------------------ state
    def joint_state(self) -> JointState:
        position = self.world.data.qpos[self._qadr]
        position[self._arm_rows] = self.world.arm_q()  # as the encoders read them
        msg = JointState(
            name=self._joint_names,
            position=position.tolist(),
            velocity=self.world.data.qvel[self._vadr].tolist(),
        )
        msg.header.stamp = self.get_clock().now().to_msg()
        return msg

    def publish_state(self) -> None:
        """Joint states, fingertip wrenches, pads and the true object pose (call under the lock)."""
        stamp = self.get_clock().now().to_msg()
        js = self.joint_state()
        js.header.stamp = stamp
        self.state_pubs.publish_joints(js)
        self._state_sensors.bias = self.world.sensors.bias  # the same tare as the guarded moves
        pads, wrench = self._state_sensors.read()
        for i, pub in enumerate(self.state_pubs.wrenches):
            w = WrenchStamped()
            w.header.stamp, w.header.frame_id = stamp, ros_name(TIP_BODIES[i])
            w.wrench.force, w.wrench.torque = (
                vector_to_msg(wrench[i, :3]),
                vector_to_msg(wrench[i, 3:]),
            )
            pub.publish(w)
        p = ContactPads(
            in_contact=[bool(f) for f in pads > SENSING.pad_force_threshold], force=pads.tolist()
        )
        p.header.stamp, p.header.frame_id = stamp, ros_name("bh/palm")
        self.state_pubs.pads.publish(p)
        self.eval.publish_truth(stamp)

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
            self.get_logger().warning("guarded_move goal rejected: a move is running")
            return GoalResponse.REJECT
        return GoalResponse.ACCEPT

    def via_points(self, goal: GuardedMove.Goal) -> tuple[np.ndarray, np.ndarray]:
        """(q (M,7), t (M,)) of a goal, the arm's current configuration prepended at t = 0;
        GoalError when invalid or outside the simulated arm's joint limits."""
        q, t = goal_via_points(goal, self.world.arm_q())
        if not np.all(wam.within_limits(q)):
            bad = int(np.argmin(wam.within_limits(q))) - 1
            raise GoalError(
                f"point {bad} is outside the joint limits: {np.round(q[bad + 1], 3).tolist()}",
                GuardedMove.Result.JOINT_LIMITS,
            )
        return q, t

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
                except GoalError as exc:
                    result.error_code, result.error_msg = exc.code, str(exc)
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
                unconfirmed = self.world.unconfirmed_stops
                stop = self.world.follow(
                    q, t, guard=goal.stop_on_contact, monitor=self.monitor(interrupted, feedback)
                )
                result.unconfirmed_stops = self.world.unconfirmed_stops - unconfirmed
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

    # ------------------------------------------------------------------ hand, reset
    @keep_serving
    def on_hand_command(
        self, req: HandCommand.Request, resp: HandCommand.Response
    ) -> HandCommand.Response:
        proximal = np.asarray(req.proximal, dtype=float)
        if not check_hand_command(req, resp):
            self.get_logger().warning(f"hand_command refused: {resp.error_msg}")
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

    def reset_world(self, object_name: str, pose: np.ndarray) -> None:
        """Place ``object_name`` (its own kept world when the object changes) at the planar
        pose, arm home (call under the lock)."""
        if object_name != self.world.obj.name:
            self.world = self._world_of(object_name)
        self.world.reset(pose)


def main(argv: list[str] | None = None) -> int:
    return run_node(SimNode, multi_threaded=True, argv=argv)


if __name__ == "__main__":
    sys.exit(main())
