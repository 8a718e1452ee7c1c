"""Long runs (operations §8): ``rrg-launch --grasps N`` runs N robust grasps in one graph and
reports each grasp, each node's memory, threads and file descriptors, and the event messages the bag
lost. A 10-grasp soak of the box (high uncertainty: several actions per grasp, so retreats
between them) judges every grasp, hangs on none, loses no observation or belief, and ends with
the thread and file-descriptor counts it had after its first grasp."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from ros_testing import ROOT, ros_env

from rrg_bringup.launch import main as launch
from rrg_bringup.soak import (
    FDS_TOLERANCE,
    THREADS_TOLERANCE,
    header_stamp_ns,
    parse_objects,
    proc_sample,
    soak_draws,
)

LAUNCH = [sys.executable, "-m", "rrg_bringup.launch"]
GRASPS = 10
NODES = {"recorder", "sim", "executor", "estimator", "planner"}
#: Every field of the report, of a grasp's record, of a node's figures and of a topic's counts.
REPORT_KEYS = set(
    "grasps_requested grasps_run stopped settings bag judged successes success_rate hung errors "
    "mean_actions mean_wall_s max_wall_s by_object nodes messages targets grasps".split()
)
GRASP_KEYS = set(
    "index object_name true_pose success judged judge planner_success actions p_goal error "
    "wall_s hung".split()
)
NODE_KEYS = set(
    "pids rss_kb_start rss_kb_grasp20 rss_kb_end rss_growth_from_start rss_growth_from_grasp20 "
    "threads_start threads_end fds_start fds_end samples".split()
)
MESSAGE_KEYS = set("produced recorded lost witnessed unrecorded".split())
TARGET_KEYS = set(
    "no_hung_grasp no_lost_message rss_growth_within_10pct stable_threads_and_fds".split()
)


@pytest.fixture(scope="module")
def soak(tmp_path_factory, ros_domain):
    """One 10-grasp soak: (its JSON report, its last-line summary, its stdout)."""
    tmp = tmp_path_factory.mktemp("soak")
    args = [
        *LAUNCH,
        *("--grasps", str(GRASPS), "--objects", "box", "--level", "high", "--seed", "2"),
        *("--domain-id", str(ros_domain), "--bags", str(tmp), "--bag-name", "soak"),
        *("--log-dir", str(tmp / "logs"), "--json"),
    ]
    out = subprocess.run(
        args, env=ros_env(ros_domain), cwd=ROOT, capture_output=True, text=True, timeout=600
    )
    assert out.returncode == 0, out.stdout + out.stderr[-3000:]
    report = json.loads((tmp / "soak_soak.json").read_text())
    return report, json.loads(out.stdout.strip().splitlines()[-1]), out.stdout


@pytest.mark.slow  # ten robust grasps of the ROS graph
def test_every_grasp_of_a_soak_is_judged_and_none_hangs(soak):
    report, summary, stdout = soak
    assert report["grasps_run"] == report["grasps_requested"] == GRASPS
    assert report["stopped"] == "" and report["hung"] == 0 and report["errors"] == 0
    grasps = report["grasps"]
    assert [g["index"] for g in grasps] == list(range(1, GRASPS + 1))
    assert all(g["judged"] and g["judge"] and not g["hung"] and g["actions"] for g in grasps)
    assert report["judged"] == GRASPS
    assert report["successes"] == sum(g["success"] for g in grasps)
    assert stdout.count("[rrg-launch] grasp ") == GRASPS
    assert report["targets"]["no_hung_grasp"] is True


@pytest.mark.slow  # ten robust grasps of the ROS graph
def test_a_soak_loses_no_observation_or_belief(soak):
    """Each action's observation, and each reset's, observation's and retreat's belief, is in
    the bag; the box at high uncertainty takes several actions, so retreats are counted too."""
    report, _, _ = soak
    actions = sum(len(g["actions"]) for g in report["grasps"])
    obs, belief = report["messages"]["/rrg/observation"], report["messages"]["/rrg/belief"]
    assert obs == dict(produced=actions, recorded=actions, lost=0, witnessed=actions, unrecorded=0)
    assert belief["produced"] > GRASPS + actions  # the retreats' beliefs too
    assert belief["lost"] == 0 and belief["unrecorded"] == 0
    assert belief["recorded"] == belief["witnessed"] == belief["produced"]
    assert report["targets"]["no_lost_message"] is True


@pytest.mark.slow  # ten robust grasps of the ROS graph
def test_a_soak_ends_with_the_threads_and_file_descriptors_it_started_with(soak):
    """Measured: every node's thread and descriptor counts after grasp 10 equal those after grasp
    1 (the tolerance covers the MultiThreadedExecutor's worker threads, started on demand)."""
    report, _, _ = soak
    nodes = report["nodes"]
    assert NODES <= set(nodes)
    for name in NODES:
        n = nodes[name]
        assert len(n["pids"]) == 1, name  # never restarted
        assert n["rss_kb_start"] > 0 and n["rss_kb_end"] > 0, name
        assert 0 <= n["threads_end"] - n["threads_start"] <= THREADS_TOLERANCE, (name, n)
        assert n["fds_end"] - n["fds_start"] <= FDS_TOLERANCE, (name, n)
        assert [s[0] for s in n["samples"]] == list(range(GRASPS + 1))
    assert report["targets"]["stable_threads_and_fds"] is True


@pytest.mark.slow  # ten robust grasps of the ROS graph
def test_the_soak_report_has_every_field(soak):
    report, summary, stdout = soak
    assert set(report) == REPORT_KEYS
    assert all(set(g) == GRASP_KEYS for g in report["grasps"])
    assert all(set(n) == NODE_KEYS for n in report["nodes"].values())
    assert all(set(m) == MESSAGE_KEYS for m in report["messages"].values())
    assert set(report["targets"]) == TARGET_KEYS
    assert report["targets"]["rss_growth_within_10pct"] is None  # needs more than 20 grasps
    assert set(summary) == (REPORT_KEYS - {"grasps"}) | {"report"}
    assert all("samples" not in n for n in summary["nodes"].values())
    assert summary["report"].endswith("soak_soak.json")
    for header in ("object", "node", "topic", "targets:"):
        assert any(line.startswith(header) for line in stdout.splitlines()), header


@pytest.mark.slow  # the launcher's graph
def test_a_grasp_past_its_timeout_is_reported_hung_and_stops_the_soak(tmp_path, ros_domain):
    """The simulator at real time and a 1 s grasp timeout: the first grasp is hung, cancelled,
    and the soak stops with exit status 1 and a report."""
    args = [
        *LAUNCH,
        *("--grasps", "3", "--objects", "box", "--level", "low", "--levels", "low"),
        *("--real-time-factor", "1", "--grasp-timeout", "1"),
        *("--domain-id", str(ros_domain), "--no-bag", "--log-dir", str(tmp_path), "--json"),
    ]
    out = subprocess.run(
        args, env=ros_env(ros_domain), cwd=ROOT, capture_output=True, text=True, timeout=300
    )
    assert out.returncode == 1, out.stdout + out.stderr[-3000:]
    summary = json.loads(out.stdout.strip().splitlines()[-1])
    assert summary["grasps_run"] == 1 and summary["hung"] == 1
    assert summary["stopped"] == "grasp 1 hung"
    assert summary["targets"]["no_hung_grasp"] is False
    assert summary["messages"] is None and summary["targets"]["no_lost_message"] is None
    report = json.loads((tmp_path / Path(summary["report"]).name).read_text())
    assert report["grasps"][0]["hung"] and "timed out" in report["grasps"][0]["error"]


def test_soak_draws_use_every_object_once_per_round_and_repeat_with_the_seed():
    objects = ["box", "can", "cup"]
    draws = soak_draws(objects, 7, "high", 5)
    assert len(draws) == 7
    assert sorted(o for o, _ in draws[:3]) == sorted(o for o, _ in draws[3:6]) == objects
    assert draws == soak_draws(objects, 7, "high", 5)
    assert draws != soak_draws(objects, 7, "high", 6)
    assert len({tuple(p) for _, p in draws}) == 7 and np.isfinite(draws[0][1]).all()


def test_soak_arguments_are_checked_before_anything_starts(capsys):
    with pytest.raises(ValueError):
        parse_objects("box,nothing")
    assert launch(["--grasps", "3", "--objects", "box,nothing"]) == 2
    assert launch(["--grasps", "3", "--grasp", "box"]) == 2
    assert launch(["--grasps", "0"]) == 2
    assert launch(["--grasps", "3", "--mode", "hw"]) == 2
    assert "--grasps" in capsys.readouterr().err


def test_proc_sample_reads_memory_threads_and_descriptors():
    s = proc_sample(os.getpid())
    assert s["rss_kb"] > 1000 and s["threads"] >= 1 and s["fds"] >= 3
    assert proc_sample(2**22 + 1) is None  # above the largest pid


def test_header_stamp_of_a_serialized_message():
    from rclpy.serialization import serialize_message

    from rrg_msgs.msg import Observation

    msg = Observation()
    msg.header.stamp.sec, msg.header.stamp.nanosec = 1_700_000_000, 123_456_789
    assert header_stamp_ns(serialize_message(msg)) == 1_700_000_000_123_456_789
