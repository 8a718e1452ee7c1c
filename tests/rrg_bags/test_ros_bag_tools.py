"""``rrg-bag summary`` and ``rrg-bag plot`` on a bag written like the launcher's (synthetic
messages of a two-step grasp), and reading a bag whose recorder died before finalizing it."""

from __future__ import annotations

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from geometry_msgs.msg import PoseStamped
from rclpy.serialization import serialize_message

from rrg_bags.bag_cli import main as bag_cli
from rrg_bags.bag_plot import belief_frames, plot_bag
from rrg_bags.bag_read import read_messages
from rrg_bags.bag_summary import format_summary, summarize
from rrg_bags.bag_writer import Rosbag2McapWriter
from rrg_common.ros.msg_conversions import observation_to_msg
from rrg_estimator.belief import Belief
from rrg_estimator.config import HIGH, LOW
from rrg_estimator.grid import Grid
from rrg_estimator.ros.belief_msgs import belief_to_msg
from rrg_models.observation import Observation
from rrg_models.poses import make_pose
from rrg_msgs.action import RobustGrasp
from rrg_msgs.msg import GraspOutcome
from rrg_planner.closed_loop import Decision
from rrg_planner.ros.grasp_records import decision_record, done_record

TRUE_POSE = np.array([0.64, -0.02, 0.25])
TOPICS = {
    "/rrg/belief": "rrg_msgs/msg/BeliefGrid",
    "/rrg/observation": "rrg_msgs/msg/Observation",
    "/rrg/grasp_step": "rrg_msgs/msg/GraspStep",
    "/rrg/eval/object_pose": "geometry_msgs/msg/PoseStamped",
    "/rrg/eval/grasp_outcome": "rrg_msgs/msg/GraspOutcome",
}
GOAL = RobustGrasp.Goal(object_name="box", strategy="rrg-info", horizon=2, delta=0.1)


def step_record(step: int, wrt: str, kind: str, p_goal: float):
    decision = Decision(
        step,
        0,
        wrt,
        kind,
        np.array([0.62, 0.0, 0.0]),
        False,
        p_goal + 0.1,
        p_goal,
        0.05,
        action_values={wrt: p_goal + 0.1, "sweep": float("nan")},
    )
    return decision_record(GOAL, decision, Time(sec=100 + step))


def observation(wrt: str, stamp: Time, contact: bool) -> Observation:
    obs = Observation(
        contact=contact,
        progress=0.1,
        hand_pose=make_pose([0.6, 0.0, 0.2]),
        sensors=np.arange(10) == (7 if contact else 0),
        closure=[0.5, 0.5, 0.5],
    )
    return observation_to_msg(obs, "box", wrt, [0.62, 0.0, 0.0], stamp)


@pytest.fixture(scope="module")
def grasp_bag(tmp_path_factory):
    """A bag of a grasp: reset belief, info1 (contact), refined belief, goal, the judgement."""
    bag = tmp_path_factory.mktemp("bags") / "grasp"
    true = PoseStamped()
    true.pose.position.x, true.pose.position.y = TRUE_POSE[:2]
    true.pose.orientation.z, true.pose.orientation.w = (
        np.sin(TRUE_POSE[2] / 2),
        np.cos(TRUE_POSE[2] / 2),
    )
    b0 = Belief.for_level(HIGH, [0.62, 0.0, 0.0])
    b1 = Belief.gaussian(Grid.for_level(LOW, center=TRUE_POSE), TRUE_POSE, LOW.sigma)
    b2 = Belief.gaussian(
        Grid.for_level(LOW, center=TRUE_POSE), TRUE_POSE, np.asarray(LOW.sigma) / 2
    )
    t1, t2 = Time(sec=101), Time(sec=102)
    msgs = [
        ("/rrg/eval/object_pose", true),
        ("/rrg/belief", belief_to_msg(b0, Time(sec=100))),
        ("/rrg/grasp_step", step_record(1, "info1", "info", 0.31)),
        ("/rrg/observation", observation("info1", t1, True)),
        ("/rrg/belief", belief_to_msg(b1, t1)),
        ("/rrg/grasp_step", step_record(2, "goal", "goal", 0.95)),
        ("/rrg/observation", observation("goal", t2, False)),
        ("/rrg/belief", belief_to_msg(b2, t2)),
        (
            "/rrg/grasp_step",
            done_record(
                GOAL,
                RobustGrasp.Result(
                    success=True, actions_taken=["info1", "goal"], final_p_goal=0.97
                ),
                Time(sec=103),
            ),
        ),
        (
            "/rrg/eval/grasp_outcome",
            GraspOutcome(
                object_name="box",
                wrt_name="goal",
                success=True,
                in_region=True,
                held=True,
                message="SUCCESS: held, in the goal region",
            ),
        ),
    ]
    with Rosbag2McapWriter(bag) as writer:
        for topic, msg_type in TOPICS.items():
            writer.add_topic(topic, msg_type, [])
        for i, (topic, msg) in enumerate(msgs):
            writer.write(topic, serialize_message(msg), log_time_ns=1_000_000_000 * (100 + i))
    return bag


def test_summary_lists_steps_observations_and_outcome(grasp_bag, capsys):
    s = summarize(grasp_bag)
    assert (s.object_name, s.strategy, s.beliefs) == ("box", "rrg-info", 3)
    assert [(st.wrt, st.kind, st.p_goal, st.contact) for st in s.steps] == [
        ("info1", "info", 0.31, True),
        ("goal", "goal", 0.95, False),
    ]
    assert s.steps[0].sensors == ["tip1"] and s.steps[1].sensors == ["palm"]
    assert s.planner_outcome["success"] is True and s.judged_outcome["success"] is True
    assert s.planner_outcome["actions"] == ["info1", "goal"] and s.planner_outcome["p_goal"] == 0.97
    text = format_summary(s)
    assert "step 2: goal" in text and "P(goal) = 0.950" in text and "SUCCESS" in text
    assert bag_cli(["summary", str(grasp_bag)]) == 0
    assert "step 1: info1" in capsys.readouterr().out


def test_plot_writes_a_png_per_belief_and_an_overview(grasp_bag, tmp_path):
    frames = belief_frames(grasp_bag)
    assert [f.label for f in frames] == ["reset", "after info1", "after goal"]
    np.testing.assert_allclose(frames[1].true_pose, TRUE_POSE)
    paths = plot_bag(grasp_bag, tmp_path / "plots")
    assert [p.name for p in paths] == [
        "belief_00_reset.png",
        "belief_01_after_info1.png",
        "belief_02_after_goal.png",
        "overview.png",
    ]
    assert all(
        p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and p.stat().st_size > 5000 for p in paths
    )
    assert bag_cli(["plot", str(grasp_bag)]) == 0
    assert len(list(grasp_bag.with_name("grasp_plots").glob("*.png"))) == 4


def test_an_unfinalized_bag_is_read_up_to_where_it_ends(tmp_path):
    """A recorder killed mid-way leaves complete 1 MiB chunks and no summary: those are read."""
    bag = tmp_path / "long"
    b = Belief.for_level(HIGH, [0.62, 0.0, 0.0])
    with Rosbag2McapWriter(bag) as writer:
        writer.add_topic("/rrg/belief", TOPICS["/rrg/belief"], [])
        for i in range(12):  # 12 × 192 kB: several chunks
            writer.write(
                "/rrg/belief",
                serialize_message(belief_to_msg(b, Time(sec=i))),
                log_time_ns=10**9 * (1 + i),
            )
    cut = tmp_path / "cut"
    cut.mkdir()
    data = (bag / "long_0.mcap").read_bytes()
    (cut / "cut_0.mcap").write_bytes(data[: int(len(data) * 0.8)])
    full = list(read_messages(bag))
    partial = list(read_messages(cut))
    assert len(full) == 12 and 0 < len(partial) < 12
    assert [m.msg.header.stamp.sec for m in partial] == list(range(len(partial)))
