r"""The planner node (design §7): the select-action service that other robot software calls, and
the robust-grasp action that runs the whole loop.

    python -m rrg_planner.ros.planner_node \
        [--ros-args -p preload:="['powerdrill']" -p levels:="['high','mid','low']"]

Services and actions:
* ``/rrg/select_action`` (rrg_msgs/SelectAction): the next WRT for a given belief (or the
  estimator's current one), a strategy, H and δ. Every input is validated before the core sees
  it; a bad one gets its error code and a message, and the node keeps serving.
* ``/rrg/robust_grasp`` (rrg_msgs/RobustGrasp): reset the belief through the estimator, then run
  the closed loop (rrg_planner.closed_loop) with the executor and estimator nodes as its World
  and Estimator (rrg_planner.ros.graph_client), with feedback at every step, until the agent's
  stopping rule holds. Cancellable between and during actions.
* publishes ``/rrg/grasp_step`` (rrg_msgs/GraspStep): one typed record per chosen action, one per
  WRT found infeasible before it moved, and one when a grasp ends, so a bag holds the decisions
  (``rrg-bag summary`` reads them; a bag viewer can plot P(goal) over a run).
* publishes its health on ``/diagnostics`` once a second (``planner: status``: models loaded,
  the last select_action and step, the executor and the estimator).

The decisions are the core's (rrg_planner.agent.RobustGraspAgent) and the belief is the estimator
node's: this node only moves messages.

Recovery (operations §8): with ``state_file`` set, the node writes a running grasp's progress
(rrg_planner.grasp_state) after every step. A restarted planner that receives the same robust
grasp again with ``resume`` set goes on with it: it brings the hand home through the executor,
then decides on the estimator's current belief with the steps it had taken. Lost executions
and restarted executor or estimator nodes are the graph client's to recover
(rrg_planner.ros.graph_client).
"""

from __future__ import annotations

import sys
import threading
import time
from pathlib import Path

import numpy as np
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.action.server import ServerGoalHandle
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.node import Node
from rclpy.parameter import Parameter

from rrg_common.ros.diagnostics import ERROR, Health, NodeDiagnostics, milliseconds
from rrg_common.ros.futures import WaitInterrupted, wait_for
from rrg_common.ros.liveliness import announce
from rrg_common.ros.msg_conversions import planar_to_msg
from rrg_common.ros.node_main import destroy_action_endpoints, run_node
from rrg_common.ros.parameters import Param, declare
from rrg_common.ros.qos import RESULT_TIMEOUT_S
from rrg_common.state_file import StateError
from rrg_estimator.belief import Belief
from rrg_estimator.config import LEVELS
from rrg_estimator.ros.belief_msgs import InvalidBelief, InvalidGrid, belief_from_msg
from rrg_estimator.ros.likelihood_param import declare_unsensed_sensors
from rrg_models.config import WORLD
from rrg_msgs.action import RobustGrasp
from rrg_msgs.msg import GraspStep
from rrg_msgs.srv import GetBelief, SelectAction
from rrg_planner import request_checks
from rrg_planner.agent import RobustGraspAgent
from rrg_planner.closed_loop import ClosedLoop, Decision, GraspCanceled, decide
from rrg_planner.grasp_state import GraspState, load_grasp_state, save_grasp_state
from rrg_planner.planning_model import PlanningModel
from rrg_planner.request_checks import InvalidRequest
from rrg_planner.ros.graph_client import GraphClient, GraphError
from rrg_planner.ros.grasp_records import (
    decision_record,
    done_record,
    goal_check_record,
    infeasible_record,
    interrupted_record,
    resumed_record,
)
from rrg_sim.config import WORLD_PROFILES, world_profile

NODE_NAME = "planner"
NAMESPACE = "rrg"
SA = SelectAction.Response
RG = RobustGrasp.Result


class RequestError(Exception):
    """A request the node refuses: carries the interface's error code and the message."""

    def __init__(self, code: int, message: str):
        super().__init__(message)
        self.code = code

    @classmethod
    def of(cls, exc: InvalidRequest, codes) -> RequestError:
        """The interface's code for a core validation error (codes: SelectAction.Response or
        RobustGrasp.Result)."""
        return cls(getattr(codes, exc.code), str(exc))


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


class PlannerNode(Node):
    """Select-action service and robust-grasp action over the planning core."""

    def __init__(self) -> None:
        super().__init__(NODE_NAME, namespace=NAMESPACE)
        declare(self, PARAMETERS)
        self.likelihood = declare_unsensed_sensors(self)
        state_file = self.get_parameter("state_file").value
        self.state_file = Path(state_file) if state_file else None
        self.levels = tuple(self.get_parameter("levels").value)
        self.world_profile = world_profile(self.get_parameter("world_profile").value)
        unknown = [lv for lv in self.levels if lv not in LEVELS]
        if unknown:
            raise ValueError(f"unknown levels {unknown}; valid: {sorted(LEVELS)}")
        self._models: dict[str, PlanningModel] = {}
        self._model_lock = threading.Lock()
        self._loading = ""  # the object whose planning model is being loaded
        #: the last select_action's (answer, latency [s]) and the last grasp step's (text,
        #: planning time [s]), for /diagnostics
        self._last_select: tuple[str, float] | None = None
        self._last_step: tuple[str, float] | None = None
        for name in self.get_parameter_or("preload", Parameter("preload", value=[])).value:
            self.model(name)

        group = ReentrantCallbackGroup()
        self.graph = GraphClient(self, group, self.timeouts)
        self.step_pub = self.create_publisher(GraspStep, "grasp_step", 10)
        self.get_client = self.create_client(GetBelief, "get_belief", callback_group=group)
        self._grasp_active = threading.Lock()
        self.create_service(
            SelectAction, "select_action", self.on_select_action, callback_group=group
        )
        ActionServer(
            self,
            RobustGrasp,
            "robust_grasp",
            execute_callback=self.execute_robust_grasp,
            goal_callback=self.on_grasp_goal,
            cancel_callback=lambda _: CancelResponse.ACCEPT,
            callback_group=group,
            result_timeout=RESULT_TIMEOUT_S,
        )
        announce(self, NODE_NAME)
        self.diagnostics = NodeDiagnostics(self, self.health)
        self.get_logger().info(
            f"planner ready (levels {list(self.levels)}, models loaded: {sorted(self._models)})"
        )

    def destroy_node(self) -> None:
        destroy_action_endpoints(self)
        super().destroy_node()

    def timeouts(self) -> dict[str, float]:
        """The graph client's timeouts [s], read from the parameters at each use."""
        return {
            name: self.get_parameter(f"{name}_timeout").value
            for name in ("reset", "execute", "belief", "restart")
        }

    def health(self) -> Health:
        """For /diagnostics: the planning models loaded (WRTs per object and level), the last
        select_action's answer and latency, the last grasp step, and the executor and the
        estimator (WARN while one is not up: a grasp waits for it, ERROR once it is lost)."""
        health = Health(values={"levels": ", ".join(self.levels)})
        models = dict(self._models)
        health.values["models loaded"] = ", ".join(sorted(models)) or "none"
        for name, model in sorted(models.items()):
            for level in model.levels:
                health.values[f"tables {name}/{level}"] = f"{len(model.actions)} WRTs"
        health.values["loading"] = self._loading or "nothing"
        if self._loading:
            health.message = f"loading the planning model of {self._loading}"
        health.values["robust grasp"] = "running" if self._grasp_active.locked() else "idle"
        answer, latency = self._last_select or ("none", None)
        health.values["last select_action"] = answer
        health.values["last select_action latency [ms]"] = milliseconds(latency)
        step, planning = self._last_step or ("none", None)
        health.values["last step"] = step
        health.values["last step planning time [ms]"] = milliseconds(planning)
        return health.peers((self.graph.executor, self.graph.estimator), lost_level=ERROR)

    # ------------------------------------------------------------------ models
    def model(self, object_name: str) -> PlanningModel:
        """The object's planning model, loaded on first use (a first build takes ~1 min)."""
        with self._model_lock:
            if object_name not in self._models:
                self._loading = object_name
                self.get_logger().info(
                    f"loading the planning model of {object_name} at levels "
                    f"{list(self.levels)} (building missing tables takes ~1 min per object)"
                )
                t0 = time.monotonic()
                # workers=1: forking a table-building pool from a process running DDS threads can
                # deadlock; rrg-launch builds missing tables in parallel before it starts the nodes.
                try:
                    self._models[object_name] = PlanningModel(
                        object_name,
                        levels=self.levels,
                        workers=1,
                        progress=False,
                        world=self.world_profile,
                        likelihood=self.likelihood,
                    )
                finally:
                    self._loading = ""
                self.get_logger().info(
                    f"model of {object_name} loaded in {time.monotonic() - t0:.1f} s: "
                    f"WRTs {self._models[object_name].names}"
                )
            return self._models[object_name]

    # ------------------------------------------------------------------ select action
    def request_belief(self, req: SelectAction.Request) -> Belief:
        """The belief to plan on: the request's, or the estimator's current one (same object)."""
        msg = req.belief
        if req.use_current_belief:
            if not self.get_client.service_is_ready():
                raise RequestError(
                    SA.NO_BELIEF,
                    "use_current_belief, but the estimator's get_belief is not available",
                )
            current = wait_for(self.get_client.call_async(GetBelief.Request()), 10.0)
            if current.error_code != GetBelief.Response.NONE:
                raise RequestError(
                    SA.NO_BELIEF, f"the estimator has no belief: {current.error_msg}"
                )
            if current.object_name != req.object_name:
                raise RequestError(
                    SA.INVALID_BELIEF,
                    f"the current belief is about {current.object_name!r}, not {req.object_name!r}",
                )
            msg = current.belief
        try:
            return belief_from_msg(msg)
        except InvalidGrid as exc:
            raise RequestError(SA.INVALID_GRID, str(exc)) from exc
        except InvalidBelief as exc:
            raise RequestError(SA.INVALID_BELIEF, str(exc)) from exc

    def on_select_action(
        self, req: SelectAction.Request, resp: SelectAction.Response
    ) -> SelectAction.Response:
        t0 = time.monotonic()
        self.select_action(req, resp)
        answer = resp.wrt_name if resp.error_code == SA.NONE else f"error {resp.error_code}"
        self._last_select = (f"{req.object_name}: {answer}", time.monotonic() - t0)
        self.diagnostics.force_update()
        return resp

    def select_action(self, req: SelectAction.Request, resp: SelectAction.Response) -> None:
        """Fill ``resp`` with the answer to ``req``."""
        try:
            try:
                request_checks.check_choice(req.strategy, req.horizon, req.delta)
                request_checks.check_object(req.object_name)
            except InvalidRequest as exc:
                raise RequestError.of(exc, SA) from exc
            belief = self.request_belief(req)
            model = self.model(req.object_name)
            try:
                model.level_of(belief.grid)
            except ValueError as exc:
                raise RequestError(SA.INVALID_GRID, str(exc)) from exc
            decision = decide(
                RobustGraspAgent(model, req.strategy, req.horizon, req.delta), belief, number=1
            )
            if decision.action < 0:
                raise RequestError(
                    SA.NO_FEASIBLE_ACTION,
                    f"no WRT of {req.object_name} is feasible at "
                    f"w* = {np.round(belief.w_star(), 3).tolist()}",
                )
            resp.wrt_name, resp.estimate = decision.wrt, planar_to_msg(decision.estimate)
            resp.value, resp.p_goal, resp.planning_time = (
                decision.value,
                decision.p_goal,
                decision.planning_time,
            )
            if decision.search is not None:
                values = decision.search.action_values
                resp.action_names = model.names
                resp.action_values = np.where(np.isfinite(values), values, np.nan).tolist()
        except RequestError as exc:
            resp.error_code, resp.error_msg = exc.code, str(exc)
            self.get_logger().warning(f"select_action refused: {exc}")
        except Exception as exc:  # the node must keep serving whatever the core raises
            resp.error_code, resp.error_msg = SA.UNKNOWN, f"{type(exc).__name__}: {exc}"
            self.get_logger().error(f"select_action failed: {resp.error_msg}")

    # ------------------------------------------------------------------ robust grasp
    def on_grasp_goal(self, goal: RobustGrasp.Goal) -> GoalResponse:
        if self._grasp_active.locked():
            self.get_logger().warning("robust_grasp goal rejected: another grasp is running")
            return GoalResponse.REJECT
        return GoalResponse.ACCEPT

    def validate_grasp(self, goal: RobustGrasp.Goal) -> tuple[np.ndarray, np.ndarray, int]:
        """(mean, sigma, max_actions) of a valid goal; RequestError otherwise."""
        try:
            request_checks.check_choice(goal.strategy, goal.horizon, goal.delta)
            request_checks.check_object(goal.object_name)
            request_checks.check_level(goal.level, self.levels)
            mean = (
                [goal.initial_mean.x, goal.initial_mean.y, goal.initial_mean.theta]
                if goal.use_initial_mean
                else WORLD.nominal_pose
            )
            mean, sigma = request_checks.grasp_prior(
                goal.level, [goal.sigma_x, goal.sigma_y, goal.sigma_theta], mean
            )
            return mean, sigma, request_checks.max_actions(goal.max_actions)
        except InvalidRequest as exc:
            raise RequestError.of(exc, RG) from exc

    def execute_robust_grasp(self, handle: ServerGoalHandle) -> RobustGrasp.Result:
        with self._grasp_active:
            result = RobustGrasp.Result()
            try:
                self.run_grasp(handle, result)
            except (RequestError, GraphError) as exc:
                result.error_code, result.error_msg = exc.code, str(exc)
            except (WaitInterrupted, GraspCanceled):
                result.error_code, result.error_msg = RG.CANCELED, "canceled"
            except Exception as exc:  # report, keep serving
                result.error_code, result.error_msg = RG.UNKNOWN, f"{type(exc).__name__}: {exc}"
            if self.graph.belief_msg is not None:
                result.final_belief = self.graph.belief_msg
            if result.error_code == RG.CANCELED and handle.is_cancel_requested:
                handle.canceled()
            elif result.error_code == RG.NONE:
                handle.succeed()
            else:
                handle.abort()
            text = (
                f"robust grasp ended: success={result.success} "
                f"actions={list(result.actions_taken)} P(goal)={result.final_p_goal:.3f}"
            )
            if result.error_code == RG.NONE:
                self.get_logger().info(text)
            else:
                self.get_logger().error(f"{text}, error {result.error_code}: {result.error_msg}")
            self.step_pub.publish(done_record(handle.request, result, self.now()))
        self.diagnostics.force_update()  # idle again
        return result

    def run_grasp(self, handle: ServerGoalHandle, result: RobustGrasp.Result) -> None:
        goal = handle.request
        mean, sigma, max_actions = self.validate_grasp(goal)
        model = self.model(goal.object_name)
        interrupted = lambda: handle.is_cancel_requested or not self.context.ok()
        agent = RobustGraspAgent(model, goal.strategy, goal.horizon, goal.delta, max_actions)
        request = grasp_request(goal)
        resumed = self.resumable(goal, request)

        def save(loop: ClosedLoop, active: bool = True) -> None:
            if self.state_file is None:
                return
            try:
                save_grasp_state(self.state_file, GraspState.of(request, loop, active))
            except OSError as exc:
                self.get_logger().error(
                    f"could not write the grasp state to {self.state_file} ({exc}); a "
                    "restarted planner could not resume this grasp"
                )

        decisions: list[Decision] = []

        def on_decision(d: Decision) -> None:
            decisions.append(d)
            self._last_step = (
                f"{goal.object_name} step {d.number}: {d.wrt} ({d.kind}), P(goal) {d.p_goal:.3f}",
                d.planning_time,
            )
            self.diagnostics.force_update()
            handle.publish_feedback(
                RobustGrasp.Feedback(
                    step=d.number,
                    wrt_name=d.wrt,
                    value=d.value,
                    p_goal=d.p_goal,
                    belief=self.graph.belief_msg,
                )
            )
            self.step_pub.publish(decision_record(goal, d, self.now()))
            self.get_logger().info(
                f"step {d.number}: {d.wrt} ({d.kind}) at e = {np.round(d.estimate, 3).tolist()}, "
                f"P(goal) = {d.p_goal:.3f}, planned in {d.planning_time * 1e3:.0f} ms"
            )

        def on_infeasible(d: Decision, reason: str) -> None:
            self.get_logger().warning(
                f"{d.wrt} infeasible at {np.round(d.estimate, 3).tolist()} ({reason}): replanning"
            )
            self.step_pub.publish(infeasible_record(goal, d, reason, self.now()))
            save(loop)

        def on_lost(d: Decision, reason: str) -> None:
            self.get_logger().warning(f"{d.wrt} lost ({reason}): replanning on the current belief")
            self.step_pub.publish(interrupted_record(goal, d, reason, self.now()))

        def on_step(step, belief) -> None:
            result.actions_taken.append(step.wrt)
            result.final_p_goal = step.p_goal
            if step.kind == "goal":
                d = decisions[-1]
                self.step_pub.publish(goal_check_record(goal, d, step, belief.frame, self.now()))
                self.get_logger().info(
                    f"goal grasp {d.number} checked: P(goal) = {step.p_goal:.3f} (belief "
                    f"{step.p_goal_belief:.3f} from frame {belief.frame or 'prior'!r}"
                    + (f"; rejected: {'; '.join(step.mismatches)})" if step.mismatches else ")")
                )
            save(loop)

        loop = ClosedLoop(
            agent,
            self.graph,
            self.graph,
            on_decision=on_decision,
            on_infeasible=on_infeasible,
            on_step=on_step,
            canceled=interrupted,
            on_lost=on_lost,
        )
        if resumed is None:
            self.graph.reset(goal.object_name, goal.level, mean, sigma, interrupted)
            save(loop)
        else:
            resumed.restore(loop)
            result.actions_taken.extend(s.wrt for s in resumed.steps)
            reason = f"resumed after {len(resumed.steps)} actions: bringing the hand home first"
            self.get_logger().warning(f"robust grasp of {goal.object_name} {reason}")
            self.step_pub.publish(resumed_record(goal, len(resumed.steps), reason, self.now()))
            self.graph.resume(goal.object_name, interrupted)
        try:
            run = loop.run(resume=resumed is not None)
        finally:
            save(loop, active=False)
        if run.error:
            raise RequestError(RG.PLANNING_FAILED, run.error)
        result.final_p_goal, result.success = run.p_goal, run.declared

    def resumable(self, goal: RobustGrasp.Goal, request: dict) -> GraspState | None:
        """The stored grasp a ``resume`` goal goes on with: a running one of the same request."""
        if not goal.resume or self.state_file is None:
            return None
        try:
            state = load_grasp_state(self.state_file)
        except FileNotFoundError:
            state = None
        except StateError as exc:
            self.get_logger().error(f"no grasp to resume: {exc}")
            return None
        if state is None or not state.active or state.request != request:
            self.get_logger().warning(
                f"resume asked for {goal.object_name}, but no running grasp of that request "
                "is stored: starting afresh"
            )
            return None
        return state

    def now(self):
        """The node clock's time as a message stamp."""
        return self.get_clock().now().to_msg()


def grasp_request(goal: RobustGrasp.Goal) -> dict:
    """The fields of a robust-grasp goal that define the grasp (all but ``resume``)."""
    return {
        "object_name": goal.object_name,
        "level": goal.level,
        "sigma": [goal.sigma_x, goal.sigma_y, goal.sigma_theta],
        "initial_mean": [goal.initial_mean.x, goal.initial_mean.y, goal.initial_mean.theta]
        if goal.use_initial_mean
        else None,
        "strategy": goal.strategy,
        "horizon": int(goal.horizon),
        "delta": float(goal.delta),
        "max_actions": int(goal.max_actions),
    }


def main(argv: list[str] | None = None) -> int:
    return run_node(PlannerNode, multi_threaded=True, argv=argv)


if __name__ == "__main__":
    sys.exit(main())
