"""The whole simulated graph, end to end, as ``rrg-launch`` runs it: each node in its own process,
a robust grasp of the box at low uncertainty judged a success by the simulator, a bag that
rosbags and Foxglove's readers decode completely, ``rrg-bag plot`` and ``summary`` on it; and
Ctrl-C in the middle of a grasp still leaves a finalized bag."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time

import pytest
import yaml
from ros_testing import ROOT, ros_env
from rosbags.highlevel import AnyReader

from rrg_planner.bags.bag_cli import bag_info
from rrg_planner.bags.bag_cli import main as bag_cli

NODE_MODULES = ROOT / ".cache" / "npm" / "node_modules"
LAUNCH = [sys.executable, "-m", "rrg_planner.bringup.launch"]
#: Every topic the graph publishes during a grasp (the recorder must have them all).
GRAPH_TOPICS = {
    "/rrg/joint_states",
    "/rrg/fingertip1/wrench",
    "/rrg/fingertip2/wrench",
    "/rrg/fingertip3/wrench",
    "/rrg/contact_pads",
    "/rrg/eval/object_pose",
    "/rrg/eval/grasp_outcome",
    "/rrg/observation",
    "/rrg/belief",
    "/rrg/belief_markers",
    "/rrg/grasp_step",
    "/rosout",
}


def launch_args(tmp_path, name: str, domain_id: int, *extra: str) -> list[str]:
    return [
        *LAUNCH,
        "--grasp",
        "box",
        "--level",
        "low",
        "--levels",
        "low",
        "--domain-id",
        str(domain_id),
        "--bags",
        str(tmp_path),
        "--bag-name",
        name,
        "--log-dir",
        str(tmp_path / f"{name}_logs"),
        *extra,
    ]


@pytest.fixture(scope="module")
def grasp_run(tmp_path_factory):
    """One launcher run: returns (its JSON outcome, the bag folder, its stdout)."""
    tmp = tmp_path_factory.mktemp("graph")
    out = subprocess.run(
        launch_args(tmp, "e2e", 43, "--seed", "4", "--json"),
        env=ros_env(43),
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert out.returncode == 0, out.stdout + out.stderr
    return json.loads(out.stdout.strip().splitlines()[-1]), tmp / "e2e", out.stdout


def test_robust_grasp_of_the_box_succeeds_as_judged_by_the_simulator(grasp_run):
    outcome, _, stdout = grasp_run
    assert outcome["error"] == ""
    assert outcome["success"], outcome["judge"]
    assert outcome["judge"].startswith("SUCCESS") and "held True" in outcome["judge"]
    assert outcome["actions"] and outcome["actions"][-1] == "goal"
    assert outcome["planner_success"] and outcome["p_goal"] > 0.9
    assert "step 1:" in stdout and "finalized" in stdout


def test_bag_records_every_topic_and_rosbags_decodes_every_message(grasp_run):
    outcome, bag, _ = grasp_run
    assert sorted(p.name for p in bag.iterdir()) == ["e2e_0.mcap", "metadata.yaml"]
    info = bag_info(bag)
    assert info.finalized and info.profile == "ros2"
    counts = {t.name: t.count for t in info.topics}
    assert GRAPH_TOPICS <= set(counts), GRAPH_TOPICS - set(counts)
    meta = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert meta["message_count"] == info.message_count
    decoded: dict[str, list] = {}
    with AnyReader([bag]) as reader:
        for conn, _, raw in reader.messages():
            decoded.setdefault(conn.topic, []).append(reader.deserialize(raw, conn.msgtype))
    assert {t: len(m) for t, m in decoded.items()} == {t: n for t, n in counts.items() if n}
    assert [o.wrt_name for o in decoded["/rrg/observation"]] == outcome["actions"]
    assert (
        len(decoded["/rrg/belief"]) == len(outcome["actions"]) + 1
    )  # the reset, then one per action
    assert decoded["/rrg/belief"][-1].weights.size == 31 * 31 * 25
    assert decoded["/rrg/eval/grasp_outcome"][-1].message.startswith("SUCCESS")
    assert decoded["/rrg/joint_states"][-1].name[:7] == [f"wam_j{i}" for i in range(1, 8)]


def test_foxglove_readers_decode_the_graph_bag(grasp_run):
    _, bag, _ = grasp_run
    out = subprocess.run(
        [
            "node",
            str(ROOT / "tests" / "foxglove_bag_reader.cjs"),
            str(NODE_MODULES),
            str(bag / "e2e_0.mcap"),
        ],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode == 0, out.stderr
    topics = json.loads(out.stdout)[
        "topics"
    ]  # (CDR's end padding counts as trailing bytes there: benign)
    assert {t: v["count"] for t, v in topics.items()} == {
        t.name: t.count for t in bag_info(bag).topics
    }
    assert GRAPH_TOPICS <= set(topics)


def test_bag_plot_and_summary(grasp_run, capsys):
    outcome, bag, _ = grasp_run
    out = bag.with_name("plots")
    assert bag_cli(["plot", str(bag), "--out", str(out)]) == 0
    pngs = sorted(out.glob("*.png"))
    assert len(pngs) == len(outcome["actions"]) + 2  # a PNG per belief, and the overview
    assert all(p.read_bytes()[:4] == b"\x89PNG" for p in pngs)
    assert bag_cli(["summary", str(bag)]) == 0
    text = capsys.readouterr().out
    for k, name in enumerate(outcome["actions"], 1):
        assert f"step {k}: {name}" in text
    assert "Simulator: SUCCESS" in text and "Planner:   success = True" in text


def test_ctrl_c_mid_grasp_leaves_a_finalized_bag(tmp_path):
    """SIGINT while the first WRT executes (the simulator paced at real time to make the grasp
    last): the launcher cancels the grasp, stops the nodes and the recorder in order."""
    proc = subprocess.Popen(
        launch_args(tmp_path, "interrupted", 44, "--real-time-factor", "1"),
        env=ros_env(44),
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    lines = []
    try:
        for line in proc.stdout:  # until the first action is under way
            lines.append(line)
            if "step 1:" in line:
                break
        assert lines and "step 1:" in lines[-1], "".join(lines)
        time.sleep(1.0)  # inside the WRT's guarded moves
        proc.send_signal(signal.SIGINT)
        rest, _ = proc.communicate(timeout=60)
    except BaseException:
        proc.kill()
        raise
    text = "".join(lines) + rest
    assert proc.returncode == 1, text  # interrupted grasp
    assert (
        "interrupted: stopping the graph" in text
        and "finalized" in text
        and "NOT finalized" not in text
    )
    bag = tmp_path / "interrupted"
    info = bag_info(bag)
    assert info.finalized and info.message_count > 0
    assert (bag / "metadata.yaml").is_file()
    with AnyReader([bag]) as reader:
        assert sum(1 for _ in reader.messages()) == info.message_count


def test_hw_mode_fails_clearly():
    out = subprocess.run(
        [*LAUNCH, "--mode", "hw"], capture_output=True, text=True, timeout=60, cwd=ROOT
    )
    assert out.returncode == 2
    assert "rrg_hw_bridge" in out.stderr and "does not exist yet" in out.stderr
