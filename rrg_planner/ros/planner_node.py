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

Recovery (operations §8): with ``state_file`` set, a running grasp's progress
(rrg_planner.grasp_state) is written after every step (rrg_planner.ros.grasp_run). A
restarted planner that receives the same robust grasp again with ``resume`` set goes on with
it: it brings the hand home through the executor, then decides on the estimator's current
belief with the steps it had taken. Lost executions and restarted executor or estimator nodes
are the graph client's to recover
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
from rrg_common.ros.parameters import declare
from rrg_common.ros.qos import RESULT_TIMEOUT_S
from rrg_estimator.belief import Belief
from rrg_estimator.config import LEVELS
from rrg_estimator.ros.belief_msgs import InvalidBelief, InvalidGrid, belief_from_msg
from rrg_estimator.ros.likelihood_param import declare_unsensed_sensors
from rrg_msgs.action import RobustGrasp
from rrg_msgs.msg import GraspStep
from rrg_msgs.srv import GetBelief, SelectAction
from rrg_planner import request_checks
from rrg_planner.agent import RobustGraspAgent
from rrg_planner.closed_loop import GraspCanceled, decide
from rrg_planner.model_cache import ModelCache
from rrg_planner.planning_model import PlanningModel
from rrg_planner.request_checks import InvalidRequest
from rrg_planner.ros.graph_client import GraphClient, GraphError
from rrg_planner.ros.grasp_records import done_record
from rrg_planner.ros.grasp_run import GraspRun, RequestError
from rrg_planner.ros.planner_parameters import PARAMETERS
from rrg_sim.config import world_profile

NODE_NAME = "planner"
NAMESPACE = "rrg"
SA = SelectAction.Response
RG = RobustGrasp.Result


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
        self.models = ModelCache(
            self.levels, self.world_profile, self.likelihood, self.get_logger()
        )
        #: the last select_action's (answer, latency [s]) and the last grasp step's (text,
        #: planning time [s]), for /diagnostics
        self._last_select: tuple[str, float] | None = None
        self.last_step: tuple[str, float] | None = None
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
        loaded = sorted(self.models.models)
        self.get_logger().info(
            f"planner ready (levels {list(self.levels)}, models loaded: {loaded})"
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
        models = dict(self.models.models)
        health.values["models loaded"] = ", ".join(sorted(models)) or "none"
        for name, model in sorted(models.items()):
            for level in model.levels:
                health.values[f"tables {name}/{level}"] = f"{len(model.actions)} WRTs"
        loading = self.models.loading
        health.values["loading"] = loading or "nothing"
        if loading:
            health.message = f"loading the planning model of {loading}"
        health.values["robust grasp"] = "running" if self._grasp_active.locked() else "idle"
        answer, latency = self._last_select or ("none", None)
        health.values["last select_action"] = answer
        health.values["last select_action latency [ms]"] = milliseconds(latency)
        step, planning = self.last_step or ("none", None)
        health.values["last step"] = step
        health.values["last step planning time [ms]"] = milliseconds(planning)
        return health.peers((self.graph.executor, self.graph.estimator), lost_level=ERROR)

    def model(self, object_name: str) -> PlanningModel:
        """The object's planning model, loaded on first use (a first build takes ~1 min)."""
        return self.models.get(object_name)

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

    def execute_robust_grasp(self, handle: ServerGoalHandle) -> RobustGrasp.Result:
        with self._grasp_active:
            result = RobustGrasp.Result()
            try:
                GraspRun(self, handle, result).run()
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

    def now(self):
        """The node clock's time as a message stamp."""
        return self.get_clock().now().to_msg()


def main(argv: list[str] | None = None) -> int:
    return run_node(PlannerNode, multi_threaded=True, argv=argv)


if __name__ == "__main__":
    sys.exit(main())
