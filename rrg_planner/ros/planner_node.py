"""The planner node (DESIGN §7): the select-action service that other robot software calls, and
the robust-grasp action that runs the whole loop.

    python -m rrg_planner.ros.planner_node [--ros-args -p preload:="['powerdrill']" -p levels:="['high','mid','low']"]

Services and actions:
* ``/rrg/select_action`` (rrg_msgs/SelectAction): the next WRT for a given belief (or the
  estimator's current one), a strategy, H and δ. Every input is validated before the core sees
  it; a bad one gets its error code and a message, and the node keeps serving.
* ``/rrg/robust_grasp`` (rrg_msgs/RobustGrasp): reset the belief through the estimator, then
  repeatedly select a WRT, execute it through the executor's ``/rrg/execute_wrt``, and wait for
  the estimator's updated belief (stamped with the observation's stamp), with feedback at every
  step, until the agent's stopping rule holds. Cancellable between and during actions.
* publishes ``/rrg/grasp_step`` (diagnostic_msgs/DiagnosticStatus): one record per chosen action
  and one when a grasp ends, so a bag holds the decisions (``rrg-bag summary`` reads them).

The decisions are the core's (rrg_planner.agent.RobustGraspAgent): this node only moves messages.
"""
from __future__ import annotations

import sys
import threading
import time

import numpy as np
from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
from rcl_interfaces.msg import FloatingPointRange, ParameterDescriptor
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.action.server import ServerGoalHandle
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.node import Node
from rclpy.parameter import Parameter
from std_srvs.srv import Trigger

from rrg_estimator.belief import Belief
from rrg_estimator.ros.belief_msgs import InvalidBelief, InvalidGrid, belief_from_msg
from rrg_msgs.action import ExecuteWrt, RobustGrasp
from rrg_msgs.msg import BeliefGrid, Observation as ObservationMsg
from rrg_msgs.srv import GetBelief, ResetBelief, SelectAction
from rrg_estimator.config import LEVELS
from rrg_planner.config import SEARCH
from rrg_sim.config import WORLD
from rrg_sim.objects import OBJECT_NAMES
from rrg_sim.ros_common.msg_conversions import planar_to_msg
from rrg_sim.ros_common.futures import ThreadSafeActionClient, WaitInterrupted, WaitTimeout, wait_for
from rrg_sim.ros_common.node_main import run_node
from rrg_sim.ros_common.qos import LATCHED
from rrg_sim.wrt import InfeasibleWRT

from ..agent import MAX_BLOCKED, STRATEGIES, RobustGraspAgent
from rrg_planner.planning_model import PlanningModel
from ..search import SearchResult

NODE_NAME = "planner"
NAMESPACE = "rrg"
SA = SelectAction.Response
RG = RobustGrasp.Result


class RequestError(Exception):
    """A request the node refuses: carries the interface's error code and the message."""

    def __init__(self, code: int, message: str):
        super().__init__(message)
        self.code = code


def static_value(agent: RobustGraspAgent, belief: Belief) -> float:
    """v(b): P_b(goal) of the goal WRT executed at its best estimate (agent.goal_estimate; 0
    where it is infeasible)."""
    e = agent.goal_estimate(belief, agent.goal)
    return agent.grasp_probability(belief, agent.goal, e) if agent.model.feasible(agent.goal, e) else 0.0


def diagnostic(name: str, message: str, level: bytes, values: dict) -> DiagnosticStatus:
    return DiagnosticStatus(level=level, name=name, message=message, hardware_id="rrg",
                            values=[KeyValue(key=k, value=str(v)) for k, v in values.items()])


class PlannerNode(Node):
    """Select-action service and robust-grasp action over the planning core."""

    def __init__(self) -> None:
        super().__init__(NODE_NAME, namespace=NAMESPACE)
        self.declare_parameter("levels", list(LEVELS), ParameterDescriptor(
            description="Uncertainty levels whose tables are loaded (beliefs must use one of their grids)",
            read_only=True))
        self.declare_parameter("preload", Parameter.Type.STRING_ARRAY, ParameterDescriptor(
            read_only=True, description="Objects whose planning models are loaded before the services start "
                        "(a first build takes ~1 min per object)"))
        self.declare_parameter("reset_timeout", 300.0, ParameterDescriptor(
            description="Longest wait [s] for the estimator's reset (it may load or build tables)",
            floating_point_range=[FloatingPointRange(from_value=1.0, to_value=3600.0)]))
        self.declare_parameter("execute_timeout", 300.0, ParameterDescriptor(
            description="Longest wait [s] for one WRT execution",
            floating_point_range=[FloatingPointRange(from_value=1.0, to_value=3600.0)]))
        self.declare_parameter("belief_timeout", 120.0, ParameterDescriptor(
            description="Longest wait [s] for the estimator's belief after an observation",
            floating_point_range=[FloatingPointRange(from_value=0.1, to_value=3600.0)]))
        self.levels = tuple(self.get_parameter("levels").value)
        unknown = [lv for lv in self.levels if lv not in LEVELS]
        if unknown:
            raise ValueError(f"unknown levels {unknown}; valid: {sorted(LEVELS)}")
        self._models: dict[str, PlanningModel] = {}
        self._model_lock = threading.Lock()
        for name in self.get_parameter_or("preload", Parameter("preload", value=[])).value:
            self.model(name)

        group = ReentrantCallbackGroup()
        self._belief_cv = threading.Condition()
        self._belief_msg: BeliefGrid | None = None
        self.create_subscription(BeliefGrid, "belief", self.on_belief, LATCHED, callback_group=group)
        self.step_pub = self.create_publisher(DiagnosticStatus, "grasp_step", 10)
        self.reset_client = self.create_client(ResetBelief, "reset_belief", callback_group=group)
        self.get_client = self.create_client(GetBelief, "get_belief", callback_group=group)
        self.retreat_client = self.create_client(Trigger, "retreat", callback_group=group)
        self.execute_client = ThreadSafeActionClient(self, ExecuteWrt, "execute_wrt", callback_group=group)
        self._grasp_active = threading.Lock()
        self.create_service(SelectAction, "select_action", self.on_select_action, callback_group=group)
        ActionServer(self, RobustGrasp, "robust_grasp", execute_callback=self.execute_robust_grasp,
                     goal_callback=self.on_grasp_goal, cancel_callback=lambda _: CancelResponse.ACCEPT,
                     callback_group=group)
        self.get_logger().info(f"planner ready (levels {list(self.levels)}, models loaded: {sorted(self._models)})")

    # ------------------------------------------------------------------ models and beliefs
    def model(self, object_name: str) -> PlanningModel:
        """The object's planning model, loaded on first use (a first build takes ~1 min)."""
        with self._model_lock:
            if object_name not in self._models:
                self.get_logger().info(f"loading the planning model of {object_name} at levels "
                                       f"{list(self.levels)} (building missing tables takes ~1 min per object)")
                t0 = time.monotonic()
                # workers=1: forking a table-building pool from a process running DDS threads can
                # deadlock; rrg-launch builds missing tables in parallel before it starts the nodes.
                self._models[object_name] = PlanningModel(object_name, levels=self.levels, workers=1, progress=False)
                self.get_logger().info(f"model of {object_name} loaded in {time.monotonic() - t0:.1f} s: "
                                       f"WRTs {self._models[object_name].names}")
            return self._models[object_name]

    def on_belief(self, msg: BeliefGrid) -> None:
        with self._belief_cv:
            self._belief_msg = msg
            self._belief_cv.notify_all()

    def wait_for_belief(self, stamp, timeout_s: float, interrupted) -> BeliefGrid:
        """The estimator's belief stamped ``stamp`` (the update of the observation with that stamp)."""
        deadline = time.monotonic() + timeout_s
        with self._belief_cv:
            while self._belief_msg is None or self._belief_msg.header.stamp != stamp:
                if interrupted():
                    raise WaitInterrupted("interrupted while waiting for the belief")
                if time.monotonic() > deadline:
                    raise WaitTimeout(f"no updated belief from the estimator within {timeout_s:.0f} s")
                self._belief_cv.wait(0.05)
            return self._belief_msg

    # ------------------------------------------------------------------ select action
    def validate_choice(self, object_name: str, strategy: str, horizon: int, delta: float, codes) -> None:
        """Raise RequestError (with the interface's codes) for a bad strategy, H, δ or object."""
        if strategy not in STRATEGIES:
            raise RequestError(codes.UNKNOWN_STRATEGY, f"unknown strategy {strategy!r}; valid: {list(STRATEGIES)}")
        if not 1 <= horizon <= 3:
            raise RequestError(codes.INVALID_HORIZON, f"horizon must be 1, 2 or 3, got {horizon}")
        if not 0.0 < delta < 1.0:  # also false for NaN
            raise RequestError(codes.INVALID_DELTA, f"delta must be in (0, 1), got {delta}")
        if object_name not in OBJECT_NAMES:
            raise RequestError(codes.UNKNOWN_OBJECT, f"unknown object {object_name!r}; valid: {list(OBJECT_NAMES)}")

    def request_belief(self, req: SelectAction.Request) -> Belief:
        """The belief to plan on: the request's, or the estimator's current one (same object)."""
        msg = req.belief
        if req.use_current_belief:
            if not self.get_client.service_is_ready():
                raise RequestError(SA.NO_BELIEF, "use_current_belief, but the estimator's get_belief is not available")
            current = wait_for(self.get_client.call_async(GetBelief.Request()), 10.0)
            if current.error_code != GetBelief.Response.NONE:
                raise RequestError(SA.NO_BELIEF, f"the estimator has no belief: {current.error_msg}")
            if current.object_name != req.object_name:
                raise RequestError(SA.INVALID_BELIEF, f"the current belief is about {current.object_name!r}, "
                                                      f"not {req.object_name!r}")
            msg = current.belief
        try:
            return belief_from_msg(msg)
        except InvalidGrid as exc:
            raise RequestError(SA.INVALID_GRID, str(exc)) from exc
        except InvalidBelief as exc:
            raise RequestError(SA.INVALID_BELIEF, str(exc)) from exc

    def on_select_action(self, req: SelectAction.Request, resp: SelectAction.Response) -> SelectAction.Response:
        try:
            self.validate_choice(req.object_name, req.strategy, req.horizon, req.delta, SA)
            belief = self.request_belief(req)
            model = self.model(req.object_name)
            try:
                model.level_of(belief.grid)
            except ValueError as exc:
                raise RequestError(SA.INVALID_GRID, str(exc)) from exc
            agent = RobustGraspAgent(model, req.strategy, req.horizon, req.delta)
            t0 = time.perf_counter()
            action, e, res, _ = agent.plan_step(belief, step=1)
            elapsed = time.perf_counter() - t0
            if action < 0:
                raise RequestError(SA.NO_FEASIBLE_ACTION, f"no WRT of {req.object_name} is feasible at "
                                                          f"w* = {np.round(belief.w_star(), 3).tolist()}")
            self.fill_choice(resp, agent, belief, action, res, elapsed)
            resp.estimate = planar_to_msg(e)
        except RequestError as exc:
            resp.error_code, resp.error_msg = exc.code, str(exc)
            self.get_logger().warn(f"select_action refused: {exc}")
        except Exception as exc:  # the node must keep serving whatever the core raises
            resp.error_code, resp.error_msg = SA.UNKNOWN, f"{type(exc).__name__}: {exc}"
            self.get_logger().error(f"select_action failed: {resp.error_msg}")
        return resp

    @staticmethod
    def fill_choice(resp: SelectAction.Response, agent: RobustGraspAgent, belief: Belief, action: int,
                    res: SearchResult | None, elapsed_s: float) -> None:
        """The response of a successful choice. Without a search (open-loop, rrg-goal) the value
        is v(b) and no action values are listed."""
        resp.wrt_name = agent.model.names[action]
        if res is not None:
            values = np.where(np.isfinite(res.action_values), res.action_values, np.nan)
            resp.value, resp.p_goal, resp.planning_time = float(values[action]), res.p_goal, res.planning_time
            resp.action_names, resp.action_values = agent.model.names, values.tolist()
        else:
            resp.p_goal = resp.value = static_value(agent, belief)
            resp.planning_time = elapsed_s

    # ------------------------------------------------------------------ robust grasp
    def on_grasp_goal(self, goal: RobustGrasp.Goal) -> GoalResponse:
        if self._grasp_active.locked():
            self.get_logger().warn("robust_grasp goal rejected: another grasp is running")
            return GoalResponse.REJECT
        return GoalResponse.ACCEPT

    def validate_grasp(self, goal: RobustGrasp.Goal) -> tuple[np.ndarray, np.ndarray, int]:
        """(mean, sigma, max_actions) of a valid goal; RequestError otherwise."""
        self.validate_choice(goal.object_name, goal.strategy, goal.horizon, goal.delta, RG)
        if goal.level not in LEVELS:
            raise RequestError(RG.UNKNOWN_LEVEL, f"unknown level {goal.level!r}; valid: {sorted(LEVELS)}")
        if goal.level not in self.levels:
            raise RequestError(RG.UNKNOWN_LEVEL, f"level {goal.level!r} is not loaded; loaded: {list(self.levels)}")
        override = np.array([goal.sigma_x, goal.sigma_y, goal.sigma_theta])
        if not np.all(np.isfinite(override)) or np.any(override < 0.0):
            raise RequestError(RG.INVALID_SIGMA, f"sigma overrides must be finite and >= 0, got {override.tolist()}")
        sigma = np.where(override > 0.0, override, LEVELS[goal.level].sigma)
        mean = (np.array([goal.initial_mean.x, goal.initial_mean.y, goal.initial_mean.theta])
                if goal.use_initial_mean else np.asarray(WORLD.nominal_pose, dtype=float))
        if not np.all(np.isfinite(mean)):
            raise RequestError(RG.INVALID_SIGMA, f"initial mean must be finite, got {mean.tolist()}")
        max_actions = goal.max_actions or SEARCH.max_actions
        if max_actions > SEARCH.max_actions:
            raise RequestError(RG.INVALID_MAX_ACTIONS, f"max_actions must be 1-{SEARCH.max_actions} "
                                                       f"(0: {SEARCH.max_actions}), got {goal.max_actions}")
        return mean, sigma, max_actions

    def execute_robust_grasp(self, handle: ServerGoalHandle) -> RobustGrasp.Result:
        with self._grasp_active:
            result = RobustGrasp.Result()
            try:
                self.run_grasp(handle, result)
            except RequestError as exc:
                result.error_code, result.error_msg = exc.code, str(exc)
            except WaitInterrupted:
                result.error_code, result.error_msg = RG.CANCELED, "canceled"
            except Exception as exc:  # report, keep serving
                result.error_code, result.error_msg = RG.UNKNOWN, f"{type(exc).__name__}: {exc}"
            if result.error_code == RG.CANCELED and handle.is_cancel_requested:
                handle.canceled()
            elif result.error_code == RG.NONE:
                handle.succeed()
            else:
                handle.abort()
            text = (f"robust grasp ended: success={result.success} actions={list(result.actions_taken)} "
                    f"P(goal)={result.final_p_goal:.3f}")
            if result.error_code == RG.NONE:
                self.get_logger().info(text)
            else:
                self.get_logger().error(f"{text}, error {result.error_code}: {result.error_msg}")
            self.publish_step(handle.request, "done", DiagnosticStatus.OK if result.success else DiagnosticStatus.WARN,
                              success=result.success, actions=",".join(result.actions_taken),
                              p_goal=result.final_p_goal, error_code=result.error_code, error_msg=result.error_msg)
            return result

    def run_grasp(self, handle: ServerGoalHandle, result: RobustGrasp.Result) -> None:
        goal = handle.request
        mean, sigma, max_actions = self.validate_grasp(goal)
        model = self.model(goal.object_name)
        interrupted = lambda: handle.is_cancel_requested or not self.context.ok()  # noqa: E731
        belief_msg = self.reset_belief(goal, mean, sigma, interrupted)
        belief = belief_from_msg(belief_msg)
        agent = RobustGraspAgent(model, goal.strategy, goal.horizon, goal.delta, max_actions)
        while True:  # ends at the last action, which is always the goal grasp
            if interrupted():
                raise WaitInterrupted("canceled")
            step = len(result.actions_taken) + 1  # an infeasible execution (nothing moved) is not an action
            t0 = time.perf_counter()
            action, e, res, last = agent.plan_step(belief, step)
            plan_s = time.perf_counter() - t0
            if action < 0:
                raise RequestError(RG.PLANNING_FAILED, f"no feasible WRT at w* = {np.round(e, 3).tolist()}")
            name, kind = model.names[action], model.actions[action].kind
            p_goal = res.p_goal if res is not None else static_value(agent, belief)
            value = float(res.action_values[action]) if res is not None else p_goal
            handle.publish_feedback(RobustGrasp.Feedback(step=step, wrt_name=name, value=value, p_goal=p_goal,
                                                         belief=belief_msg))
            self.publish_step(goal, f"step {step}: {name}", DiagnosticStatus.OK, step=step, wrt=name, kind=kind,
                              value=value, p_goal=p_goal, planning_time_s=plan_s,
                              estimate=np.round(e, 4).tolist())
            self.get_logger().info(f"step {step}: {name} ({kind}) at e = {np.round(e, 3).tolist()}, "
                                   f"P(goal) = {p_goal:.3f}, planned in {plan_s * 1e3:.0f} ms")
            try:
                obs = self.execute(goal.object_name, name, e, interrupted)
            except InfeasibleWRT as exc:  # nothing moved: rule it out at e and choose again (as the agent does)
                self.get_logger().warn(f"{name} infeasible at {np.round(e, 3).tolist()} ({exc}): replanning")
                self.publish_step(goal, f"step {step}: {name} infeasible, replanning", DiagnosticStatus.WARN,
                                  step=step, infeasible=name, estimate=np.round(e, 4).tolist())
                agent.search.block(action, e)
                if len(agent.search.blocked) > MAX_BLOCKED:
                    raise RequestError(RG.PLANNING_FAILED, f"{len(agent.search.blocked)} infeasible executions") \
                        from exc
                continue
            result.actions_taken.append(name)
            agent.executed(action, e)
            belief_msg = self.wait_for_belief(obs.header.stamp, self.get_parameter("belief_timeout").value,
                                              interrupted)
            belief = belief_from_msg(belief_msg)
            p_exec = agent.grasp_probability(belief, action, e)
            result.final_belief, result.final_p_goal = belief_msg, p_exec if kind == "goal" else p_goal
            if agent.finished(action, p_exec, last):
                result.success = bool(p_exec > 1.0 - goal.delta)
                return
            if kind == "goal":  # the executor leaves a goal grasp closed on the object
                self.retreat(interrupted)
                belief = agent.after_retreat(belief, action, e, bool(obs.contact))  # as the estimator will

    # ------------------------------------------------------------------ calls to the other nodes
    def reset_belief(self, goal: RobustGrasp.Goal, mean: np.ndarray, sigma: np.ndarray, interrupted) -> BeliefGrid:
        if not self.reset_client.wait_for_service(timeout_sec=10.0):
            raise RequestError(RG.ESTIMATION_FAILED, "the estimator's reset_belief is not available")
        req = ResetBelief.Request(object_name=goal.object_name, mean=planar_to_msg(mean), level=goal.level,
                                  sigma_x=float(sigma[0]), sigma_y=float(sigma[1]), sigma_theta=float(sigma[2]))
        try:
            resp = wait_for(self.reset_client.call_async(req), self.get_parameter("reset_timeout").value, interrupted)
        except WaitTimeout as exc:
            raise RequestError(RG.ESTIMATION_FAILED, f"reset_belief: {exc}") from exc
        if resp.error_code != ResetBelief.Response.NONE:
            raise RequestError(RG.ESTIMATION_FAILED, f"reset_belief failed: {resp.error_msg}")
        return resp.belief

    def execute(self, object_name: str, wrt_name: str, e: np.ndarray, interrupted) -> ObservationMsg:
        """Run ExecuteWrt and return its observation; a cancel request cancels the execution.
        Raises InfeasibleWRT when the executor found τ(e) infeasible before moving."""
        if not self.execute_client.wait_for_server(timeout_sec=10.0):
            raise RequestError(RG.EXECUTION_FAILED, "the executor's execute_wrt is not available")
        goal = ExecuteWrt.Goal(object_name=object_name, wrt_name=wrt_name, estimate=planar_to_msg(e))
        handle = wait_for(self.execute_client.send_goal_async(goal), 10.0)
        if not handle.accepted:
            raise RequestError(RG.EXECUTION_FAILED, f"execute_wrt rejected {wrt_name}")
        timeout = self.get_parameter("execute_timeout").value
        try:
            answer = wait_for(handle.get_result_async(), timeout, interrupted)
        except WaitInterrupted:
            wait_for(handle.cancel_goal_async(), 10.0)
            raise
        except WaitTimeout as exc:
            handle.cancel_goal_async()
            raise RequestError(RG.EXECUTION_FAILED, f"execute_wrt {wrt_name}: {exc}") from exc
        if answer.result.error_code == ExecuteWrt.Result.INFEASIBLE:
            raise InfeasibleWRT(answer.result.error_msg)
        if answer.result.error_code != ExecuteWrt.Result.NONE:
            raise RequestError(RG.EXECUTION_FAILED, f"execute_wrt {wrt_name} failed: {answer.result.error_msg}")
        return answer.result.observation

    def retreat(self, interrupted) -> None:
        if not self.retreat_client.wait_for_service(timeout_sec=10.0):
            raise RequestError(RG.EXECUTION_FAILED, "the executor's retreat is not available")
        resp = wait_for(self.retreat_client.call_async(Trigger.Request()),
                        self.get_parameter("execute_timeout").value, interrupted)
        if not resp.success:
            raise RequestError(RG.EXECUTION_FAILED, f"retreat failed: {resp.message}")

    def publish_step(self, goal: RobustGrasp.Goal, message: str, level: bytes, **values) -> None:
        self.step_pub.publish(diagnostic("robust_grasp", message, level,
                                         dict(object=goal.object_name, strategy=goal.strategy, **values)))


def main(argv: list[str] | None = None) -> int:
    return run_node(PlannerNode, multi_threaded=True, argv=argv)


if __name__ == "__main__":
    sys.exit(main())
