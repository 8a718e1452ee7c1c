"""Long runs: ``rrg-launch --grasps N`` runs N robust grasps back to back in one graph and
reports what they did to it (operations §8).

Each grasp's object and true pose come from ``--seed``: the objects (``--objects``, default all
ten) in shuffled rounds, each once per round, so that every object has been grasped by grasp
``len(objects)``; the pose from the level's Gaussian about the nominal pose, as ``--grasp``
draws it. Every grasp is ``Graph.grasp``: reset_sim, the robust grasp, the simulator's judgement.

Reported, per grasp: the object, its true pose, the simulator's judgement, the actions, P(goal),
the error and the wall time. Per node process (from ``/proc``, after the graph is ready and after
every grasp): resident memory (VmRSS), thread count and open file descriptors; the summary takes
them after grasp 1 (the start), after grasp 20 (the baseline of the memory growth once every
object was used, when N > 20) and after the last grasp (the end).

Messages (with a bag): for ``/rrg/observation`` and ``/rrg/belief``, the messages the grasps
produced against the messages the bag holds (distinct header stamps). Produced observations are
the grasps' actions: each action is one WRT execution, whose observation the executor publishes
once. Produced beliefs: the estimator answers each event with one belief of the event's stamp,
so one per grasp's belief reset, one per observation and one per retreat (the retreats are the
``/rrg/retreated`` messages that the launcher's own subscription received). Lost = produced −
recorded. As a cross-check the launcher subscribes to both topics too: ``unrecorded`` counts the
stamps it received that the bag lacks.

A grasp whose robust grasp has not ended ``--grasp-timeout`` seconds after the planner accepted
it, or whose reset or judgement timed out, is hung: it is reported as such, cancelled, and the
soak stops there (the graph is stuck; what followed would not measure a working graph). A grasp
that ends with an error is reported and the soak goes on, unless a node has died for good (it
used up its restarts).
"""

from __future__ import annotations

import argparse
import json
import os
import struct
import sys
import time
from collections.abc import Iterable
from dataclasses import asdict, dataclass
from functools import partial
from pathlib import Path

import numpy as np
from tqdm import tqdm

from rrg_bringup.graph import GRASP_TIMEOUT_S, Graph, GraspOutcome, draw_pose
from rrg_bringup.supervisor import LaunchError, LaunchTimeout
from rrg_models.objects import object_names

#: The grasp whose sample is the baseline of the memory growth in a long run.
BASELINE_GRASP = 20
#: Target: each node's RSS grows by at most this fraction from BASELINE_GRASP to the last grasp.
RSS_GROWTH_MAX = 0.10
#: Targets: thread and file-descriptor counts after the last grasp may exceed those after grasp 1
#: by at most this many. The executor and the planner spin rclpy's MultiThreadedExecutor with 4
#: worker threads, which Python's ThreadPoolExecutor starts one at a time as callbacks overlap:
#: up to 3 of them may first appear after grasp 1.
THREADS_TOLERANCE = 3
FDS_TOLERANCE = 0
#: The event topics the launcher also subscribes to (every message starts with a std_msgs/Header).
OBSERVATION, RETREATED, BELIEF = "/rrg/observation", "/rrg/retreated", "/rrg/belief"
#: Topics whose produced and recorded messages are compared.
COUNTED = (OBSERVATION, BELIEF)


def parse_objects(text: str) -> list[str]:
    """'a,b,c' → the object names; ValueError for an unknown one."""
    names = [n.strip() for n in text.split(",") if n.strip()]
    installed = object_names()
    unknown = [n for n in names if n not in installed]
    if unknown or not names:
        raise ValueError(f"--objects: unknown {unknown}; installed: {', '.join(installed)}")
    return names


def soak_draws(objects: list[str], n: int, level: str, seed: int) -> list[tuple[str, list[float]]]:
    """N grasps' (object, true pose): the objects in shuffled rounds, the poses from the level's
    Gaussian, all from ``seed``."""
    rng = np.random.default_rng(seed)
    draws: list[tuple[str, list[float]]] = []
    while len(draws) < n:
        for name in rng.permutation(objects)[: n - len(draws)]:
            draws.append((str(name), np.round(draw_pose(rng, level), 5).tolist()))
    return draws


def proc_sample(pid: int) -> dict[str, int] | None:
    """A process's resident memory [kB], threads and open file descriptors, from /proc; None
    when it is gone."""
    try:
        with open(f"/proc/{pid}/status") as f:
            fields = dict(line.split(":", 1) for line in f if ":" in line)
        fds = len(os.listdir(f"/proc/{pid}/fd"))
    except (FileNotFoundError, ProcessLookupError):
        return None
    return {
        "rss_kb": int(fields["VmRSS"].split()[0]),
        "threads": int(fields["Threads"]),
        "fds": fds,
    }


def header_stamp_ns(cdr: bytes) -> int:
    """The header stamp [ns] of a serialized message that begins with a std_msgs/Header."""
    sec, nsec = struct.unpack_from("<iI" if cdr[1] & 1 else ">iI", cdr, 4)
    return sec * 1_000_000_000 + nsec


def bag_stamps(bag_dir: Path, topics: Iterable[str]) -> dict[str, set[int]]:
    """The distinct header stamps of each topic's messages over the bag's files."""
    from rrg_bags.bag_info import bag_files, raw_messages

    stamps: dict[str, set[int]] = {t: set() for t in topics}
    for path in bag_files(bag_dir):
        for _, channel, message in raw_messages(path, stamps):
            stamps[channel.topic].add(header_stamp_ns(message.data))
    return stamps


@dataclass
class SoakGrasp:
    """One grasp of a soak: its outcome (GraspOutcome's fields) and how it went."""

    index: int  # 1-based
    object_name: str
    true_pose: list[float]
    success: bool  # judged by the simulator
    judged: bool
    judge: str
    planner_success: bool
    actions: list[str]
    p_goal: float
    error: str
    wall_s: float
    hung: bool

    @classmethod
    def of(cls, index: int, o: GraspOutcome, wall_s: float, hung: bool) -> SoakGrasp:
        """The record of grasp ``index``, whose outcome is ``o``."""
        return cls(
            index,
            o.object_name,
            o.true_pose,
            o.success,
            bool(o.judge),
            o.judge,
            o.planner_success,
            o.actions,
            float(o.p_goal),
            o.error,
            round(wall_s, 3),
            hung,
        )

    def line(self, total: int) -> str:
        """One line for the log."""
        verdict = (
            "HUNG"
            if self.hung
            else ("SUCCESS" if self.success else "FAILURE")
            if self.judged
            else "not judged"
        )
        return (
            f"[rrg-launch] grasp {self.index}/{total}: {self.object_name} {verdict} in "
            f"{len(self.actions)} actions, P(goal) = {self.p_goal:.3f}, {self.wall_s:.1f} s"
            + (f"; {self.error}" if self.error else "")
        )


class Soak:
    """N robust grasps in one running graph, and the report of what they did to it."""

    def __init__(
        self,
        draws: list[tuple[str, list[float]]],
        settings: dict,
        timeout_s: float = GRASP_TIMEOUT_S,
    ):
        self.draws = draws
        #: level, strategy, horizon, delta, max_actions (Graph.grasp's), and what else to report
        self.settings = settings
        self.timeout_s = timeout_s
        self.grasps: list[SoakGrasp] = []
        self.samples: dict[str, list[dict]] = {}  # node → a sample per grasp (0: graph ready)
        self.pids: dict[str, list[int]] = {}  # node → its processes' pids, in order
        self.stopped = ""  # why the soak ended before its last grasp
        self.witness: dict[str, set[int]] = {OBSERVATION: set(), RETREATED: set(), BELIEF: set()}
        self._subscriptions: list = []

    @classmethod
    def from_args(cls, args: argparse.Namespace) -> Soak:
        """The soak rrg-launch's arguments ask for; ValueError when they cannot make one."""
        real_robot = args.mode == "hw" and not args.fake_hw  # nothing places or judges
        if args.grasps < 1 or args.grasp or args.true_pose or real_robot or args.grasp_timeout <= 0:
            raise ValueError(
                "--grasps N needs N >= 1, a simulated world (sim, or hw with --fake-hw), a "
                "--grasp-timeout > 0, and neither --grasp nor --true-pose"
            )
        settings = {
            k: getattr(args, k)
            for k in ("level", "strategy", "horizon", "delta", "max_actions", "seed", "world")
        }
        draws = soak_draws(parse_objects(args.objects), args.grasps, args.level, args.seed)
        return cls(
            draws, settings | {"real_time_factor": args.real_time_factor}, args.grasp_timeout
        )

    @property
    def objects(self) -> list[str]:
        """The objects the grasps use (the planner preloads them)."""
        return sorted({name for name, _ in self.draws})

    # ------------------------------------------------------------------ running
    def attach(self, graph: Graph) -> None:
        """Subscribe the launcher's node to the event topics (undecoded; before the grasps)."""
        from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

        from rrg_msgs.msg import BeliefGrid, Observation, Retreated

        qos = QoSProfile(
            history=HistoryPolicy.KEEP_ALL,
            reliability=ReliabilityPolicy.RELIABLE,
            durability=DurabilityPolicy.VOLATILE,
        )
        types = {OBSERVATION: Observation, RETREATED: Retreated, BELIEF: BeliefGrid}
        self._subscriptions = [
            graph.node.create_subscription(
                types[topic], topic, partial(self._witnessed, topic), qos, raw=True
            )
            for topic in self.witness
        ]

    def _witnessed(self, topic: str, cdr: bytes) -> None:
        self.witness[topic].add(header_stamp_ns(cdr))

    def sample(self, graph: Graph, grasp: int) -> None:
        """Sample every node process (and the launcher) after grasp ``grasp``."""
        procs = [(c.name, c.proc.pid) for c in graph.children] + [("launcher", os.getpid())]
        for name, pid in procs:
            s = proc_sample(pid)
            if s is None:
                continue
            pids = self.pids.setdefault(name, [])
            if not pids or pids[-1] != pid:
                pids.append(pid)
            self.samples.setdefault(name, []).append({"grasp": grasp, "pid": pid, **s})

    def run(self, graph: Graph) -> int:
        """Run the grasps; 0 when every one ended without error, 1 otherwise."""
        graph.spin_until(
            lambda: all(s.get_publisher_count() for s in self._subscriptions),
            60.0,
            "the launcher's subscriptions to the event topics",
        )
        self.sample(graph, 0)
        total = len(self.draws)
        s = self.settings
        bar = tqdm(self.draws, desc="[rrg-launch] grasps", unit="grasp", file=sys.stderr)
        try:
            for index, (name, pose) in enumerate(bar, 1):
                outcome = GraspOutcome(name, s["level"], s["strategy"], pose)
                hung, t0 = False, time.monotonic()
                try:
                    graph.grasp(
                        outcome,
                        s["horizon"],
                        s["delta"],
                        s["max_actions"],
                        timeout_s=self.timeout_s,
                        verbose=False,
                    )
                except LaunchTimeout as exc:
                    hung, outcome.error = True, str(exc)
                except LaunchError as exc:
                    outcome.error = str(exc)
                record = SoakGrasp.of(index, outcome, time.monotonic() - t0, hung)
                self.grasps.append(record)
                self.sample(graph, index)
                tqdm.write(record.line(total), file=sys.stdout)
                sys.stdout.flush()
                gone = [
                    c.name
                    for c in graph.children
                    if c.proc.poll() is not None and c.restarts >= graph.respawn_max
                ]
                if hung:
                    self.stopped = f"grasp {index} hung"
                    graph.cancel_grasp()
                elif gone:
                    self.stopped = f"after grasp {index}: {', '.join(gone)} died for good"
                if self.stopped:
                    print(f"[rrg-launch] soak stopped: {self.stopped}", flush=True)
                    break
        except KeyboardInterrupt:
            self.stopped = "interrupted"
            raise
        finally:
            bar.close()
        return int(bool(self.stopped or any(g.error for g in self.grasps)))

    # ------------------------------------------------------------------ reporting
    def node_report(self, name: str) -> dict:
        """A node's samples after grasp 1, BASELINE_GRASP and the last, and their changes."""
        by_grasp = {s["grasp"]: s for s in self.samples.get(name, [])}
        last = max(by_grasp, default=0)
        start, base, end = by_grasp.get(1), by_grasp.get(BASELINE_GRASP), by_grasp.get(last)

        def growth(a: dict | None) -> float | None:
            if a is None or end is None or last <= a["grasp"]:
                return None
            return round(end["rss_kb"] / a["rss_kb"] - 1.0, 4)

        return {
            "pids": self.pids.get(name, []),
            "rss_kb_start": start and start["rss_kb"],
            f"rss_kb_grasp{BASELINE_GRASP}": base and base["rss_kb"],
            "rss_kb_end": end and end["rss_kb"],
            "rss_growth_from_start": growth(start),
            f"rss_growth_from_grasp{BASELINE_GRASP}": growth(base),
            "threads_start": start and start["threads"],
            "threads_end": end and end["threads"],
            "fds_start": start and start["fds"],
            "fds_end": end and end["fds"],
            "samples": [
                [s["grasp"], s["rss_kb"], s["threads"], s["fds"]]
                for s in self.samples.get(name, [])
            ],
        }

    def message_report(self, bag_dir: Path) -> dict:
        """Produced, recorded and lost messages of the COUNTED topics (see the module's text)."""
        recorded = bag_stamps(bag_dir, COUNTED)
        done = [g for g in self.grasps if not g.hung]
        observations = sum(len(g.actions) for g in done)
        produced = {
            OBSERVATION: observations,
            BELIEF: len(done) + observations + len(self.witness[RETREATED]),
        }
        return {
            topic: {
                "produced": produced[topic],
                "recorded": len(recorded[topic]),
                "lost": produced[topic] - len(recorded[topic]),
                "witnessed": len(self.witness[topic]),
                "unrecorded": len(self.witness[topic] - recorded[topic]),
            }
            for topic in COUNTED
        }

    def report(self, bag_dir: Path | None) -> dict:
        """The whole report (written as JSON)."""
        g = self.grasps
        judged = [x for x in g if x.judged]
        by_object: dict[str, dict] = {}
        for x in g:
            o = by_object.setdefault(x.object_name, {"grasps": 0, "successes": 0, "actions": 0})
            o["grasps"] += 1
            o["successes"] += int(x.success)
            o["actions"] += len(x.actions)
        nodes = {name: self.node_report(name) for name in self.samples}
        messages = self.message_report(bag_dir) if bag_dir is not None else None
        growth = [
            n[f"rss_growth_from_grasp{BASELINE_GRASP}"]
            for name, n in nodes.items()
            if name != "launcher"
        ]
        children = [n for name, n in nodes.items() if name != "launcher"]
        targets = {
            "no_hung_grasp": not any(x.hung for x in g),
            "no_lost_message": None
            if messages is None
            else all(m["lost"] == 0 and m["unrecorded"] == 0 for m in messages.values()),
            "rss_growth_within_10pct": None
            if None in growth or not growth
            else all(x <= RSS_GROWTH_MAX for x in growth),
            "stable_threads_and_fds": bool(children)
            and all(
                None not in (n["threads_start"], n["threads_end"])
                and n["threads_end"] - n["threads_start"] <= THREADS_TOLERANCE
                and n["fds_end"] - n["fds_start"] <= FDS_TOLERANCE
                and len(n["pids"]) == 1
                for n in children
            ),
        }
        return {
            "grasps_requested": len(self.draws),
            "grasps_run": len(g),
            "stopped": self.stopped,
            "settings": {**self.settings, "grasp_timeout_s": self.timeout_s},
            "bag": str(bag_dir) if bag_dir is not None else None,
            "judged": len(judged),
            "successes": sum(x.success for x in judged),
            "success_rate": round(sum(x.success for x in judged) / len(judged), 4)
            if judged
            else None,
            "hung": sum(x.hung for x in g),
            "errors": sum(bool(x.error) for x in g),
            "mean_actions": round(float(np.mean([len(x.actions) for x in g])), 3) if g else None,
            "mean_wall_s": round(float(np.mean([x.wall_s for x in g])), 3) if g else None,
            "max_wall_s": max((x.wall_s for x in g), default=None),
            "by_object": by_object,
            "nodes": nodes,
            "messages": messages,
            "targets": targets,
            "grasps": [asdict(x) for x in g],
        }


def summary(report: dict) -> dict:
    """The report without its per-grasp records and per-grasp samples (``--json``'s last line)."""
    nodes = {
        name: {k: v for k, v in n.items() if k != "samples"} for name, n in report["nodes"].items()
    }
    return {**{k: v for k, v in report.items() if k != "grasps"}, "nodes": nodes}


def _mb(kb: int | None) -> str:
    return "–" if kb is None else f"{kb / 1024:.1f}"


def _pct(x: float | None) -> str:
    return "–" if x is None else f"{100 * x:+.1f} %"


def _verdict(ok: bool | None) -> str:
    return "not measured" if ok is None else ("met" if ok else "MISSED")


def table(header: list[str], rows: list[list[object]]) -> list[str]:
    """Text table lines: the first column left-aligned, the others right-aligned."""
    cells = [header, *([str(c) for c in row] for row in rows)]
    widths = [max(len(row[i]) for row in cells) for i in range(len(header))]
    return [
        "  ".join(c.ljust(w) if i == 0 else c.rjust(w) for i, (c, w) in enumerate(zip(row, widths)))
        for row in cells
    ]


def format_report(report: dict) -> str:
    """The tables printed at the end of a soak."""
    r, b = report, BASELINE_GRASP
    rate = "–" if r["success_rate"] is None else f"{100 * r['success_rate']:.0f} %"
    lines = [
        f"[rrg-launch] soak: {r['grasps_run']} of {r['grasps_requested']} grasps, {r['judged']} "
        f"judged, {r['successes']} successes ({rate}), {r['hung']} hung, {r['errors']} with an "
        f"error; {r['mean_actions']} actions and {r['mean_wall_s']} s per grasp on average"
        + (f"; stopped: {r['stopped']}" if r["stopped"] else ""),
        "",
        *table(
            ["object", "grasps", "successes", "actions"],
            [
                [name, o["grasps"], o["successes"], f"{o['actions'] / o['grasps']:.1f}"]
                for name, o in sorted(r["by_object"].items())
            ],
        ),
        "",
        *table(
            ["node", "RSS 1 [MB]", f"RSS {b} [MB]", "RSS end [MB]", "growth", f"from {b}"]
            + ["threads", "fds", "pids"],
            [
                [
                    name,
                    _mb(n["rss_kb_start"]),
                    _mb(n[f"rss_kb_grasp{b}"]),
                    _mb(n["rss_kb_end"]),
                    _pct(n["rss_growth_from_start"]),
                    _pct(n[f"rss_growth_from_grasp{b}"]),
                    f"{n['threads_start']}→{n['threads_end']}",
                    f"{n['fds_start']}→{n['fds_end']}",
                    len(n["pids"]),
                ]
                for name, n in r["nodes"].items()
            ],
        ),
    ]
    if r["messages"] is not None:
        keys = ["produced", "recorded", "lost", "witnessed", "unrecorded"]
        rows = [[topic, *(m[k] for k in keys)] for topic, m in r["messages"].items()]
        lines += ["", *table(["topic", *keys], rows)]
    t = r["targets"]
    lines += [
        "",
        f"targets: no hung grasp {_verdict(t['no_hung_grasp'])}; no lost message "
        f"{_verdict(t['no_lost_message'])}; RSS growth ≤ {100 * RSS_GROWTH_MAX:.0f} % from grasp "
        f"{b} {_verdict(t['rss_growth_within_10pct'])}; stable threads and fds "
        f"{_verdict(t['stable_threads_and_fds'])}",
    ]
    return "\n".join(lines)


def default_report_path(bag_dir: Path | None, log_dir: Path | None, name: str) -> Path | None:
    """Beside the bag folder (``<bag>_soak.json``), else in the log folder."""
    if bag_dir is not None:
        return bag_dir.with_name(f"{bag_dir.name}_soak.json")
    if log_dir is not None:
        return log_dir / f"{name}_soak.json"
    return None


def finish(soak: Soak, bag_dir: Path | None, path: Path | None, as_json: bool) -> None:
    """Print the soak's tables, write its report to ``path`` and, with ``as_json``, print the
    summary as JSON on the last line."""
    report = soak.report(bag_dir)
    print(format_report(report), flush=True)
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(report, indent=1) + "\n")
        print(f"[rrg-launch] soak report: {path}", flush=True)
    if as_json:
        print(json.dumps({**summary(report), "report": str(path or "")}), flush=True)
