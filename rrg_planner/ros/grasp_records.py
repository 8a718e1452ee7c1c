"""The planner's typed per-step records of a robust grasp (rrg_msgs/GraspStep on
/rrg/grasp_step)."""

from __future__ import annotations

import numpy as np
from builtin_interfaces.msg import Time
from std_msgs.msg import Header

from rrg_common.ros.msg_conversions import WORLD_FRAME, planar_to_msg
from rrg_msgs.action import RobustGrasp
from rrg_msgs.msg import GraspStep
from rrg_planner.closed_loop import Decision, Step


def _record(goal: RobustGrasp.Goal, event: int, stamp: Time) -> GraspStep:
    return GraspStep(
        header=Header(stamp=stamp, frame_id=WORLD_FRAME),
        event=event,
        object_name=goal.object_name,
        strategy=goal.strategy,
        horizon=goal.horizon,
        delta=goal.delta,
    )


def _with_decision(msg: GraspStep, d: Decision) -> GraspStep:
    msg.step, msg.wrt_name, msg.wrt_kind, msg.estimate = (
        d.number,
        d.wrt,
        d.kind,
        planar_to_msg(d.estimate),
    )
    msg.value, msg.p_goal, msg.planning_time = (
        float(d.value),
        float(d.p_goal),
        float(d.planning_time),
    )
    msg.goal_wrt_name = d.goal_wrt
    msg.action_names = list(d.action_values)
    msg.action_values = [
        float(v) if np.isfinite(v) else float("nan") for v in d.action_values.values()
    ]
    return msg


def decision_record(goal: RobustGrasp.Goal, d: Decision, stamp: Time) -> GraspStep:
    """A WRT was chosen and is about to run."""
    return _with_decision(_record(goal, GraspStep.EVENT_DECISION, stamp), d)


def infeasible_record(goal: RobustGrasp.Goal, d: Decision, reason: str, stamp: Time) -> GraspStep:
    """The chosen WRT could not run at its estimate; nothing moved."""
    msg = _with_decision(_record(goal, GraspStep.EVENT_INFEASIBLE, stamp), d)
    msg.reason = reason
    return msg


def interrupted_record(goal: RobustGrasp.Goal, d: Decision, reason: str, stamp: Time) -> GraspStep:
    """The chosen WRT's execution was lost with a node that died; the hand is home again."""
    msg = _with_decision(_record(goal, GraspStep.EVENT_INTERRUPTED, stamp), d)
    msg.reason = reason
    return msg


def resumed_record(goal: RobustGrasp.Goal, actions: int, reason: str, stamp: Time) -> GraspStep:
    """A restarted planner goes on with the grasp after ``actions`` actions."""
    msg = _record(goal, GraspStep.EVENT_RESUMED, stamp)
    msg.step, msg.reason = actions, reason
    return msg


def goal_check_record(
    goal: RobustGrasp.Goal, d: Decision, step: Step, frame: str, stamp: Time
) -> GraspStep:
    """A goal grasp closed: its P(goal), what the belief says before the grasp's own check,
    the belief's posture frame and what the check found."""
    msg = _with_decision(_record(goal, GraspStep.EVENT_GOAL_CHECKED, stamp), d)
    msg.p_goal, msg.p_goal_belief = float(step.p_goal), float(step.p_goal_belief)
    msg.posture_frame, msg.mismatches = frame, list(step.mismatches)
    return msg


def done_record(goal: RobustGrasp.Goal, result: RobustGrasp.Result, stamp: Time) -> GraspStep:
    """The robust grasp ended, as its action result says."""
    msg = _record(goal, GraspStep.EVENT_DONE, stamp)
    msg.success, msg.actions_taken, msg.final_p_goal = (
        result.success,
        list(result.actions_taken),
        result.final_p_goal,
    )
    msg.error_code, msg.error_msg = result.error_code, result.error_msg
    return msg
