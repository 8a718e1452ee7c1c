"""Simulation-only reset and evaluation of a node that owns a PhysicsWorld (the simulator node and
the emulated hardware drivers, rrg_fake_hw.fake_hw_node, share it).

Serves ``reset_sim`` (rrg_msgs/ResetSim: place an object, arm home) and ``eval/judge_grasp``
(std_srvs/Trigger: lift and hold the grasp the last goal WRT on ``observation`` left, judge it
against the ground truth, and publish the judgement on ``eval/grasp_outcome``,
rrg_msgs/GraspOutcome), and publishes the true object pose on ``eval/object_pose``
(geometry_msgs/PoseStamped) when the owner asks. The names are parameters (``EvalNames``).
"""

from __future__ import annotations

from collections.abc import Callable
from contextlib import AbstractContextManager
from dataclasses import dataclass

import numpy as np
from builtin_interfaces.msg import Time
from geometry_msgs.msg import PoseStamped
from rclpy.node import Node
from std_msgs.msg import Header
from std_srvs.srv import Trigger

from rrg_common.ros.frames import OBJECT_TRUE_FRAME, TfPublisher
from rrg_common.ros.msg_conversions import (
    WORLD_FRAME,
    observation_from_msg,
    planar_from_msg,
    planar_to_msg,
    pose_to_msg,
)
from rrg_common.ros.node_main import keep_serving
from rrg_models.config import PHYSICS, WORLD
from rrg_models.objects import object_names, unknown_object_message
from rrg_msgs.msg import GraspOutcome
from rrg_msgs.msg import Observation as ObservationMsg
from rrg_msgs.srv import ResetSim
from rrg_sim.physics.judge import judge_grasp
from rrg_sim.physics.world import PhysicsWorld


@dataclass(frozen=True)
class EvalNames:
    """Service and topic names (relative to the owner's namespace unless they start with /)."""

    reset: str = "reset_sim"
    judge: str = "eval/judge_grasp"
    object_pose: str = "eval/object_pose"
    outcome: str = "eval/grasp_outcome"
    observation: str = "observation"


class EvalServices:
    """The simulation-only interfaces of one PhysicsWorld owner.

    world: returns the owner's current world. exclusive: a context manager under which the
    world may be stepped and replaced. reset_world(object_name, pose): reset the world (a new
    one for another object), called inside ``exclusive``. on_change: called inside
    ``exclusive`` after a reset or a judgement (e.g. to publish the state).
    """

    def __init__(
        self,
        node: Node,
        world: Callable[[], PhysicsWorld],
        exclusive: Callable[[], AbstractContextManager],
        reset_world: Callable[[str, np.ndarray], None],
        group,
        on_change: Callable[[], None] | None = None,
        names: EvalNames = EvalNames(),
    ):
        self.node, self.world, self.exclusive = node, world, exclusive
        self.reset_world, self.on_change = reset_world, on_change
        self.last_observation: ObservationMsg | None = None
        self.truth_pub = node.create_publisher(PoseStamped, names.object_pose, 10)
        self.tf = TfPublisher(node)  # world → object_true
        self.outcome_pub = node.create_publisher(GraspOutcome, names.outcome, 10)
        node.create_subscription(
            ObservationMsg, names.observation, self.on_observation, 10, callback_group=group
        )
        node.create_service(ResetSim, names.reset, self.on_reset_sim, callback_group=group)
        node.create_service(Trigger, names.judge, self.on_judge_grasp, callback_group=group)

    def get_logger(self):
        return self.node.get_logger()

    def publish_truth(self, stamp: Time, pose: np.ndarray | None = None) -> None:
        """The true object pose (4,4) (evaluation only; default: read from the world, so call
        where the world may be read)."""
        pose = self.world().object_pose() if pose is None else pose
        truth = PoseStamped(pose=pose_to_msg(pose))
        truth.header.stamp, truth.header.frame_id = stamp, WORLD_FRAME
        self.truth_pub.publish(truth)
        self.tf.publish([(WORLD_FRAME, OBJECT_TRUE_FRAME, pose)], stamp)

    def _changed(self) -> None:
        if self.on_change is not None:
            self.on_change()

    def on_observation(self, msg: ObservationMsg) -> None:
        self.last_observation = msg

    @keep_serving
    def on_reset_sim(self, req: ResetSim.Request, resp: ResetSim.Response) -> ResetSim.Response:
        pose = planar_from_msg(req.pose)
        if req.object_name not in object_names():
            resp.error_code = ResetSim.Response.UNKNOWN_OBJECT
            resp.error_msg = unknown_object_message(req.object_name)
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
            self.get_logger().warning(f"reset_sim refused: {resp.error_msg}")
            return resp
        with self.exclusive():
            self.reset_world(req.object_name, pose)
            self.last_observation = None
            self._changed()
        self.get_logger().info(
            f"reset: {req.object_name} at {np.round(pose, 4).tolist()}, arm home"
        )
        return resp

    @keep_serving
    def on_judge_grasp(self, req: Trigger.Request, resp: Trigger.Response) -> Trigger.Response:
        obs = self.last_observation
        obj = self.world().obj
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
            with self.exclusive():
                ok, info = judge_grasp(
                    self.world(),
                    obj,
                    planar_from_msg(obs.estimate),
                    observation_from_msg(obs),
                    goal=obs.wrt_name,
                )
                self._changed()
            resp.success = bool(ok)
            resp.message = (
                f"{'SUCCESS' if ok else 'FAILURE'}: {obs.wrt_name}, in goal region "
                f"{info['in_region']} "
                f"(offset {np.round(info['delta'], 4).tolist()}), {info['fingers']} fingers in "
                f"contact, required contacts {info['required'] or 'none'}, "
                f"held {info['held']} "
                f"(lifted {info['lift_dz']:.3f} m of {PHYSICS.lift_height} m, "
                f"slip {info['slip']:.4f} m); strict (at first touch) "
                f"{'in' if info['touch_in_region'] else 'out of'} the region"
            )
            self.outcome_pub.publish(
                GraspOutcome(
                    header=Header(stamp=self.node.get_clock().now().to_msg(), frame_id=WORLD_FRAME),
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
            self.get_logger().warning(f"judge_grasp: {resp.message}")
        return resp
