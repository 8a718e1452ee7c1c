"""``rrg-bag summary``: what happened in a recorded robust grasp, step by step.

From the planner's decisions (``/rrg/grasp_step``), the executor's observations
(``/rrg/observation``) and the simulator's judgement (``/rrg/eval/grasp_outcome``, when the
launcher asked for one); and the launcher's restarts of nodes that died
(``/rrg/launch/node_events``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from rrg_bags.bag_read import (
    BELIEF_TOPIC,
    GRASP_OUTCOME_TOPIC,
    GRASP_STEP_TOPIC,
    NODE_EVENTS_TOPIC,
    OBSERVATION_TOPIC,
    read_messages,
)
from rrg_models.config import SENSOR_NAMES


@dataclass
class StepSummary:
    """One executed (or at least chosen) action."""

    step: int
    wrt: str
    kind: str
    estimate: list[float]  # e = w*(b) the WRT ran relative to (x [m], y [m], θ [rad])
    p_goal: float  # P_b(goal) of the belief it was chosen on
    value: float
    planning_time_s: float
    contact: bool | None = None  # None: no observation recorded (e.g. interrupted)
    sensors: list[str] = field(default_factory=list)
    progress_m: float | None = None
    check: str = ""  # a goal grasp's: its P(goal), what it accounts for and what it rejected


@dataclass
class GraspSummary:
    object_name: str = ""
    strategy: str = ""
    steps: list[StepSummary] = field(default_factory=list)
    beliefs: int = 0
    replanned: list[str] = field(default_factory=list)  # WRTs found infeasible before moving
    planner_outcome: dict = field(default_factory=dict)  # the planner's "done" record
    judged_outcome: dict = field(default_factory=dict)  # the simulator's judgement
    node_events: list[str] = field(default_factory=list)  # the launcher's, in words, in order


def summarize(bag: str | Path) -> GraspSummary:
    """The last robust grasp recorded in a bag, and every node exit and restart."""
    s = GraspSummary()
    for m in read_messages(
        bag,
        {GRASP_STEP_TOPIC, OBSERVATION_TOPIC, GRASP_OUTCOME_TOPIC, BELIEF_TOPIC, NODE_EVENTS_TOPIC},
    ):
        if m.topic == NODE_EVENTS_TOPIC:
            s.node_events.append(m.msg.message)
        elif m.topic == BELIEF_TOPIC:
            s.beliefs += 1
        elif m.topic == GRASP_STEP_TOPIC:
            r = m.msg
            estimate = [r.estimate.x, r.estimate.y, r.estimate.theta]
            if (
                r.event == r.EVENT_INFEASIBLE
            ):  # the last chosen step did not move: the planner chose again
                if s.steps and s.steps[-1].wrt == r.wrt_name and s.steps[-1].contact is None:
                    s.steps.pop()
                s.replanned.append(
                    f"step {r.step}: {r.wrt_name} infeasible at e = "
                    f"{np.round(estimate, 4).tolist()}"
                )
            elif r.event == r.EVENT_DECISION:
                if (
                    s.planner_outcome
                ):  # a step after a finished grasp: a new grasp, keep only the last
                    s.steps, s.replanned, s.planner_outcome, s.judged_outcome = [], [], {}, {}
                s.object_name, s.strategy = r.object_name, r.strategy
                s.steps.append(
                    StepSummary(
                        int(r.step),
                        r.wrt_name,
                        r.wrt_kind,
                        estimate,
                        r.p_goal,
                        r.value,
                        r.planning_time,
                    )
                )
            elif r.event == r.EVENT_GOAL_CHECKED:
                if s.steps and s.steps[-1].step == r.step:
                    s.steps[-1].check = (
                        f"P(goal) = {r.p_goal:.3f} (belief {r.p_goal_belief:.3f} from posture "
                        f"frame {r.posture_frame or 'prior'!r})"
                        + (f", rejected: {'; '.join(r.mismatches)}" if r.mismatches else "")
                    )
            elif r.event == r.EVENT_DONE:
                s.planner_outcome = dict(
                    success=r.success,
                    p_goal=r.final_p_goal,
                    actions=list(r.actions_taken),
                    error_code=r.error_code,
                    error_msg=r.error_msg,
                )
        elif m.topic == OBSERVATION_TOPIC:
            pending = [st for st in s.steps if st.contact is None and st.wrt == m.msg.wrt_name]
            if pending:
                st = pending[0]
                st.contact, st.progress_m = bool(m.msg.contact), float(m.msg.progress)
                st.sensors = [n for n, on in zip(SENSOR_NAMES, m.msg.sensors) if on]
        elif m.topic == GRASP_OUTCOME_TOPIC:
            o = m.msg
            s.judged_outcome = dict(
                success=o.success,
                in_region=o.in_region,
                held=o.held,
                offset=[o.offset.x, o.offset.y, o.offset.theta],
                message=o.message,
            )
    return s


def format_summary(s: GraspSummary) -> str:
    restarts = [  # the launcher's node events, one per line
        f"{'Restarts:' if k == 0 else '':<11}{e}" for k, e in enumerate(s.node_events or ["none"])
    ]
    if not s.steps:
        return "\n".join(["no robust grasp recorded in this bag", *restarts])
    lines = [
        f"Object:    {s.object_name}",
        f"Strategy:  {s.strategy}",
        f"Actions:   {len(s.steps)} ({', '.join(st.wrt for st in s.steps)})",
        f"Beliefs:   {s.beliefs} published",
        "",
    ]
    for st in s.steps:
        e = np.round(st.estimate, 3).tolist()
        lines.append(
            f"step {st.step}: {st.wrt:<13} ({st.kind}) at e = {e}   P(goal) = {st.p_goal:.3f}   "
            f"value = {st.value:.3f}   planned in {st.planning_time_s * 1e3:.0f} ms"
        )
        if st.contact is None:
            lines.append("        observation: none recorded")
        else:
            lines.append(
                f"        observation: contact = {'yes' if st.contact else 'no'}, "
                f"progress = {st.progress_m:.3f} m, sensors = {st.sensors or 'none'}"
            )
        if st.check:
            lines.append(f"        goal check: {st.check}")
    lines.append("")
    lines += [f"Replanned: {r} (nothing moved)" for r in s.replanned]
    if s.planner_outcome:
        o = s.planner_outcome
        lines.append(
            f"Planner:   success = {o['success']}, final P(goal) = {o['p_goal']:.3f}"
            + (f", error {o['error_code']}: {o['error_msg']}" if o["error_code"] else "")
        )
    else:
        lines.append("Planner:   no outcome recorded (interrupted?)")
    if s.judged_outcome:
        lines.append(f"Simulator: {s.judged_outcome['message']}")
    return "\n".join([*lines, *restarts])
