"""``rrg-bag replay``: a real robust-grasp bag (the box at low uncertainty, as ``rrg-launch``
records it) replays to the recorded beliefs and decisions; a copy with one observation edited
diverges exactly where the edit is; bags it cannot replay get one line and exit status 2."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import pytest
from builtin_interfaces.msg import Time
from mcap.reader import make_reader
from mcap.writer import Writer
from rclpy.serialization import deserialize_message, serialize_message
from ros_testing import ROOT, ros_env

from rrg_bags.bag_cli import main as bag_cli
from rrg_bags.bag_replay import (
    BagReplay,
    BeliefStep,
    DecisionStep,
    UnusableBag,
    replay_bag,
)
from rrg_bags.bag_schema import full_definition, layout, same_layout
from rrg_bags.bag_writer import Rosbag2McapWriter
from rrg_estimator.belief import Belief
from rrg_estimator.config import LEVELS, LOW
from rrg_estimator.ros.belief_msgs import belief_to_msg
from rrg_msgs.msg import Observation as ObservationMsg

#: A true pose 2.4 cm and 0.05 rad from the mean of the low level's belief: the first goal
#: grasp stops early on the box, so the grasp takes an observation, a retreat and another
#: observation (measured: two goal grasps, the second judged a success).
TRUE_POSE = ("0.64", "0.02", "0.05")
TOPIC_TYPES = {
    "/rrg/belief": "rrg_msgs/msg/BeliefGrid",
    "/rrg/observation": "rrg_msgs/msg/Observation",
    "/rrg/retreated": "rrg_msgs/msg/Retreated",
}


def rewrite_bag(
    src: Path,
    dst: Path,
    edit: Callable[[str, bytes], bytes] = lambda topic, data: data,
    drop: frozenset[str] = frozenset(),
    schema_edit: Callable[[str, bytes], bytes] = lambda name, data: data,
) -> Path:
    """A copy of bag ``src`` as bag folder ``dst``, written with the mcap writer: every channel
    but the ``drop`` topics, each schema through ``schema_edit`` and each message's CDR data
    through ``edit``."""
    dst.mkdir()
    with (src / f"{src.name}_0.mcap").open("rb") as f, (dst / f"{dst.name}_0.mcap").open("wb") as g:
        reader = make_reader(f)
        summary = reader.get_summary()
        writer = Writer(g)
        writer.start(profile="ros2", library="tests/rrg_bags/test_bag_replay.py")
        schemas = {
            sid: writer.register_schema(s.name, s.encoding, schema_edit(s.name, s.data))
            for sid, s in summary.schemas.items()
        }
        channels = {
            cid: writer.register_channel(
                c.topic, c.message_encoding, schemas[c.schema_id], c.metadata
            )
            for cid, c in summary.channels.items()
            if c.topic not in drop
        }
        for _, channel, m in reader.iter_messages(log_time_order=True):
            if channel.id in channels:
                data = edit(channel.topic, m.data)
                writer.add_message(
                    channels[channel.id], m.log_time, data, m.publish_time, m.sequence
                )
        writer.finish()
    return dst


@pytest.fixture(scope="module")
def synthetic_bag(tmp_path_factory) -> Path:
    """A bag of the topics a replay reads, with one reset belief (no graph, no tables)."""
    bag = tmp_path_factory.mktemp("synthetic") / "reset"
    with Rosbag2McapWriter(bag) as writer:
        for topic, msg_type in TOPIC_TYPES.items():
            writer.add_topic(topic, msg_type, [])
        belief = Belief.for_level(LOW, [0.62, 0.0, 0.0])
        writer.write("/rrg/belief", serialize_message(belief_to_msg(belief, Time(sec=100))))
    return bag


@pytest.fixture(scope="module")
def grasp_bag(tmp_path_factory, ros_domain) -> Path:
    """A robust grasp of the box at low uncertainty through the whole graph, recorded."""
    tmp = tmp_path_factory.mktemp("replay")
    args = [sys.executable, "-m", "rrg_bringup.launch", "--grasp", "box"]
    args += ["--level", "low", "--levels", "low", "--true-pose", *TRUE_POSE, "--seed", "0"]
    args += ["--domain-id", str(ros_domain), "--bags", str(tmp), "--bag-name", "grasp"]
    args += ["--log-dir", str(tmp / "logs"), "--json"]
    out = subprocess.run(
        args, env=ros_env(ros_domain), cwd=ROOT, capture_output=True, text=True, timeout=600
    )
    assert out.returncode == 0, out.stdout + out.stderr
    return tmp / "grasp"


def flip_last_observation(bag: Path, dst: Path) -> Path:
    """A copy of ``bag`` whose last observation reports the opposite contact and palm reading."""
    with (bag / f"{bag.name}_0.mcap").open("rb") as f:
        count = sum(c.topic == "/rrg/observation" for _, c, _ in make_reader(f).iter_messages())
    seen = []

    def flip(topic: str, data: bytes) -> bytes:
        if topic != "/rrg/observation":
            return data
        seen.append(topic)
        if len(seen) < count:
            return data
        msg = deserialize_message(data, ObservationMsg)
        msg.contact = not msg.contact
        msg.sensors = [not msg.sensors[0], *msg.sensors[1:]]
        return serialize_message(msg)

    return rewrite_bag(bag, dst, edit=flip)


# --------------------------------------------------------------------------- a real bag
@pytest.mark.slow  # the launcher's node processes
def test_replay_reproduces_every_recorded_belief_and_decision(grasp_bag, capsys):
    """Measured on the box grasp: every belief identical (max |Δp| = 0), and the planner's
    decisions again the recorded ones."""
    r = replay_bag(grasp_bag, planner=True)
    events = [b.event for b in r.beliefs]
    assert events[0] == "reset" and events.count("observation") >= 2 and "retreat" in events
    compared = [b for b in r.beliefs if b.max_abs_diff is not None]
    assert len(compared) == len(r.beliefs) - 1  # every event has its recorded belief
    assert r.max_abs_diff <= 1e-9 and r.first_divergence is None
    assert len(r.decisions) == events.count("observation") >= 2
    assert all(d.same for d in r.decisions), [(d.recorded_wrt, d.wrt) for d in r.decisions]
    assert r.reproduced and not r.what_if
    # the launcher's --levels low when the recorder caught the planner declaring it, else the
    # planner's default (the recorder may subscribe to /parameter_events after that)
    assert r.grasps[0].levels == (("low",) if r.levels_recorded else tuple(LEVELS))
    assert bag_cli(["replay", str(grasp_bag), "--json"]) == 0
    out = capsys.readouterr().out.strip().splitlines()
    data = json.loads(out[-1])
    assert data["reproduced"] and data["max_abs_diff"] <= 1e-9 and data["first_divergence"] is None
    assert any("every belief reproduced" in line for line in out)


@pytest.mark.slow  # the launcher's node processes
def test_an_edited_observation_makes_the_replay_diverge_where_it_was_edited(
    grasp_bag, tmp_path, capsys
):
    """The last observation with its contact and palm flipped: the beliefs before it still
    match, and the first divergence is that observation's belief."""
    edited = flip_last_observation(grasp_bag, tmp_path / "edited")
    r = replay_bag(edited)
    last = max(i for i, b in enumerate(r.beliefs) if b.event == "observation")
    assert r.first_divergence == last
    assert r.beliefs[last].max_abs_diff > 1e-6  # measured: 8.6e-4
    assert all(b.max_abs_diff <= 1e-9 for b in r.beliefs[1:last])
    assert not r.reproduced
    assert bag_cli(["replay", str(edited), "--json"]) == 1
    out = capsys.readouterr().out.strip().splitlines()
    assert json.loads(out[-1])["first_divergence"] == last
    assert any(line.split()[:1] == [str(last)] and "DIVERGES" in line for line in out)


@pytest.mark.slow  # the launcher's node processes
def test_other_planner_settings_report_decisions_not_failures(grasp_bag, capsys):
    """δ = 0.01 and H = 1 on the recorded beliefs: the decisions are made with those settings,
    and those that differ are reported with exit status 0 (measured: the second decision
    sweeps where the recorded one, at δ = 0.1, grasped)."""
    assert bag_cli(["replay", str(grasp_bag), "--delta", "0.01", "--horizon", "1", "--json"]) == 0
    data = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert data["planner"] and data["what_if"] and data["reproduced"]
    assert data["grasps"][0]["horizon"] == 1 and data["grasps"][0]["delta"] == 0.01
    assert len(data["decisions"]) >= 2 and data["decisions_differing"] >= 1
    assert data["decisions_differing"] == sum(not d["same"] for d in data["decisions"])


def test_differing_decisions_fail_a_replay_only_with_the_recorded_settings():
    d = DecisionStep(0, 1, "goal", [0.62, 0.0, 0.0], 0.8, wrt="sweep", estimate=[0.62, 0.0, 0.0])
    r = BagReplay("bag", 1e-9, True, False, [BeliefStep("reset", "", 0)], planner=True)
    r.decisions.append(d)
    assert not r.reproduced and r.decisions_differing == 1
    r.what_if = True
    assert r.reproduced


# --------------------------------------------------------------------------- bags it cannot replay
def test_a_bag_without_the_retreats_is_refused(synthetic_bag, tmp_path, capsys):
    bag = rewrite_bag(synthetic_bag, tmp_path / "partial", drop=frozenset({"/rrg/retreated"}))
    with pytest.raises(UnusableBag, match="no /rrg/retreated"):
        replay_bag(bag)
    assert bag_cli(["replay", str(bag)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no /rrg/retreated" in err and "Traceback" not in err


def test_the_planner_needs_the_grasp_records(synthetic_bag, capsys):
    assert bag_cli(["replay", str(synthetic_bag), "--planner"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no /rrg/grasp_step" in err


@pytest.mark.parametrize("content", [b"", b"hello, not a bag\n", b"\x89MCAP0\r\n"])
def test_a_file_that_is_not_a_bag_is_refused(tmp_path, capsys, content):
    path = tmp_path / "not_a_bag.mcap"
    path.write_bytes(content)
    assert bag_cli(["replay", str(path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "not an MCAP bag" in err


def test_a_missing_bag_and_an_empty_folder_are_refused(tmp_path, capsys):
    assert bag_cli(["replay", str(tmp_path / "nowhere")]) == 2
    assert bag_cli(["replay", str(tmp_path)]) == 2
    err = capsys.readouterr().err.splitlines()
    assert err[0].endswith("no bag at " + str(tmp_path / "nowhere")) and "no .mcap" in err[1]


def test_a_bag_of_another_interface_version_is_refused(synthetic_bag, tmp_path, capsys):
    """An Observation with one more field, as another version of rrg_msgs would record it."""

    def older(name: str, data: bytes) -> bytes:
        if name != "rrg_msgs/msg/Observation":
            return data
        return data.replace(b"bool contact", b"bool contact\nfloat64 stop_force", 1)

    bag = rewrite_bag(synthetic_bag, tmp_path / "other", schema_edit=older)
    assert bag_cli(["replay", str(bag)]) == 2
    err = capsys.readouterr().err
    assert "another version of the interfaces" in err and "Observation" in err
    assert err.count("\n") == 1


def test_bad_planner_settings_are_usage_errors(synthetic_bag, capsys):
    for args in (["--horizon", "4"], ["--delta", "1.5"], ["--levels", "coarse"]):
        assert bag_cli(["replay", str(synthetic_bag), *args]) == 2
    assert len(capsys.readouterr().err.splitlines()) == 3


def test_a_reset_alone_replays_with_nothing_to_compare(synthetic_bag):
    r = replay_bag(synthetic_bag)
    assert [b.event for b in r.beliefs] == ["reset"] and r.max_abs_diff is None
    assert r.reproduced and r.beliefs[0].note == "no event follows"


# --------------------------------------------------------------------------- message layouts
def test_layout_ignores_comments_and_constants_but_not_fields():
    text = full_definition("rrg_msgs/msg/GraspStep")
    assert same_layout("rrg_msgs/msg/GraspStep", text)
    for old in ("uint8 event", "uint8 EVENT_DONE=2", "uint32 step"):
        assert old in text
    commented = text.replace("uint8 event", "uint8 event   # changed comment").replace(
        "uint8 EVENT_DONE=2", "uint8 EVENT_DONE=2\nuint8 EVENT_OTHER = 7"
    )
    assert layout(commented) == layout(text)
    assert not same_layout("rrg_msgs/msg/GraspStep", text.replace("uint32 step", "uint16 step"))
    without_reason = re.sub(r"^string reason\b.*\n", "", text, flags=re.M)
    assert without_reason != text
    assert not same_layout("rrg_msgs/msg/GraspStep", without_reason)
    assert not same_layout("rrg_msgs/msg/NoSuchType", text)
    assert "MSG: rrg_msgs/PlanarPose" in layout(text) and "float64 theta" in layout(text)
