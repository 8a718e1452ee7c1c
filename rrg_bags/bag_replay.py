"""``rrg-bag replay``: the estimator, and optionally the planner, run again on a bag's events.

The recorded observations (``/rrg/observation``) and retreats (``/rrg/retreated``) go through
the estimator's core (rrg_estimator.tracker.BeliefTracker) in recorded order, as the estimator
node applies them (design §7), and each re-estimated belief is compared with the recorded
``/rrg/belief`` of the same stamp. A bag does not hold the reset request (a service call): a
recorded belief whose stamp is no event's is a reset's, and the replay starts from it. The
estimator's ``variable_resolution`` and the planner's ``levels`` come from
``/parameter_events`` when the recorder caught the nodes declaring them, else their defaults.

With the planner, each decision recorded on ``/rrg/grasp_step`` is made again
(closed_loop.decide) on the replayed belief it was made on, with the grasp's recorded strategy,
H and δ, or the ones asked for. The agent spends the reading of each recorded observation and
blocks each recorded infeasible execution, as the planner's agent did.
"""

from __future__ import annotations

import math
import struct
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Channel, Schema

from rrg_bags.bag_info import complete_records
from rrg_bags.bag_read import (
    BELIEF_TOPIC,
    GRASP_STEP_TOPIC,
    OBSERVATION_TOPIC,
    BagMessage,
    read_messages,
)
from rrg_bags.bag_schema import same_layout
from rrg_common.ros.msg_conversions import observation_from_msg, planar_from_msg, stamp_to_ns
from rrg_estimator.config import LEVELS
from rrg_estimator.grid import Grid
from rrg_estimator.ros.belief_msgs import belief_from_msg
from rrg_estimator.tracker import BeliefTracker, CachedTables
from rrg_models.objects import ObjectModel, get_object
from rrg_planner.agent import RobustGraspAgent
from rrg_planner.closed_loop import decide
from rrg_planner.config import REPLAY_TOLERANCE, SEARCH
from rrg_planner.planning_model import PlanningModel

RETREATED_TOPIC = "/rrg/retreated"
PARAMETER_EVENTS_TOPIC = "/parameter_events"
#: The type each topic the replay reads must have.
TOPIC_TYPES = {
    BELIEF_TOPIC: "rrg_msgs/msg/BeliefGrid",
    OBSERVATION_TOPIC: "rrg_msgs/msg/Observation",
    RETREATED_TOPIC: "rrg_msgs/msg/Retreated",
    GRASP_STEP_TOPIC: "rrg_msgs/msg/GraspStep",
    PARAMETER_EVENTS_TOPIC: "rcl_interfaces/msg/ParameterEvent",
}
ESTIMATOR_NODE = "/rrg/estimator"
PLANNER_NODE = "/rrg/planner"


class UnusableBag(ValueError):
    """Not an MCAP bag, or one without the topics a replay needs or with other message types."""


@dataclass
class BeliefStep:
    """One replayed event and how its belief compares with the recorded one."""

    event: str  # "reset", "observation" or "retreat"
    wrt: str  # the WRT observed or retreated from ("" for a reset)
    stamp_ns: int  # the event's stamp, which its recorded belief carries
    max_abs_diff: float | None = None  # max |p_replayed − p_recorded| over the grid points
    grid_mismatch: str = ""  # how the replayed grid differs from the recorded one
    note: str = ""  # an event the estimator ignored, a belief missing on one side, …
    diverged: bool = False  # differs from the recording beyond the tolerance


@dataclass(frozen=True)
class PlannerSettings:
    """What one robust grasp was (or is now) planned with."""

    strategy: str
    horizon: int
    delta: float
    levels: tuple[str, ...]
    max_actions: int


@dataclass
class DecisionStep:
    """One recorded decision and the one the planner makes on the replayed belief."""

    grasp: int  # index into BagReplay.grasps
    step: int  # the 1-based action number
    recorded_wrt: str
    recorded_estimate: list[float]  # (x [m], y [m], θ [rad])
    recorded_p_goal: float
    wrt: str = ""  # "" when nothing is feasible or no decision could be made
    estimate: list[float] = field(default_factory=list)  # (x [m], y [m], θ [rad])
    p_goal: float = math.nan  # v(b) on the replayed belief
    note: str = ""
    same: bool = False  # the same WRT at the same estimate (within the tolerance)


@dataclass
class BagReplay:
    """A bag's events replayed through the estimator (and the planner)."""

    bag: str
    tolerance: float
    variable_resolution: bool
    variable_resolution_recorded: bool  # read from /parameter_events, not assumed
    beliefs: list[BeliefStep] = field(default_factory=list)
    planner: bool = False
    what_if: bool = False  # planner settings other than the recorded ones were asked for
    levels_recorded: bool = False  # the planner's levels were read from /parameter_events
    grasps: list[PlannerSettings] = field(default_factory=list)
    decisions: list[DecisionStep] = field(default_factory=list)

    @property
    def max_abs_diff(self) -> float | None:
        """The largest difference over every compared belief (None: nothing compared)."""
        diffs = [b.max_abs_diff for b in self.beliefs if b.max_abs_diff is not None]
        return max(diffs) if diffs else None

    @property
    def first_divergence(self) -> int | None:
        """Index into ``beliefs`` of the first belief that diverged (None: none did)."""
        return next((i for i, b in enumerate(self.beliefs) if b.diverged), None)

    @property
    def decisions_differing(self) -> int:
        return sum(not d.same for d in self.decisions)

    @property
    def reproduced(self) -> bool:
        """Every belief, and with the recorded planner settings every decision, reproduced."""
        decisions_ok = self.what_if or self.decisions_differing == 0
        return self.first_divergence is None and decisions_ok

    def to_dict(self) -> dict:
        """Plain JSON data (NaN as None)."""
        out = asdict(self)
        out.update(
            max_abs_diff=self.max_abs_diff,
            first_divergence=self.first_divergence,
            decisions_differing=self.decisions_differing,
            reproduced=self.reproduced,
        )
        return _json_safe(out)


def _json_safe(value):
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: _json_safe(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_json_safe(v) for v in value]
    return value


# --------------------------------------------------------------------------- reading the bag
def recorded_schemas(bag: Path) -> dict[str, Schema | None]:
    """Each recorded topic's schema, over the bag's MCAP files (the file given, or every
    ``.mcap`` file of the folder); UnusableBag for a path that holds no MCAP bag."""
    paths = [bag] if bag.is_file() else sorted(bag.glob("*.mcap")) if bag.is_dir() else []
    if not paths:
        raise UnusableBag(f"no .mcap file in {bag}" if bag.is_dir() else f"no bag at {bag}")
    topics: dict[str, Schema | None] = {}
    for path in paths:
        with path.open("rb") as f:
            try:
                reader = make_reader(f)
                reader.get_header()
            except (McapError, ValueError, EOFError, struct.error) as exc:
                raise UnusableBag(f"{path} is not an MCAP bag ({type(exc).__name__})") from exc
            try:
                summary = reader.get_summary()
            except (McapError, ValueError, EOFError, struct.error):
                summary = None  # a recorder killed before it wrote the summary
        if summary is not None:
            schemas, channels = summary.schemas, list(summary.channels.values())
        else:
            records = list(complete_records(path))
            schemas = {r.id: r for r in records if isinstance(r, Schema)}
            channels = [r for r in records if isinstance(r, Channel)]
        topics.update({c.topic: schemas.get(c.schema_id) for c in channels})
    return topics


def usable(schemas: dict[str, Schema | None], topic: str) -> str:
    """Why the bag's ``topic`` cannot be decoded as this version's TOPIC_TYPES[topic] ("" when
    it can)."""
    if topic not in schemas:
        return f"the bag has no {topic}"
    schema, wanted = schemas[topic], TOPIC_TYPES[topic]
    if schema is None or schema.name != wanted:
        return f"{topic} is {schema.name if schema else 'untyped'}, not {wanted}"
    if not same_layout(schema.name, schema.data.decode("utf-8", errors="replace")):
        return (
            f"{topic} was recorded with another version of the interfaces: its {wanted} "
            "differs from this version's"
        )
    return ""


def grid_mismatch(replayed: Grid, recorded: Grid) -> str:
    """How two grids differ, in words ("" when they are the same grid)."""
    parts = []
    for what, a, b in (
        ("shape", replayed.shape, recorded.shape),
        ("spacing", replayed.spacing, recorded.spacing),
        ("origin", replayed.center, recorded.center),
    ):
        if not np.array_equal(a, b):
            parts.append(f"{what} {np.round(a, 6).tolist()} replayed, {np.round(b, 6).tolist()}")
    return "; ".join(parts)


# --------------------------------------------------------------------------- the replay
class _Replayer:
    """The estimator node's and the planner's sequence, driven by recorded messages."""

    def __init__(self, replay: BagReplay, recorded: dict[int, BagMessage], overrides: dict):
        self.replay = replay
        self.recorded = recorded  # event stamp [ns] → its recorded belief
        self.overrides = overrides  # the planner settings asked for (levels, horizon, …)
        self.tracker: BeliefTracker | None = None
        self.agent: RobustGraspAgent | None = None
        self.planner_levels: tuple[str, ...] | None = None  # as /parameter_events said
        self._tables: dict[str, CachedTables] = {}
        self._models: dict[tuple[str, tuple[str, ...]], PlanningModel] = {}

    def tables(self, obj: ObjectModel) -> CachedTables:
        """The object's tables as the estimator node loads them (one copy per object)."""
        return self._tables.setdefault(obj.name, CachedTables(obj, workers=1))

    # ----------------------------------------------------------------- estimator
    def on_parameters(self, msg) -> None:
        for p in [*msg.new_parameters, *msg.changed_parameters]:
            if msg.node == ESTIMATOR_NODE and p.name == "variable_resolution":
                self.replay.variable_resolution = bool(p.value.bool_value)
                self.replay.variable_resolution_recorded = True
            elif msg.node == PLANNER_NODE and p.name == "levels":
                self.planner_levels = tuple(p.value.string_array_value)

    def on_reset(self, msg, object_name: str) -> None:
        """A recorded reset belief: the estimator starts again from it."""
        step = BeliefStep("reset", "", stamp_to_ns(msg.header.stamp))
        self.tracker, self.agent = None, None
        try:
            obj = get_object(object_name)
            belief = belief_from_msg(msg)
        except (KeyError, ValueError) as exc:
            step.note = f"not replayed: {exc}" if object_name else "no event follows"
        else:
            self.tracker = BeliefTracker(
                obj,
                belief,
                tables=self.tables(obj),
                levels=LEVELS.values(),
                variable_resolution=self.replay.variable_resolution,
            )
            step.note = f"{obj.name}: the replay starts from the recorded belief"
        self.replay.beliefs.append(step)

    def on_observation(self, msg) -> None:
        step = BeliefStep("observation", msg.wrt_name, stamp_to_ns(msg.header.stamp))
        applied = False
        if self.tracker is None:
            step.note = "ignored: no belief yet"
        elif msg.object_name != self.tracker.obj.name:
            step.note = (
                f"ignored: about {msg.object_name!r}, the belief about {self.tracker.obj.name!r}"
            )
        else:
            e = planar_from_msg(msg.estimate)
            try:
                self.tracker.update(msg.wrt_name, e, observation_from_msg(msg))
                applied = True
            except Exception as exc:  # the node logs it and keeps the belief
                step.note = f"ignored: {type(exc).__name__}: {exc}"
            if self.agent is not None and msg.wrt_name in self.agent.model.names:
                self.agent.executed(self.agent.model.index(msg.wrt_name), e)
        self.compare(step, applied)

    def on_retreated(self, msg) -> None:
        step = BeliefStep("retreat", msg.wrt_name, stamp_to_ns(msg.header.stamp))
        if self.tracker is None:
            step.note = "ignored: no belief yet"
        else:
            try:
                self.tracker.retreated()
            except Exception as exc:  # the node logs it and publishes the belief it keeps
                step.note = f"not applied: {type(exc).__name__}: {exc}"
        self.compare(step, self.tracker is not None)

    def compare(self, step: BeliefStep, published: bool) -> None:
        """Compare the replayed belief after ``step`` with the recorded one of its stamp
        (``published``: the estimator node publishes a belief for this event)."""
        self.replay.beliefs.append(step)
        recorded = self.recorded.get(step.stamp_ns)
        if published != (recorded is not None):
            step.diverged = True
            missing = "no recorded belief" if published else "the replay publishes no belief"
            step.note = "; ".join(filter(None, [step.note, f"{missing} of this stamp"]))
            return
        if recorded is None:
            return
        try:
            theirs = belief_from_msg(recorded.msg)
        except ValueError as exc:
            step.diverged, step.note = True, f"recorded belief unreadable: {exc}"
            return
        ours = self.tracker.belief
        step.grid_mismatch = grid_mismatch(ours.grid, theirs.grid)
        if step.grid_mismatch:
            step.diverged = True
            return
        step.max_abs_diff = float(np.max(np.abs(ours.weights - theirs.weights)))
        step.diverged = step.max_abs_diff > self.replay.tolerance

    # ----------------------------------------------------------------- planner
    def on_grasp_step(self, r) -> None:
        if r.event == r.EVENT_DONE:
            self.agent = None
        elif r.event == r.EVENT_INFEASIBLE:
            if self.agent is not None and r.wrt_name in self.agent.model.names:
                self.agent.search.block(
                    self.agent.model.index(r.wrt_name), planar_from_msg(r.estimate)
                )
        elif r.event == r.EVENT_DECISION:
            self.on_decision(r)

    def settings(self, r) -> PlannerSettings:
        """A grasp's planner settings: those asked for, else the recorded ones."""
        o = self.overrides
        levels = o.get("levels") or self.planner_levels or tuple(LEVELS)
        return PlannerSettings(
            r.strategy,
            int(o.get("horizon") or r.horizon),
            float(o.get("delta") or r.delta),
            tuple(levels),
            int(o.get("max_actions") or SEARCH.max_actions),
        )

    def on_decision(self, r) -> None:
        step = DecisionStep(
            len(self.replay.grasps) - 1,
            int(r.step),
            r.wrt_name,
            planar_from_msg(r.estimate).tolist(),
            float(r.p_goal),
        )
        try:
            if self.agent is None:  # the grasp's first decision
                s = self.settings(r)
                key = (r.object_name, s.levels)
                if key not in self._models:
                    self._models[key] = PlanningModel(
                        r.object_name, levels=s.levels, workers=1, progress=False
                    )
                self.agent = RobustGraspAgent(
                    self._models[key], s.strategy, s.horizon, s.delta, s.max_actions
                )
                self.replay.grasps.append(s)
                step.grasp = len(self.replay.grasps) - 1
            if self.tracker is None:
                raise ValueError("no replayed belief")
            d = decide(self.agent, self.tracker.belief, step.step)
        except (KeyError, ValueError) as exc:
            step.note = f"no decision: {exc}"
        else:
            step.wrt, step.estimate, step.p_goal = d.wrt, d.estimate.tolist(), float(d.p_goal)
            step.note = "" if d.action >= 0 else "no feasible action"
            step.same = d.wrt == step.recorded_wrt and np.allclose(
                d.estimate, step.recorded_estimate, rtol=0.0, atol=self.replay.tolerance
            )
        self.replay.decisions.append(step)


def replay_bag(
    bag: str | Path,
    planner: bool = False,
    levels: tuple[str, ...] | None = None,
    horizon: int | None = None,
    delta: float | None = None,
    max_actions: int | None = None,
    tolerance: float = REPLAY_TOLERANCE,
) -> BagReplay:
    """Replay a bag's observations and retreats through the estimator's core, and with
    ``planner`` its decisions through the planner's (levels, horizon, δ, max_actions: other
    settings than the recorded ones; max_actions is not recorded, its default is
    SEARCH.max_actions). Raises UnusableBag for a bag that cannot be replayed."""
    bag = Path(bag)
    schemas = recorded_schemas(bag)
    needed = [BELIEF_TOPIC, OBSERVATION_TOPIC, RETREATED_TOPIC]
    needed += [GRASP_STEP_TOPIC] if planner else []
    problems = [p for p in (usable(schemas, t) for t in needed) if p]
    if problems:
        raise UnusableBag(f"cannot replay {bag}: {'; '.join(problems)}")
    optional = [t for t in (GRASP_STEP_TOPIC, PARAMETER_EVENTS_TOPIC) if not usable(schemas, t)]
    try:
        messages = list(read_messages(bag, set(needed + optional)))
    except Exception as exc:  # a message that does not decode as its recorded type says
        raise UnusableBag(f"cannot decode {bag}: {type(exc).__name__}: {exc}") from exc

    event_topics = (OBSERVATION_TOPIC, RETREATED_TOPIC)
    events = {stamp_to_ns(m.msg.header.stamp) for m in messages if m.topic in event_topics}
    recorded: dict[int, BagMessage] = {}
    for m in messages:
        if m.topic == BELIEF_TOPIC:
            recorded.setdefault(stamp_to_ns(m.msg.header.stamp), m)
    # the object each message's grasp is about: that of the next message that names one
    next_object, name = [""] * len(messages), ""
    for i in reversed(range(len(messages))):
        name = getattr(messages[i].msg, "object_name", "") or name
        next_object[i] = name

    overrides = dict(levels=levels, horizon=horizon, delta=delta, max_actions=max_actions)
    replay = BagReplay(
        str(bag),
        tolerance,
        variable_resolution=True,  # the estimator node's default
        variable_resolution_recorded=False,
        planner=planner,
        what_if=any(v is not None for v in overrides.values()),
    )
    replayer = _Replayer(replay, recorded, {k: v for k, v in overrides.items() if v is not None})
    seen: set[tuple[str, int]] = set()  # (topic, stamp) of what was replayed: each once
    for i, m in enumerate(messages):
        if m.topic == PARAMETER_EVENTS_TOPIC:
            replayer.on_parameters(m.msg)
            continue
        if m.topic == GRASP_STEP_TOPIC:
            if planner:
                replayer.on_grasp_step(m.msg)
            continue
        key = (m.topic, stamp_to_ns(m.msg.header.stamp))
        if key in seen or (m.topic == BELIEF_TOPIC and key[1] in events):
            continue  # a repeated message, or an event's belief (compared at its event)
        seen.add(key)
        if m.topic == BELIEF_TOPIC:
            replayer.on_reset(m.msg, next_object[i])
        elif m.topic == OBSERVATION_TOPIC:
            replayer.on_observation(m.msg)
        else:
            replayer.on_retreated(m.msg)
    replay.levels_recorded = levels is None and replayer.planner_levels is not None
    if not replay.beliefs:
        raise UnusableBag(f"cannot replay {bag}: it records no belief")
    return replay


# --------------------------------------------------------------------------- the report
def _fmt_diff(x: float | None) -> str:
    return "—" if x is None else "0" if x == 0.0 else f"{x:.1e}"


def _fmt_decision(wrt: str, estimate: list[float]) -> str:
    if not wrt:
        return "nothing"
    return f"{wrt} at {np.round(estimate, 4).tolist()}"


def format_replay(r: BagReplay) -> str:
    """The replay as a table: one line per event, then one per decision."""
    source = "recorded" if r.variable_resolution_recorded else "assumed: not in the bag"
    compared = [b for b in r.beliefs if b.max_abs_diff is not None]
    first = r.first_divergence
    if first is None:
        verdict = "every belief reproduced"
    else:
        b = r.beliefs[first]
        verdict = f"first divergence at event {first} ({b.event} {b.wrt}".rstrip() + ")"
    lines = [
        f"Bag:        {r.bag}",
        f"Estimator:  variable resolution {'on' if r.variable_resolution else 'off'} ({source})",
        f"Beliefs:    {len(compared)} compared, max |Δp| = {_fmt_diff(r.max_abs_diff)} "
        f"(tolerance {r.tolerance:.0e}): {verdict}",
        "",
        f"{'#':>3}  {'t [s]':>8}  {'event':<11}  {'WRT':<13}  {'max |Δp|':>9}  note",
    ]
    t0 = r.beliefs[0].stamp_ns
    for i, b in enumerate(r.beliefs):
        note = "; ".join(
            filter(
                None,
                [
                    b.grid_mismatch and f"grids differ: {b.grid_mismatch}",
                    b.note,
                    "DIVERGES" if i == first else "",
                ],
            )
        )
        lines.append(
            f"{i:>3}  {(b.stamp_ns - t0) / 1e9:>8.3f}  {b.event:<11}  {b.wrt or '—':<13}  "
            f"{_fmt_diff(b.max_abs_diff):>9}  {note}"
        )
    if not r.planner:
        return "\n".join(lines)
    lines.append("")
    levels = "recorded" if r.levels_recorded else "asked for" if r.what_if else "assumed"
    for k, s in enumerate(r.grasps):
        lines.append(
            f"Planner:    grasp {k + 1}: {s.strategy}, H = {s.horizon}, δ = {s.delta:g}, "
            f"levels {','.join(s.levels)} ({levels}), at most {s.max_actions} actions"
        )
    n, differing = len(r.decisions), r.decisions_differing
    what = "differ with these settings" if r.what_if else "differ from the recording"
    lines.append(f"Decisions:  {n - differing} of {n} the same, {differing} {what}")
    lines.append("")
    lines.append(f"{'step':>4}  {'recorded':<40}  {'replayed':<40}  same")
    for d in r.decisions:
        replayed = _fmt_decision(d.wrt, d.estimate) if not d.note.startswith("no decision") else ""
        lines.append(
            f"{d.step:>4}  {_fmt_decision(d.recorded_wrt, d.recorded_estimate):<40}  "
            f"{replayed or d.note:<40}  {'yes' if d.same else 'NO'}"
        )
    return "\n".join(lines)
