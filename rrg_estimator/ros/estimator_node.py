"""The estimator node (design §7): keeps the belief over the object's pose, updates it with every
observation on ``/rrg/observation``, and publishes it.

    python -m rrg_estimator.ros.estimator_node [--ros-args -p marker_count:=300 ...]

Topics: subscribes ``/rrg/observation`` (rrg_msgs/Observation) and ``/rrg/retreated``
(rrg_msgs/Retreated: the executor retreated the hand, so the belief takes the retreat's
transition, tracker.BeliefTracker.retreated); publishes ``/rrg/belief``
(rrg_msgs/BeliefGrid, TRANSIENT_LOCAL depth 1: late joiners get the current belief) and
``/rrg/belief_markers`` (visualization_msgs/MarkerArray, the heaviest grid points).
Services: ``/rrg/reset_belief`` (rrg_msgs/ResetBelief), ``/rrg/get_belief`` (rrg_msgs/GetBelief).
Its health (tables in memory, the last update's latency) goes on ``/diagnostics`` once a second
(``estimator: status``).

A published belief is stamped with the stamp of the event it incorporates, an observation or a
retreat (header and metadata.update_time), so a client can wait for the update of the event it
caused. Every retreat gets a belief of its stamp, even one with nothing to apply. An
observation that cannot be used (no belief yet, another object, an unknown WRT, a malformed
or impossible observation) is logged as an error and the belief is kept.

Recovery: with ``state_file`` set, the estimator writes its state (rrg_estimator.persistence:
the belief, its grid level, the pending retreat and the last event's stamp) after every reset,
update and retreat, before it publishes. A restarted estimator restores it and publishes the
restored belief again. The executor's ``/rrg/observation`` and ``/rrg/retreated`` are latched
streams, so a restarted estimator also receives their latest messages: it applies the one its
state does not include yet (newer than its last event) and skips the others, so an event that
arrived while it was down is not lost and none is applied twice.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np
from builtin_interfaces.msg import Time
from rclpy.node import Node
from visualization_msgs.msg import MarkerArray

from rrg_common.ros.diagnostics import WARN, Health, NodeDiagnostics, milliseconds
from rrg_common.ros.frames import OBJECT_ESTIMATE_FRAME, TfPublisher
from rrg_common.ros.liveliness import announce
from rrg_common.ros.msg_conversions import (
    WORLD_FRAME,
    ns_to_stamp,
    observation_from_msg,
    planar_from_msg,
    stamp_to_ns,
)
from rrg_common.ros.node_main import keep_serving, release_free_memory, run_node
from rrg_common.ros.parameters import Param, declare
from rrg_common.ros.qos import LATCHED, STREAM
from rrg_common.state_file import StateError
from rrg_estimator.config import LEVELS
from rrg_estimator.persistence import EstimatorState, load_state, save_state
from rrg_estimator.ros.belief_msgs import belief_markers, belief_to_msg
from rrg_estimator.ros.likelihood_param import declare_unsensed_sensors
from rrg_estimator.tracker import BeliefTracker, CachedTables
from rrg_models.objects import get_object
from rrg_models.poses import planar_pose
from rrg_msgs.msg import BeliefGrid, Retreated
from rrg_msgs.msg import Observation as ObservationMsg
from rrg_msgs.srv import GetBelief, ResetBelief
from rrg_sim.config import WORLD_PROFILES, world_profile
from rrg_sim.posture_calibration import PostureCalibration

NODE_NAME = "estimator"
NAMESPACE = "rrg"


#: The node's parameters (rrg_common.ros.parameters).
PARAMETERS: tuple[Param, ...] = (
    Param(
        "frame_id", WORLD_FRAME, "Frame of the belief's poses (the WAM base frame)", read_only=True
    ),
    Param(
        "marker_count",
        300,
        "Number of heaviest grid points drawn in /rrg/belief_markers",
        low=1,
        high=10000,
    ),
    Param(
        "marker_diameter",
        0.02,
        "Diameter [m] of the sphere of the heaviest grid point",
        low=0.001,
        high=0.2,
    ),
    Param(
        "variable_resolution",
        True,
        "Re-grid the belief at the low level's spacing once it has concentrated",
    ),
    Param(
        "world_profile",
        "nominal",
        (
            "World profile the belief assumes the robot acts in "
            f"(rrg_sim.config.world_profile: {', '.join(WORLD_PROFILES)}, …): its calibration "
            "error puts readings in posture frames (rrg_sim.posture_calibration)"
        ),
        read_only=True,
    ),
    Param(
        "state_file",
        "",
        (
            "File the estimator writes its state to after every event and "
            "restores it from when it starts ('' = no persistence)"
        ),
        read_only=True,
    ),
)


class EstimatorNode(Node):
    """Belief filter over one object's pose, driven by observation messages."""

    def __init__(self) -> None:
        super().__init__(NODE_NAME, namespace=NAMESPACE)
        declare(self, PARAMETERS)
        self.likelihood = declare_unsensed_sensors(self)
        self.frame_id = self.get_parameter("frame_id").value
        self.world_profile = world_profile(self.get_parameter("world_profile").value)
        state_file = self.get_parameter("state_file").value
        self.state_file = Path(state_file) if state_file else None
        self.tracker: BeliefTracker | None = None
        self._map_load_time = Time()
        self._last_event_ns = 0  # stamp [ns] of the last event the belief includes
        self._started_ns = self.get_clock().now().nanoseconds
        self._belief_msg: BeliefGrid | None = None
        #: for /diagnostics: the last update's WRT and latency [s], the updates and retreats
        #: applied, and why the last event was not used ("" when it was)
        self._last_update: tuple[str, float] | None = None
        self._applied = {"updates": 0, "retreats": 0}
        self._refused = ""
        self.belief_pub = self.create_publisher(BeliefGrid, "belief", STREAM)
        self.marker_pub = self.create_publisher(MarkerArray, "belief_markers", LATCHED)
        self.tf = TfPublisher(self)  # world → object_estimate, the belief's most likely pose
        self.restore()
        self.create_subscription(ObservationMsg, "observation", self.on_observation, STREAM)
        self.create_subscription(Retreated, "retreated", self.on_retreated, STREAM)
        self.create_service(ResetBelief, "reset_belief", self.on_reset_belief)
        self.create_service(GetBelief, "get_belief", self.on_get_belief)
        announce(self, NODE_NAME)
        self.diagnostics = NodeDiagnostics(self, self.health)
        if self.tracker is None:
            self.get_logger().info("estimator ready: call reset_belief to start a belief")

    def health(self) -> Health:
        """For /diagnostics: the belief's object, the observation tables in memory (WRTs per
        level), the last update's latency, the events applied, and WARN while the last event
        could not be used."""
        tracker = self.tracker
        if tracker is None:
            health = Health(message="ready: no belief yet (call reset_belief)")
            health.values["belief"] = "none"
        else:
            health = Health(message=f"ready: belief about {tracker.obj.name}")
            health.values["belief"] = tracker.obj.name
            health.values["grid spacing"] = str(np.round(tracker.belief.grid.spacing, 4).tolist())
            for level, wrts in sorted(tracker.tables.loaded().items()):
                health.values[f"tables {tracker.obj.name}/{level}"] = f"{len(wrts)} WRTs"
        wrt, latency = self._last_update or ("none", None)
        health.values["last update"] = wrt
        health.values["last update latency [ms]"] = milliseconds(latency)
        health.values.update({k: str(n) for k, n in self._applied.items()})
        health.values["state file"] = str(self.state_file or "none")
        if self._refused:
            health.escalate(WARN, self._refused)
        return health

    def refuse(self, text: str) -> None:
        """An event the belief does not take: log it as an error and report it."""
        self._refused = text
        self.get_logger().error(text)

    # ------------------------------------------------------------------ persistence
    def restore(self) -> None:
        """Restore the state of ``state_file``, if there is one, and publish its belief."""
        if self.state_file is None:
            return
        log = self.get_logger()
        try:
            state = load_state(self.state_file)
            obj = get_object(state.object_name)
            tracker = state.tracker(
                CachedTables(obj, workers=1),
                variable_resolution=self.get_parameter("variable_resolution").value,
                calibration=PostureCalibration.for_object(obj, self.world_profile),
                likelihood=self.likelihood,
                world=self.world_profile.name,
            )
        except FileNotFoundError:
            return
        except (StateError, KeyError) as exc:
            log.error(f"state not restored, starting without a belief: {exc}")
            return
        tracker.preload()
        self.tracker, self._last_event_ns = tracker, state.last_event_ns
        self._map_load_time = ns_to_stamp(state.map_load_ns)
        self.publish_belief(ns_to_stamp(state.last_event_ns))
        log.warning(
            f"restored the belief about {state.object_name} from {self.state_file}: w* = "
            f"{np.round(tracker.belief.w_star(), 3).tolist()}, grid spacing "
            f"{tracker.belief.grid.spacing}, retreat pending: {state.pending_wrt or 'none'}"
        )

    def persist(self) -> None:
        """Write the state to ``state_file`` (if set); a failed write is logged, not fatal."""
        if self.state_file is None or self.tracker is None:
            return
        try:
            save_state(
                self.state_file,
                EstimatorState.of(
                    self.tracker, self._last_event_ns, stamp_to_ns(self._map_load_time)
                ),
            )
        except OSError as exc:
            self.get_logger().error(
                f"could not write the state to {self.state_file} ({exc}); a restart would "
                "lose the belief"
            )

    def already_applied(self, stamp: Time, what: str) -> bool:
        """Whether the event of ``stamp`` is older than the belief (a latched event that a
        restarted estimator receives again, or one from before this estimator started)."""
        if stamp_to_ns(stamp) > self._last_event_ns and (
            self.tracker is not None or stamp_to_ns(stamp) >= self._started_ns
        ):
            return False
        self.get_logger().info(
            f"{what} of {stamp_to_ns(stamp)} ns already applied or stale: skipped"
        )
        return True

    # ------------------------------------------------------------------ publishing
    def commit(self, stamp: Time, new_grid: bool) -> BeliefGrid:
        """The belief now includes the event of ``stamp``: persist the state, then publish it
        (and the node's status)."""
        if new_grid:
            self._map_load_time = stamp
        self._last_event_ns = stamp_to_ns(stamp)
        self.persist()
        msg = self.publish_belief(stamp)
        self.diagnostics.force_update()
        return msg

    def publish_belief(self, stamp: Time) -> BeliefGrid:
        """Publish the tracker's belief stamped ``stamp``, and its markers."""
        belief = self.tracker.belief
        msg = belief_to_msg(belief, stamp, self._map_load_time, self.frame_id)
        self._belief_msg = msg
        self.belief_pub.publish(msg)
        estimate = planar_pose(belief.w_star())
        self.tf.publish([(self.frame_id, OBJECT_ESTIMATE_FRAME, estimate)], stamp)
        self.marker_pub.publish(
            belief_markers(
                belief,
                stamp,
                self.get_parameter("marker_count").value,
                self.get_parameter("marker_diameter").value,
                self.frame_id,
            )
        )
        return msg

    # ------------------------------------------------------------------ callbacks
    def on_observation(self, msg: ObservationMsg) -> None:
        log = self.get_logger()
        if self.tracker is None:
            self.refuse(
                f"observation of {msg.object_name}/{msg.wrt_name} ignored: no belief yet "
                "(call reset_belief)"
            )
            return
        if self.already_applied(msg.header.stamp, f"observation of {msg.wrt_name}"):
            return
        if msg.object_name != self.tracker.obj.name:
            self.refuse(
                f"observation of object {msg.object_name!r} ignored: the belief is about "
                f"{self.tracker.obj.name!r}; belief kept"
            )
            return
        old_grid = self.tracker.belief.grid
        t0 = time.monotonic()
        try:
            belief = self.tracker.update(
                msg.wrt_name, planar_from_msg(msg.estimate), observation_from_msg(msg)
            )
        except KeyError as exc:
            self.refuse(f"observation ignored, unknown WRT: {exc.args[0]}; belief kept")
            return
        except Exception as exc:
            self.refuse(
                f"observation of {msg.wrt_name} ignored: {type(exc).__name__}: {exc}; belief kept"
            )
            return
        self._last_update = (msg.wrt_name, time.monotonic() - t0)
        self._applied["updates"] += 1
        self._refused = ""
        self.commit(msg.header.stamp, belief.grid != old_grid)
        log.info(
            f"updated with {msg.wrt_name} (contact={msg.contact}): w* = "
            f"{np.round(belief.w_star(), 3).tolist()}, grid spacing {belief.grid.spacing}"
        )

    def on_retreated(self, msg: Retreated) -> None:
        if self.already_applied(msg.header.stamp, f"retreat from {msg.wrt_name or 'nothing'}"):
            return
        if self.tracker is None:
            self.get_logger().warning(
                f"retreat from {msg.object_name}/{msg.wrt_name} ignored: no belief yet"
            )
            return
        old_grid = self.tracker.belief.grid
        try:
            belief = self.tracker.retreated()
        except Exception as exc:
            self.refuse(f"retreat from {msg.wrt_name} not applied: {type(exc).__name__}: {exc}")
            belief = self.tracker.belief
        else:
            self._applied["retreats"] += 1
            self._refused = ""
        self.commit(msg.header.stamp, belief.grid != old_grid)
        self.get_logger().info(
            f"retreated from {msg.wrt_name or 'nothing'}: w* = "
            f"{np.round(belief.w_star(), 3).tolist()}, grid spacing {belief.grid.spacing}"
        )

    @keep_serving
    def on_reset_belief(
        self, req: ResetBelief.Request, resp: ResetBelief.Response
    ) -> ResetBelief.Response:
        sigma = np.array([req.sigma_x, req.sigma_y, req.sigma_theta])
        mean = planar_from_msg(req.mean)
        if req.level and req.level not in LEVELS:
            resp.error_code = ResetBelief.Response.UNKNOWN_LEVEL
            resp.error_msg = f"unknown level {req.level!r}; valid: {sorted(LEVELS)} or empty"
        elif not np.all(np.isfinite(mean)):
            resp.error_code, resp.error_msg = (
                ResetBelief.Response.INVALID_MEAN,
                f"mean must be finite, got {mean.tolist()}",
            )
        elif not (np.all(np.isfinite(sigma)) and np.all(sigma > 0.0)):
            resp.error_code = ResetBelief.Response.INVALID_SIGMA
            resp.error_msg = f"sigma (x, y, theta) must be finite and > 0, got {sigma.tolist()}"
        else:
            try:
                obj = get_object(req.object_name)
                same_object = self.tracker is not None and self.tracker.obj.name == obj.name
                tracker = BeliefTracker.gaussian(
                    obj,
                    mean,
                    sigma,
                    LEVELS.get(req.level),
                    # the object's tables again, or another's (workers=1: no fork from a
                    # process running DDS threads; tables are normally cached on disk)
                    tables=self.tracker.tables if same_object else CachedTables(obj, workers=1),
                    variable_resolution=self.get_parameter("variable_resolution").value,
                    calibration=self.tracker.calibration
                    if same_object
                    else PostureCalibration.for_object(obj, self.world_profile),
                    likelihood=self.likelihood,
                    world=self.world_profile.name,
                )
            except KeyError as exc:
                resp.error_code, resp.error_msg = (
                    ResetBelief.Response.UNKNOWN_OBJECT,
                    str(exc.args[0]),
                )
            else:
                tracker.preload()
                self.tracker = tracker
                self._refused = ""
                if not same_object:
                    release_free_memory()  # the last object's tables
                resp.belief = self.commit(self.get_clock().now().to_msg(), new_grid=True)
                self.get_logger().info(
                    f"belief reset: {req.object_name} at {np.round(mean, 3).tolist()}, "
                    f"sigma {np.round(sigma, 3).tolist()}, grid {tracker.belief.grid.spacing}"
                )
                return resp
        self.get_logger().error(f"reset_belief refused: {resp.error_msg}")
        return resp

    @keep_serving
    def on_get_belief(self, req: GetBelief.Request, resp: GetBelief.Response) -> GetBelief.Response:
        if self._belief_msg is None:
            resp.error_code, resp.error_msg = (
                GetBelief.Response.NO_BELIEF,
                "no belief yet: call reset_belief first",
            )
            return resp
        resp.object_name, resp.belief = self.tracker.obj.name, self._belief_msg
        return resp


def main(argv: list[str] | None = None) -> int:
    return run_node(EstimatorNode, argv=argv)


if __name__ == "__main__":
    sys.exit(main())
