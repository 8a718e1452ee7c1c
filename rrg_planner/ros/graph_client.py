"""The executor and estimator nodes as the closed loop's World and Estimator
(algorithm §6, design §7).

``GraphClient`` is what the planner node's robust-grasp action hands to
``rrg_planner.closed_loop.ClosedLoop``: ``execute`` runs ``/rrg/execute_wrt`` (the executor
publishes the observation, and the estimator updates on it by itself), ``update`` waits for the
estimator's belief stamped with that observation's stamp, ``retreat`` calls ``/rrg/retreat``
(the executor publishes ``/rrg/retreated``), and ``retreated`` waits for the belief stamped with
the retreat. The planner never computes a belief itself: the estimator node owns it.

Every wait polls ``interrupted`` (a cancel request or shutdown) and has a timeout; failures
raise GraphError with the robust-grasp result code that names them.

Restarted nodes (operations §8): the executor and the estimator announce themselves
(rrg_common.ros.liveliness), so a wait on one that dies ends at once. A lost execution is
recovered: once the executor is back, the hand is retreated home (a restarted executor that
has no path to retrace backs out and rises) and ``execute`` raises ExecutionLost, so the agent
chooses again on the belief as it now is. A lost retreat or belief reset is made again. A
restarted estimator restores its belief by itself, so a wait for a belief just goes on. When
the arm/hand interface dies, the executor reports a robot fault and the grasp aborts with
ROBOT_FAULT.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

import numpy as np
from builtin_interfaces.msg import Time
from rclpy.callback_groups import CallbackGroup
from rclpy.node import Node

from rrg_common.ros.futures import ThreadSafeActionClient, WaitInterrupted, WaitTimeout, wait_for
from rrg_common.ros.liveliness import PeerLost, PeerWatch
from rrg_common.ros.msg_conversions import observation_from_msg, planar_to_msg
from rrg_common.ros.qos import LATCHED
from rrg_estimator.belief import Belief
from rrg_estimator.ros.belief_msgs import belief_from_msg
from rrg_models.observation import Observation
from rrg_models.wrt import WRT, InfeasibleWRT
from rrg_msgs.action import ExecuteWrt, RobustGrasp
from rrg_msgs.msg import BeliefGrid
from rrg_msgs.srv import ResetBelief, Retreat
from rrg_planner.closed_loop import ExecutionLost

RG = RobustGrasp.Result
SERVER_WAIT_S = 10.0  # longest wait for a service or action server to appear
#: Calls made again after their server died and came back, at most (a node that keeps dying is
#: the launcher's to give up on).
RETRIES = 3


class GraphError(RuntimeError):
    """A call into the graph failed: ``code`` is the rrg_msgs/RobustGrasp result code."""

    def __init__(self, code: int, message: str):
        super().__init__(message)
        self.code = code


class GraphClient:
    """World (executor node) and Estimator (estimator node) of one node's robust grasps.

    Timeouts [s]: ``reset`` for the estimator's reset (it may load tables), ``execute`` for one
    WRT execution or retreat, ``belief`` for the estimator's belief after an event, ``restart``
    for a node that died to be back.
    """

    def __init__(self, node: Node, group: CallbackGroup, timeouts: Callable[[], dict[str, float]]):
        self.node = node
        self.timeouts = timeouts
        self.object_name = ""
        self.interrupted: Callable[[], bool] = lambda: not node.context.ok()
        self._belief_cv = threading.Condition()
        self.belief_msg: BeliefGrid | None = None  # the estimator's latest belief
        node.create_subscription(
            BeliefGrid, "belief", self._on_belief, LATCHED, callback_group=group
        )
        self.reset_client = node.create_client(ResetBelief, "reset_belief", callback_group=group)
        self.retreat_client = node.create_client(Retreat, "retreat", callback_group=group)
        self.execute_client = ThreadSafeActionClient(
            node, ExecuteWrt, "execute_wrt", callback_group=group
        )
        self.executor = PeerWatch(node, "executor", group)
        self.estimator = PeerWatch(node, "estimator", group)
        self._observation_stamp: Time | None = None
        self._retreat_stamp: Time | None = None
        self.log = node.get_logger()

    def _back(self, peer: PeerWatch, what: str, code: int) -> None:
        """Wait until ``peer`` is up (it may be restarting); GraphError(code) if it is not in
        time."""
        if peer.alive:
            return
        self.log.warning(f"the {peer.name} is not up: waiting for it before {what}")
        if not peer.wait_alive(self.timeouts()["restart"], self.interrupted):
            if self.interrupted():
                raise WaitInterrupted(f"interrupted while waiting for the {peer.name}")
            raise GraphError(
                code,
                f"the {peer.name} did not come back within {self.timeouts()['restart']:.0f} s",
            )

    # ------------------------------------------------------------------ the estimator's belief
    def _on_belief(self, msg: BeliefGrid) -> None:
        with self._belief_cv:
            self.belief_msg = msg
            self._belief_cv.notify_all()

    def _wait_for_belief(self, stamp: Time | None) -> Belief:
        """The estimator's belief stamped ``stamp`` (its update for the event of that stamp), or
        with ``stamp`` None whatever belief it has."""
        timeout_s = self.timeouts()["belief"]
        deadline = time.monotonic() + timeout_s
        with self._belief_cv:
            while self.belief_msg is None or (
                stamp is not None and self.belief_msg.header.stamp != stamp
            ):
                if self.interrupted():
                    raise WaitInterrupted("interrupted while waiting for the belief")
                if time.monotonic() > deadline:
                    raise GraphError(
                        RG.ESTIMATION_FAILED,
                        f"no belief from the estimator within {timeout_s:.0f} s",
                    )
                self._belief_cv.wait(0.05)
            return belief_from_msg(self.belief_msg)

    def _call(self, client, request, peer: PeerWatch, timeout: str, what: str, code: int):
        """Call the service ``client`` of node ``peer`` (timeout: a key of ``timeouts()``), again
        when the node dies during the call and comes back (at most RETRIES times); GraphError
        with ``code`` when it fails."""
        for attempt in range(RETRIES + 1):
            self._back(peer, f"calling {what}", code)
            if not client.wait_for_service(timeout_sec=SERVER_WAIT_S):
                raise GraphError(code, f"the {peer.name}'s {what} is not available")
            try:
                return wait_for(
                    client.call_async(request), self.timeouts()[timeout], self.interrupted, peer
                )
            except WaitTimeout as exc:
                raise GraphError(code, f"{what}: {exc}") from exc
            except PeerLost as exc:
                if attempt == RETRIES:
                    raise GraphError(code, f"{what}: {exc}") from exc
                self.log.warning(f"{what}: {exc}; calling it again once it is back")

    @property
    def belief(self) -> Belief:
        if self.belief_msg is None:
            raise GraphError(RG.ESTIMATION_FAILED, "no belief from the estimator yet")
        return belief_from_msg(self.belief_msg)

    def reset(
        self,
        object_name: str,
        level: str,
        mean: np.ndarray,
        sigma: np.ndarray,
        interrupted: Callable[[], bool],
    ) -> Belief:
        """Start a robust grasp: the estimator's belief N(mean, σ²) on the level's grid."""
        self.object_name, self.interrupted = object_name, interrupted
        req = ResetBelief.Request(
            object_name=object_name,
            mean=planar_to_msg(mean),
            level=level,
            sigma_x=float(sigma[0]),
            sigma_y=float(sigma[1]),
            sigma_theta=float(sigma[2]),
        )
        resp = self._call(
            self.reset_client, req, self.estimator, "reset", "reset_belief", RG.ESTIMATION_FAILED
        )
        if resp.error_code != ResetBelief.Response.NONE:
            raise GraphError(RG.ESTIMATION_FAILED, f"reset_belief failed: {resp.error_msg}")
        with self._belief_cv:
            self.belief_msg = resp.belief
        return belief_from_msg(resp.belief)

    def resume(self, object_name: str, interrupted: Callable[[], bool]) -> Belief:
        """Go on with a grasp a restarted planner had begun: wait for the estimator's belief,
        then bring the hand home (retreat) and return the belief after it."""
        self.object_name, self.interrupted = object_name, interrupted
        self._back(self.estimator, "resuming", RG.ESTIMATION_FAILED)
        self._wait_for_belief(None)
        self.retreat()
        return self.retreated()

    # ------------------------------------------------------------------ World
    def execute(self, wrt: WRT, e: np.ndarray) -> Observation:
        """Run ExecuteWrt and return its observation; a cancel request cancels the execution.
        Raises InfeasibleWRT when the executor found τ(e) infeasible before moving."""
        self._back(self.executor, f"executing {wrt.name}", RG.EXECUTION_FAILED)
        if not self.execute_client.wait_for_server(timeout_sec=SERVER_WAIT_S):
            raise GraphError(RG.EXECUTION_FAILED, "the executor's execute_wrt is not available")
        goal = ExecuteWrt.Goal(
            object_name=self.object_name, wrt_name=wrt.name, estimate=planar_to_msg(e)
        )
        try:
            handle = wait_for(
                self.execute_client.send_goal_async(goal), SERVER_WAIT_S, peer=self.executor
            )
        except WaitTimeout as exc:
            raise GraphError(RG.EXECUTION_FAILED, f"execute_wrt {wrt.name}: {exc}") from exc
        except PeerLost as exc:
            raise self._lost(wrt, exc) from exc
        if not handle.accepted:
            raise GraphError(RG.EXECUTION_FAILED, f"execute_wrt rejected {wrt.name}")
        try:
            answer = wait_for(
                handle.get_result_async(),
                self.timeouts()["execute"],
                self.interrupted,
                self.executor,
            )
        except WaitInterrupted:
            wait_for(handle.cancel_goal_async(), SERVER_WAIT_S)
            raise
        except WaitTimeout as exc:
            handle.cancel_goal_async()
            raise GraphError(RG.EXECUTION_FAILED, f"execute_wrt {wrt.name}: {exc}") from exc
        except PeerLost as exc:
            raise self._lost(wrt, exc) from exc
        result = answer.result
        if result.error_code == ExecuteWrt.Result.INFEASIBLE:
            raise InfeasibleWRT(result.error_msg)
        if result.error_code == ExecuteWrt.Result.ROBOT_FAULT:
            raise GraphError(RG.ROBOT_FAULT, f"execute_wrt {wrt.name}: {result.error_msg}")
        if result.error_code == ExecuteWrt.Result.SAFETY_STOP:  # the executor brought it home
            raise ExecutionLost(f"execute_wrt {wrt.name}: {result.error_msg}")
        if result.error_code != ExecuteWrt.Result.NONE:
            raise GraphError(
                RG.EXECUTION_FAILED, f"execute_wrt {wrt.name} failed: {result.error_msg}"
            )
        self._observation_stamp = result.observation.header.stamp
        return observation_from_msg(result.observation)

    def _lost(self, wrt: WRT, exc: PeerLost) -> ExecutionLost:
        """Bring the hand home after the executor died running ``wrt``, and the error to
        raise."""
        self.log.warning(f"execute_wrt {wrt.name}: {exc}; bringing the hand home")
        self.retreat()
        self.retreated()
        return ExecutionLost(f"the executor went away while running {wrt.name}")

    def retreat(self) -> None:
        """Retreat home through the executor; the estimator hears of it on /rrg/retreated."""
        resp = self._call(
            self.retreat_client,
            Retreat.Request(),
            self.executor,
            "execute",
            "retreat",
            RG.EXECUTION_FAILED,
        )
        if resp.error_code == Retreat.Response.ROBOT_FAULT:
            raise GraphError(RG.ROBOT_FAULT, f"retreat failed: {resp.error_msg}")
        if resp.error_code != Retreat.Response.NONE:
            raise GraphError(RG.EXECUTION_FAILED, f"retreat failed: {resp.error_msg}")
        self._retreat_stamp = resp.header.stamp

    # ------------------------------------------------------------------ Estimator
    def update(self, wrt_name: str, e: np.ndarray, obs: Observation) -> Belief:
        """The estimator's update with the observation just executed (it reads it from the
        topic)."""
        return self._wait_for_belief(self._observation_stamp)

    def retreated(self) -> Belief:
        """The estimator's belief once it applied the retreat just made."""
        return self._wait_for_belief(self._retreat_stamp)
