"""A robust grasp's progress on disk, so that a restarted planner can go on with it
(operations §8).

The planner writes the grasp's request, the steps it has taken and the executions it found
infeasible after each of them; a restarted planner reads them back into a ClosedLoop whose
agent has spent and blocked the same (action, estimate) pairs. The belief is not here: the
estimator owns it and restores its own. The file is JSON, written to a temporary file and
renamed over the old one (state_file.write_atomically), so it is always one whole state.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from rrg_common.state_file import check_format, read_state, write_atomically
from rrg_planner.closed_loop import ClosedLoop, Step

#: Bumped when the stored fields change; a state of another format is refused.
STATE_FORMAT = 2


@dataclass
class GraspState:
    """A robust grasp's progress: its request (the RobustGrasp goal's fields), the steps taken,
    the (action, estimate) pairs found infeasible, whether it is still running, and how many
    executions it lost (ClosedLoop.lost)."""

    request: dict
    steps: list[Step] = field(default_factory=list)
    blocked: list[tuple[int, list[float]]] = field(default_factory=list)
    planning_time: float = 0.0  # s
    p_goal: float = float("nan")
    active: bool = True
    lost: int = 0

    @classmethod
    def of(cls, request: dict, loop: ClosedLoop, active: bool = True) -> GraspState:
        """The state of a running (or ended) loop."""
        blocked = [(int(a), [float(v) for v in e]) for a, e in loop.blocked]
        return cls(
            request, list(loop.steps), blocked, loop.planning_time, loop.p_goal, active, loop.lost
        )

    def restore(self, loop: ClosedLoop) -> None:
        """Put a fresh loop where this state left off: its steps, planning time, P(goal) and
        lost executions, and its agent's spent and blocked (action, estimate) pairs."""
        agent = loop.agent
        agent.search.clear()
        for step in self.steps:
            action = agent.model.names.index(step.wrt)
            agent.executed(action, step.estimate)
        for action, e in self.blocked:
            agent.search.block(action, np.asarray(e, dtype=float))
        loop.steps = list(self.steps)
        loop.blocked = [(a, np.asarray(e, dtype=float)) for a, e in self.blocked]
        loop.planning_time, loop.p_goal, loop.lost = self.planning_time, self.p_goal, self.lost


def save_grasp_state(path: Path | str, state: GraspState) -> None:
    """Write ``state`` to ``path`` atomically; OSError if it cannot be written."""
    path = Path(path)
    data = {
        "format": STATE_FORMAT,
        **asdict(state),
        "steps": [
            {**asdict(s), "estimate": np.asarray(s.estimate, dtype=float).tolist()}
            for s in state.steps
        ],
    }
    write_atomically(path, json.dumps(data, allow_nan=True).encode())


def load_grasp_state(path: Path | str) -> GraspState:
    """The state stored at ``path``; FileNotFoundError when there is none, StateError when it
    is not a whole state of this format."""
    errors = (OSError, ValueError, KeyError, TypeError, AttributeError)
    return read_state(path, _parse_grasp_state, "grasp state", errors)


def _parse_grasp_state(path: Path) -> GraspState:
    data = json.loads(path.read_text())
    check_format(path, "grasp state", data.get("format"), STATE_FORMAT, "planner")
    steps = [Step(**{**s, "estimate": np.asarray(s["estimate"])}) for s in data["steps"]]
    return GraspState(
        dict(data["request"]),
        steps,
        [(int(a), list(e)) for a, e in data["blocked"]],
        float(data["planning_time"]),
        float(data["p_goal"]),
        bool(data["active"]),
        int(data["lost"]),
    )
