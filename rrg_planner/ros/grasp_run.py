"""One robust grasp as the planner node runs it (design §7): the goal checked, the closed loop
(rrg_planner.closed_loop) run with the executor and estimator nodes as its World and
Estimator, its feedback, step records and restart state written at every step, and a stored
grasp resumed (operations §8)."""

from __future__ import annotations

import numpy as np
from rclpy.action.server import ServerGoalHandle

from rrg_common.state_file import StateError
from rrg_models.config import WORLD
from rrg_msgs.action import RobustGrasp
from rrg_planner import request_checks
from rrg_planner.agent import RobustGraspAgent
from rrg_planner.closed_loop import MAX_LOST, ClosedLoop, Decision
from rrg_planner.grasp_state import GraspState, load_grasp_state, save_grasp_state
from rrg_planner.request_checks import InvalidRequest
from rrg_planner.ros.grasp_records import (
    decision_record,
    goal_check_record,
    infeasible_record,
    interrupted_record,
    resumed_record,
)

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


def validate_grasp(goal: RobustGrasp.Goal, levels) -> tuple[np.ndarray, np.ndarray, int]:
    """(mean, sigma, max_actions) of a valid goal; RequestError otherwise."""
    try:
        request_checks.check_choice(goal.strategy, goal.horizon, goal.delta)
        request_checks.check_object(goal.object_name)
        request_checks.check_level(goal.level, levels)
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


class GraspRun:
    """One robust-grasp goal on the planner node ``node``, filling ``result``."""

    def __init__(self, node, handle: ServerGoalHandle, result: RobustGrasp.Result):
        self.node, self.handle, self.result = node, handle, result
        self.goal = handle.request
        self.request = grasp_request(self.goal)
        self.decisions: list[Decision] = []
        self.loop: ClosedLoop | None = None
        self.log = node.get_logger()

    def interrupted(self) -> bool:
        return self.handle.is_cancel_requested or not self.node.context.ok()

    def run(self) -> None:
        """Run the grasp to its end (RequestError or GraphError when it fails)."""
        node, goal, result = self.node, self.goal, self.result
        mean, sigma, max_actions = validate_grasp(goal, node.levels)
        model = node.model(goal.object_name)
        agent = RobustGraspAgent(model, goal.strategy, goal.horizon, goal.delta, max_actions)
        resumed = self.resumable()
        self.loop = ClosedLoop(
            agent,
            node.graph,
            node.graph,
            on_decision=self.on_decision,
            on_infeasible=self.on_infeasible,
            on_step=self.on_step,
            canceled=self.interrupted,
            on_lost=self.on_lost,
        )
        if resumed is None:
            node.graph.reset(goal.object_name, goal.level, mean, sigma, self.interrupted)
            self.save()
        else:
            resumed.restore(self.loop)
            result.actions_taken.extend(s.wrt for s in resumed.steps)
            reason = f"resumed after {len(resumed.steps)} actions: bringing the hand home first"
            self.log.warning(f"robust grasp of {goal.object_name} {reason}")
            node.step_pub.publish(resumed_record(goal, len(resumed.steps), reason, node.now()))
            node.graph.resume(goal.object_name, self.interrupted)
        try:
            run = self.loop.run(resume=resumed is not None)
        finally:
            self.save(active=False)
        if run.error:
            lost = self.loop.lost >= MAX_LOST  # the executions, not the planning, failed
            raise RequestError(RG.EXECUTION_FAILED if lost else RG.PLANNING_FAILED, run.error)
        result.final_p_goal, result.success = run.p_goal, run.declared

    def save(self, active: bool = True) -> None:
        """The grasp's progress into the node's state file (when it has one)."""
        state_file = self.node.state_file
        if state_file is None:
            return
        try:
            save_grasp_state(state_file, GraspState.of(self.request, self.loop, active))
        except OSError as exc:
            self.log.error(
                f"could not write the grasp state to {state_file} ({exc}); a "
                "restarted planner could not resume this grasp"
            )

    def on_decision(self, d: Decision) -> None:
        node, goal = self.node, self.goal
        self.decisions.append(d)
        node.last_step = (
            f"{goal.object_name} step {d.number}: {d.wrt} ({d.kind}), P(goal) {d.p_goal:.3f}",
            d.planning_time,
        )
        node.diagnostics.force_update()
        self.handle.publish_feedback(
            RobustGrasp.Feedback(
                step=d.number,
                wrt_name=d.wrt,
                value=d.value,
                p_goal=d.p_goal,
                goal_wrt_name=d.goal_wrt,
                belief=node.graph.belief_msg,
            )
        )
        node.step_pub.publish(decision_record(goal, d, node.now()))
        self.log.info(
            f"step {d.number}: {d.wrt} ({d.kind}) at e = {np.round(d.estimate, 3).tolist()}, "
            f"P(goal) = {d.p_goal:.3f} ({d.goal_wrt or 'no goal grasp can run'}), planned in "
            f"{d.planning_time * 1e3:.0f} ms"
        )

    def on_infeasible(self, d: Decision, reason: str) -> None:
        self.log.warning(
            f"{d.wrt} infeasible at {np.round(d.estimate, 3).tolist()} ({reason}): replanning"
        )
        self.node.step_pub.publish(infeasible_record(self.goal, d, reason, self.node.now()))
        self.save()

    def on_lost(self, d: Decision, reason: str) -> None:
        self.log.warning(f"{d.wrt} lost ({reason}): replanning on the current belief")
        self.node.step_pub.publish(interrupted_record(self.goal, d, reason, self.node.now()))

    def on_step(self, step, belief) -> None:
        result = self.result
        result.actions_taken.append(step.wrt)
        result.final_p_goal = step.p_goal
        if step.kind == "goal":
            d = self.decisions[-1]
            record = goal_check_record(self.goal, d, step, belief.frame, self.node.now())
            self.node.step_pub.publish(record)
            self.log.info(
                f"goal grasp {d.number} checked: P(goal) = {step.p_goal:.3f} (belief "
                f"{step.p_goal_belief:.3f} from frame {belief.frame or 'prior'!r}"
                + (f"; rejected: {'; '.join(step.mismatches)})" if step.mismatches else ")")
            )
        self.save()

    def resumable(self) -> GraspState | None:
        """The stored grasp a ``resume`` goal goes on with: a running one of the same request."""
        goal, state_file = self.goal, self.node.state_file
        if not goal.resume or state_file is None:
            return None
        try:
            state = load_grasp_state(state_file)
        except FileNotFoundError:
            state = None
        except StateError as exc:
            self.log.error(f"no grasp to resume: {exc}")
            return None
        if state is None or not state.active or state.request != self.request:
            self.log.warning(
                f"resume asked for {goal.object_name}, but no running grasp of that request "
                "is stored: starting afresh"
            )
            return None
        return state
