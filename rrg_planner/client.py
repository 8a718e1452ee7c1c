"""RRGClient: RRG's planner as other robot software calls it, as nav2_simple_commander is to nav2.

    from rrg_planner.client import Gaussian, RRGClient

    with RRGClient() as rrg:                       # its own node and ROS context
        rrg.wait_until_ready(timeout_s=60.0)
        choice = rrg.select_action("powerdrill", Gaussian(mean=(0.64, -0.02, 0.2)))
        print(choice.wrt_name, choice.value)
        result = rrg.robust_grasp(
            "powerdrill", level="high", on_feedback=lambda f: print(f.step, f.wrt_name, f.p_goal)
        )
        print(result.success, result.actions, result.final_p_goal)

A call that the graph answers with an error code raises ``RRGServiceError`` (code and message);
a server that is not there, or no answer in time, raises ``RRGUnavailable`` or ``RRGTimeout``
within the call's timeout: nothing waits forever. A robust grasp's outcome, a failed or
cancelled one included, is a ``GraspResult``. ``start_robust_grasp`` returns a ``GraspTask`` to
cancel or to wait on; Ctrl-C inside ``robust_grasp`` cancels the grasp before it propagates.

The client spins its own node unless it is given one: then ``spin_once(timeout_s)`` is how it
lets that node's executor run while it waits (the launcher passes its supervising spin).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from rclpy.node import Node

from rrg_common.ros.futures import ThreadSafeActionClient
from rrg_common.ros.msg_conversions import planar_from_msg, planar_to_msg
from rrg_estimator.belief import Belief
from rrg_estimator.config import LEVELS
from rrg_estimator.ros.belief_msgs import belief_from_msg, belief_to_msg
from rrg_msgs.action import RobustGrasp
from rrg_msgs.msg import BeliefGrid
from rrg_msgs.srv import GetBelief, ResetBelief, SelectAction

#: The graph's namespace (every RRG service and action is under it).
NAMESPACE = "/rrg"
#: Spin slice [s] of every wait: how soon a wait notices its condition.
SPIN_SLICE_S = 0.05
#: Default timeouts [s]: a server to appear, a service's answer (a select-action at H = 3 takes
#: ~0.6 s; a reset loads tables), a robust grasp (ten actions paced at real time stay under
#: 10 min), a cancellation to be acknowledged.
READY_TIMEOUT_S = 60.0
CALL_TIMEOUT_S = 120.0
GRASP_TIMEOUT_S = 900.0
CANCEL_TIMEOUT_S = 30.0
#: Wait [s] between a server first appearing and the first request to it: the server must also
#: have matched this client's response reader, or rmw_fastrtps drops the response after 100 ms
#: (ros2/rmw_fastrtps#390), and the call would wait for its whole timeout.
SETTLE_S = 0.5

STRATEGIES = (
    SelectAction.Request.STRATEGY_RRG_INFO,
    SelectAction.Request.STRATEGY_RRG_GOAL,
    SelectAction.Request.STRATEGY_OPEN_LOOP,
)


class RRGError(RuntimeError):
    """A call into RRG's graph failed."""


class RRGUnavailable(RRGError, TimeoutError):
    """A service or action server of the graph is not there (is ``rrg-launch`` running in this
    ROS_DOMAIN_ID?)."""


class RRGTimeout(RRGError, TimeoutError):
    """A request got no answer in time."""


class RRGServiceError(RRGError):
    """The graph answered with an error: ``code`` is the interface's error code (e.g.
    rrg_msgs/SelectAction ``INVALID_HORIZON``), ``code_name`` its name."""

    def __init__(self, what: str, code: int, code_name: str, message: str):
        super().__init__(f"{what} error {code} ({code_name}): {message}")
        self.code, self.code_name, self.message = code, code_name, message


def code_name(interface, code: int) -> str:
    """The name of error ``code`` among the upper-case integer constants of ``interface``."""
    for name in dir(interface):
        if name.isupper() and getattr(interface, name) == code:
            return name
    return "UNKNOWN"


@dataclass(frozen=True)
class Gaussian:
    """A Gaussian belief N(mean, diag(sigma²)) over the pose (x [m], y [m], θ [rad]), sampled on
    the grid of uncertainty ``level`` centred on the mean; sigma defaults to the level's."""

    mean: tuple[float, float, float]
    sigma: tuple[float, float, float] | None = None
    level: str = "high"

    def belief(self) -> Belief:
        """The sampled belief; ValueError for an unknown level or a non-positive sigma."""
        if self.level not in LEVELS:
            raise ValueError(f"unknown level {self.level!r}: one of {sorted(LEVELS)}")
        level = LEVELS[self.level]
        sigma = np.asarray(self.sigma if self.sigma is not None else level.sigma, dtype=float)
        if sigma.shape != (3,) or not np.all(np.isfinite(sigma)) or np.any(sigma <= 0.0):
            raise ValueError(f"sigma must be three positive numbers, not {self.sigma}")
        return Belief.gaussian(
            Belief.for_level(level, self.mean).grid, np.asarray(self.mean, float), sigma
        )


@dataclass(frozen=True)
class ActionChoice:
    """The planner's answer to select_action."""

    wrt_name: str  # the chosen world-relative trajectory
    estimate: np.ndarray  # (x [m], y [m], θ [rad]): where to run it
    value: float  # V_H(b) of the choice
    p_goal: float  # P_b(goal) of the best goal WRT
    values: dict[str, float]  # every WRT evaluated → its value (NaN: infeasible)
    planning_time_s: float  # time the planner's core spent


class ObjectBelief(NamedTuple):
    """The estimator's current belief and the object it is about."""

    object_name: str
    belief: Belief


@dataclass(frozen=True)
class GraspFeedback:
    """One step of a robust grasp, as the planner reports it before executing it."""

    step: int  # 1-based
    wrt_name: str  # the WRT chosen at this step
    value: float  # its value V_H(b)
    p_goal: float  # P_b(goal) of the belief it was chosen on
    belief_msg: BeliefGrid = field(repr=False)
    goal_wrt_name: str = ""  # the goal grasp p_goal is of (an object may have several)

    @property
    def belief(self) -> Belief:
        return belief_from_msg(self.belief_msg)


@dataclass(frozen=True)
class GraspResult:
    """A robust grasp's outcome as the planner judges it (a simulator's judge is separate)."""

    error_code: int  # rrg_msgs/RobustGrasp result code: NONE (0) on success
    error_msg: str
    success: bool  # the goal grasp ran with P(goal) > 1 − δ
    actions: list[str]  # WRT names in execution order
    final_p_goal: float
    final_belief_msg: BeliefGrid = field(repr=False)

    @property
    def code_name(self) -> str:
        return code_name(RobustGrasp.Result, self.error_code)

    @property
    def canceled(self) -> bool:
        return self.error_code == RobustGrasp.Result.CANCELED

    @property
    def final_belief(self) -> Belief:
        return belief_from_msg(self.final_belief_msg)


class GraspTask:
    """A robust grasp the planner has accepted: ``cancel`` it, ask whether it is ``done``, or
    wait for its ``result``."""

    def __init__(self, client: RRGClient, goal_handle):
        self._client = client
        self.goal_handle = goal_handle
        self._result = goal_handle.get_result_async()
        self._cancel = None

    def done(self) -> bool:
        return self._result.done()

    def cancel(self):
        """Ask the planner to cancel; returns at once, with the future of the planner's
        acknowledgement (None when the grasp had already ended). The result then says
        CANCELED, or how the grasp ended if it ended first."""
        if self._cancel is None and not self.done():
            self._cancel = self.goal_handle.cancel_goal_async()
        return self._cancel

    def result(self, timeout_s: float = GRASP_TIMEOUT_S) -> GraspResult:
        """Wait for the outcome; RRGTimeout if it has not come within ``timeout_s``."""
        self._client.spin_until(self._result.done, timeout_s, "the robust grasp's result")
        res = self._result.result().result
        return GraspResult(
            error_code=int(res.error_code),
            error_msg=res.error_msg,
            success=bool(res.success),
            actions=list(res.actions_taken),
            final_p_goal=float(res.final_p_goal),
            final_belief_msg=res.final_belief,
        )


class RRGClient:
    """The planner's and the estimator's services and the robust-grasp action, typed.

    ``node``: a node to create the clients on (None: the client makes its own, in its own ROS
    context, on ``domain_id`` or the environment's ROS_DOMAIN_ID); ``spin_once(timeout_s)``: how
    to let that node's callbacks run (default: its own single-threaded executor; a node spun
    elsewhere passes ``time.sleep``).
    """

    def __init__(
        self,
        node: Node | None = None,
        spin_once: Callable[[float], None] | None = None,
        namespace: str = NAMESPACE,
        domain_id: int | None = None,
        node_name: str = "rrg_client",
    ):
        self._context = self._executor = None
        if node is None:
            import rclpy
            from rclpy.executors import SingleThreadedExecutor
            from rclpy.signals import SignalHandlerOptions

            self._context = rclpy.Context()
            # Ctrl-C stays a KeyboardInterrupt, and the context stays up to cancel a grasp
            kwargs = {} if domain_id is None else {"domain_id": domain_id}
            rclpy.init(
                context=self._context, signal_handler_options=SignalHandlerOptions.NO, **kwargs
            )
            node = rclpy.create_node(node_name, context=self._context)
            self._executor = SingleThreadedExecutor(context=self._context)
            self._executor.add_node(node)
            spin_once = lambda t: self._executor.spin_once(timeout_sec=t)
        elif spin_once is None:
            raise ValueError("a client on a given node needs that node's spin_once")
        self.node = node
        self._spin_once = spin_once
        ns = namespace.rstrip("/")
        self._select = node.create_client(SelectAction, f"{ns}/select_action")
        self._reset = node.create_client(ResetBelief, f"{ns}/reset_belief")
        self._get = node.create_client(GetBelief, f"{ns}/get_belief")
        self._grasp = ThreadSafeActionClient(node, RobustGrasp, f"{ns}/robust_grasp")
        self._settled: set[str] = set()  # servers seen ready SETTLE_S ago or more

    # ------------------------------------------------------------------ plumbing
    def __enter__(self) -> RRGClient:
        return self

    def __exit__(self, *_exc) -> None:
        self.close()

    def close(self) -> None:
        """Destroy the clients (and the node and context the client made itself)."""
        for c in (self._select, self._reset, self._get):
            self.node.destroy_client(c)
        self._grasp.destroy()
        if self._context is not None:
            import rclpy

            self._executor.shutdown()
            self.node.destroy_node()
            rclpy.try_shutdown(context=self._context)
            self._context = None

    def spin_until(self, condition: Callable[[], bool], timeout_s: float, what: str) -> None:
        """Let the node's callbacks run until ``condition()``; RRGTimeout after ``timeout_s``."""
        deadline = time.monotonic() + timeout_s
        while not condition():
            if time.monotonic() > deadline:
                raise RRGTimeout(f"no {what} within {timeout_s:.0f} s")
            self._spin_once(SPIN_SLICE_S)

    def _wait_for_server(self, name: str, ready: Callable[[], bool], timeout_s: float) -> None:
        """Wait until server ``name`` is ready (and, the first time, SETTLE_S more);
        RRGUnavailable after ``timeout_s``."""
        try:
            self.spin_until(ready, timeout_s, f"{name} server")
        except RRGTimeout:
            raise RRGUnavailable(f"{name} is not available within {timeout_s:.0f} s") from None
        if name not in self._settled:
            settled = time.monotonic() + SETTLE_S
            self.spin_until(lambda: time.monotonic() > settled, 2 * SETTLE_S, "settling")
            self._settled.add(name)

    def _servers(self) -> dict[str, Callable[[], bool]]:
        return {
            self._select.srv_name: self._select.service_is_ready,
            self._reset.srv_name: self._reset.service_is_ready,
            self._get.srv_name: self._get.service_is_ready,
            self._grasp._action_name: self._grasp.server_is_ready,
        }

    def is_ready(self) -> bool:
        """Whether the planner's and the estimator's services and action answer."""
        return all(ready() for ready in self._servers().values())

    def wait_until_ready(self, timeout_s: float = READY_TIMEOUT_S) -> None:
        """Wait until the graph serves RRG (planning models load first); RRGUnavailable naming
        what is missing after ``timeout_s``."""
        try:
            self.spin_until(self.is_ready, timeout_s, "RRG graph")
        except RRGTimeout:
            missing = [name for name, ready in self._servers().items() if not ready()]
            raise RRGUnavailable(
                f"{', '.join(missing)} not available within {timeout_s:.0f} s: is rrg-launch "
                "running in this ROS_DOMAIN_ID?"
            ) from None

    def _call(self, client, request, timeout_s: float, what: str):
        """The service's answer; RRGUnavailable or RRGTimeout within ``timeout_s``."""
        deadline = time.monotonic() + timeout_s
        self._wait_for_server(client.srv_name, client.service_is_ready, timeout_s)
        future = client.call_async(request)
        try:
            self.spin_until(future.done, max(0.0, deadline - time.monotonic()), f"{what} answer")
        except BaseException:
            client.remove_pending_request(future)
            raise
        resp = future.result()
        if resp.error_code != type(resp).NONE:
            raise RRGServiceError(
                what, resp.error_code, code_name(type(resp), resp.error_code), resp.error_msg
            )
        return resp

    # ------------------------------------------------------------------ services
    def select_action(
        self,
        object_name: str,
        belief: Belief | BeliefGrid | Gaussian | None = None,
        strategy: str = SelectAction.Request.STRATEGY_RRG_INFO,
        horizon: int = 2,
        delta: float = 0.1,
        timeout_s: float = CALL_TIMEOUT_S,
    ) -> ActionChoice:
        """The planner's next action for ``belief`` (None: the estimator's current belief)."""
        if isinstance(belief, Gaussian):
            belief = belief.belief()
        if isinstance(belief, Belief):
            belief = belief_to_msg(belief, self.node.get_clock().now().to_msg())
        req = SelectAction.Request(
            use_current_belief=belief is None,
            belief=belief if belief is not None else BeliefGrid(),
            object_name=object_name,
            strategy=strategy,
            horizon=horizon,
            delta=delta,
        )
        resp = self._call(self._select, req, timeout_s, "select_action")
        return ActionChoice(
            wrt_name=resp.wrt_name,
            estimate=planar_from_msg(resp.estimate),
            value=float(resp.value),
            p_goal=float(resp.p_goal),
            values=dict(zip(resp.action_names, (float(v) for v in resp.action_values))),
            planning_time_s=float(resp.planning_time),
        )

    def reset_belief(
        self,
        object_name: str,
        mean,
        sigma=None,
        level: str = "high",
        timeout_s: float = CALL_TIMEOUT_S,
    ) -> Belief:
        """Reset the estimator's belief to N(mean, diag(sigma²)) on ``level``'s grid (sigma
        defaults to the level's); returns the new belief."""
        if sigma is None and level in LEVELS:
            sigma = LEVELS[level].sigma
        sx, sy, st = (float(s) for s in (sigma if sigma is not None else (0.0, 0.0, 0.0)))
        req = ResetBelief.Request(
            object_name=object_name,
            mean=planar_to_msg(mean),
            sigma_x=sx,
            sigma_y=sy,
            sigma_theta=st,
            level=level,
        )
        return belief_from_msg(self._call(self._reset, req, timeout_s, "reset_belief").belief)

    def get_belief(self, timeout_s: float = CALL_TIMEOUT_S) -> ObjectBelief:
        """The estimator's current belief."""
        resp = self._call(self._get, GetBelief.Request(), timeout_s, "get_belief")
        return ObjectBelief(resp.object_name, belief_from_msg(resp.belief))

    # ------------------------------------------------------------------ the robust grasp
    def start_robust_grasp(
        self,
        object_name: str,
        level: str = "high",
        strategy: str = SelectAction.Request.STRATEGY_RRG_INFO,
        horizon: int = 2,
        delta: float = 0.1,
        max_actions: int = 0,
        on_feedback: Callable[[GraspFeedback], None] | None = None,
        resume: bool = False,
        timeout_s: float = READY_TIMEOUT_S,
    ) -> GraspTask:
        """Send a robust grasp (``max_actions`` 0: the planner's default, 10) and return it once
        the planner accepted it; RRGServiceError if the planner rejects it."""
        goal = RobustGrasp.Goal(
            object_name=object_name,
            level=level,
            strategy=strategy,
            horizon=horizon,
            delta=delta,
            max_actions=max_actions,
            resume=resume,
        )
        self._wait_for_server(self._grasp._action_name, self._grasp.server_is_ready, timeout_s)

        def feedback(msg) -> None:
            fb = msg.feedback
            on_feedback(
                GraspFeedback(
                    fb.step, fb.wrt_name, fb.value, fb.p_goal, fb.belief, fb.goal_wrt_name
                )
            )

        sent = self._grasp.send_goal_async(
            goal, feedback_callback=feedback if on_feedback is not None else None
        )
        self.spin_until(sent.done, timeout_s, "robust_grasp acceptance")
        handle = sent.result()
        if not handle.accepted:
            raise RRGServiceError(
                "robust_grasp",
                RobustGrasp.Result.UNKNOWN,
                "REJECTED",
                "the planner rejected the goal (is it running another grasp?)",
            )
        return GraspTask(self, handle)

    def robust_grasp(
        self,
        object_name: str,
        level: str = "high",
        strategy: str = SelectAction.Request.STRATEGY_RRG_INFO,
        horizon: int = 2,
        delta: float = 0.1,
        max_actions: int = 0,
        on_feedback: Callable[[GraspFeedback], None] | None = None,
        timeout_s: float = GRASP_TIMEOUT_S,
    ) -> GraspResult:
        """Run a robust grasp to its end; Ctrl-C (or a timeout) cancels it before raising."""
        task = self.start_robust_grasp(
            object_name,
            level,
            strategy,
            horizon,
            delta,
            max_actions,
            on_feedback,
            timeout_s=min(timeout_s, READY_TIMEOUT_S),
        )
        try:
            return task.result(timeout_s)
        except BaseException:
            task.cancel()
            try:
                self.spin_until(task.done, CANCEL_TIMEOUT_S, "cancelled grasp's end")
            except (RRGTimeout, KeyboardInterrupt):
                pass
            raise
