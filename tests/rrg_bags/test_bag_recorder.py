"""The MCAP bag recorder, end to end: a recorder process records a live graph, is stopped with
SIGINT (or SIGTERM), and leaves a rosbag2-layout bag that rosbags and Foxglove's readers decode.
Also the ROS-free parts: schema text, the bag writer, and ``rrg-bag info`` on a truncated bag."""

from __future__ import annotations

import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import ros_testing
import yaml
from geometry_msgs.msg import WrenchStamped
from mcap.reader import make_reader
from rclpy.duration import Duration
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import DurabilityPolicy, QoSProfile
from rclpy.serialization import serialize_message
from ros_testing import RosClient
from rosbags.highlevel import AnyReader
from sensor_msgs.msg import JointState
from std_msgs.msg import String

from rrg_bags.bag_cli import bag_info, format_info
from rrg_bags.bag_cli import main as bag_cli_main
from rrg_bags.bag_schema import SEPARATOR, full_definition
from rrg_bags.bag_writer import Rosbag2McapWriter
from rrg_bags.recorder_node import BagRecorder
from rrg_msgs.msg import BeliefGrid, Observation

RECORDER = "rrg_bag_recorder"

# topic: (type, number of messages published while recording)
VOLATILE_COUNTS = {
    "/chatter": 5,
    "/rrg/joint_states": 10,
    "/rrg/observation": 3,
    "/rrg/tip_wrench": 4,
}
LATCHED_TOPIC = "/rrg/belief"  # TRANSIENT_LOCAL, published once before the recorder starts


@pytest.fixture(scope="module")
def ros_env(ros_domain):
    """The recorder's environment: this file's DDS traffic on loopback, in a domain of its own."""
    return ros_testing.ros_env(ros_domain)


@pytest.fixture(scope="module")
def ros_node(ros_env):
    client = RosClient(ros_env, "bag_test_publisher")
    yield client.node, client.executor
    client.close()


def spin_until(executor, condition, timeout_s: float) -> bool:
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            return False
        executor.spin_once(timeout_sec=0.05)
    return True


def start_recorder(bag: Path, env: dict) -> subprocess.Popen:
    return subprocess.Popen(
        [
            sys.executable,
            "-m",
            "rrg_bags.recorder_node",
            "--output",
            str(bag),
            "--ros-args",
            "-p",
            "discovery_period:=0.1",
        ],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )


def stop(proc: subprocess.Popen, sig: int) -> str:
    proc.send_signal(sig)
    out, _ = proc.communicate(timeout=20)
    assert proc.returncode == 0, out
    return out


def belief_message() -> BeliefGrid:
    rng = np.random.default_rng(7)
    msg = BeliefGrid()
    msg.header.frame_id = "world"
    m = msg.metadata
    m.size_x, m.size_y, m.size_theta = 5, 5, 3
    m.resolution_x, m.resolution_y, m.resolution_theta = 0.01, 0.01, 0.1
    m.origin.x = 0.62
    w = rng.random(75)
    msg.weights = (w / w.sum()).tolist()
    msg.covariance = np.diag([1e-4, 1e-4, 0.01]).ravel()
    return msg


def observation_message(i: int) -> Observation:
    obs = Observation(
        object_name="box", wrt_name=f"info_{i}", contact=bool(i % 2), progress=0.1 * i
    )
    obs.header.frame_id = "world"
    obs.sensors = [j == i for j in range(Observation.NUM_SENSORS)]
    obs.closure = np.array([0.5, 0.6, 0.7]) + i
    obs.tip_valid = [True, False, True]
    obs.tip_points[0].x = 0.01 * i
    return obs


@pytest.fixture(scope="module")
def recorded_bag(ros_node, ros_env, tmp_path_factory):
    """Record the test node's topics, stop the recorder with SIGINT; returns the bag folder."""
    node, executor = ros_node
    bag = tmp_path_factory.mktemp("bags") / "recorder_test"
    latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
    belief_pub = node.create_publisher(BeliefGrid, LATCHED_TOPIC, latched)
    belief_pub.publish(belief_message())
    pubs = {
        "/chatter": node.create_publisher(String, "/chatter", 10),
        "/rrg/joint_states": node.create_publisher(JointState, "/rrg/joint_states", 10),
        "/rrg/observation": node.create_publisher(Observation, "/rrg/observation", 10),
        "/rrg/tip_wrench": node.create_publisher(WrenchStamped, "/rrg/tip_wrench", 10),
    }
    proc = start_recorder(bag, ros_env)
    try:
        matched = spin_until(
            executor,
            lambda: (
                all(p.get_subscription_count() > 0 for p in pubs.values())
                and belief_pub.get_subscription_count() > 0
            ),
            timeout_s=20,
        )
        assert matched, "the recorder did not subscribe to every topic"
        for i in range(VOLATILE_COUNTS["/chatter"]):
            pubs["/chatter"].publish(String(data=f"hello {i}"))
        for i in range(VOLATILE_COUNTS["/rrg/joint_states"]):
            js = JointState(name=[f"wam_j{j + 1}" for j in range(7)], position=[0.1 * i] * 7)
            js.header.stamp.sec = i
            pubs["/rrg/joint_states"].publish(js)
        for i in range(VOLATILE_COUNTS["/rrg/observation"]):
            pubs["/rrg/observation"].publish(observation_message(i))
        for i in range(VOLATILE_COUNTS["/rrg/tip_wrench"]):
            ws = WrenchStamped()
            ws.header.frame_id = f"tip{i % 3 + 1}"
            ws.wrench.force.z = 0.5 * i
            pubs["/rrg/tip_wrench"].publish(ws)
        # every message is in the recorder's queues once acknowledged (the latched one too);
        # the recorder writes what it has received before it closes the bag
        for p in [belief_pub, *pubs.values()]:
            assert p.wait_for_all_acked(Duration(seconds=10))
    except BaseException:
        proc.kill()
        raise
    log = stop(proc, signal.SIGINT)
    assert "stopping: wrote" in log and "bag closed" in log
    for p in [belief_pub, *pubs.values()]:
        node.destroy_publisher(p)
    return bag


@pytest.mark.slow  # a recorder process
def test_bag_has_rosbag2_layout_and_metadata(recorded_bag):
    assert sorted(p.name for p in recorded_bag.iterdir()) == [
        "metadata.yaml",
        "recorder_test_0.mcap",
    ]
    info = yaml.safe_load((recorded_bag / "metadata.yaml").read_text())[
        "rosbag2_bagfile_information"
    ]
    assert info["version"] == 9 and info["storage_identifier"] == "mcap"
    assert info["relative_file_paths"] == ["recorder_test_0.mcap"]
    topics = {t["topic_metadata"]["name"]: t for t in info["topics_with_message_count"]}
    for name, n in VOLATILE_COUNTS.items():
        assert topics[name]["message_count"] == n
    assert topics[LATCHED_TOPIC]["message_count"] == 1
    assert topics[LATCHED_TOPIC]["topic_metadata"]["type"] == "rrg_msgs/msg/BeliefGrid"
    assert (
        topics[LATCHED_TOPIC]["topic_metadata"]["offered_qos_profiles"][0]["durability"]
        == "transient_local"
    )
    assert topics["/chatter"]["topic_metadata"]["type_description_hash"].startswith("RIHS01_")
    assert info["message_count"] == sum(t["message_count"] for t in topics.values())
    assert info["duration"]["nanoseconds"] > 0


@pytest.mark.slow  # a recorder process
def test_mcap_is_finalized_with_ros2_schemas_and_qos(recorded_bag):
    with (recorded_bag / "recorder_test_0.mcap").open("rb") as f:
        reader = make_reader(f)
        assert reader.get_header().profile == "ros2"
        summary = reader.get_summary()  # needs the footer
        assert summary is not None and summary.statistics is not None
        channels = {c.topic: c for c in summary.channels.values()}
        counts = summary.statistics.channel_message_counts
        for name, n in VOLATILE_COUNTS.items():
            assert counts[channels[name].id] == n
        schema = summary.schemas[channels["/rrg/observation"].schema_id]
        assert (schema.name, schema.encoding) == ("rrg_msgs/msg/Observation", "ros2msg")
        assert f"{SEPARATOR}\nMSG: std_msgs/Header\n" in schema.data.decode()
        belief = channels[LATCHED_TOPIC]
        assert belief.message_encoding == "cdr"
        qos = yaml.safe_load(belief.metadata["offered_qos_profiles"])
        assert qos[0]["durability"] == "transient_local" and qos[0]["reliability"] == "reliable"
        assert "rosbag2" in {m.name for m in reader.iter_metadata()}


@pytest.mark.slow  # a recorder process
def test_rosbags_decodes_every_message(recorded_bag):
    decoded: dict[str, list] = {}
    with AnyReader(
        [recorded_bag]
    ) as reader:  # types come from the bag's own schemas (hash-checked)
        for conn, _, raw in reader.messages():
            decoded.setdefault(conn.topic, []).append(reader.deserialize(raw, conn.msgtype))
    assert {t: len(decoded[t]) for t in VOLATILE_COUNTS} == VOLATILE_COUNTS
    assert [m.data for m in decoded["/chatter"]] == [f"hello {i}" for i in range(5)]
    obs = decoded["/rrg/observation"][2]
    assert (obs.wrt_name, obs.contact, obs.sensors.tolist()) == (
        "info_2",
        False,
        [j == 2 for j in range(10)],
    )
    np.testing.assert_allclose(obs.closure, [2.5, 2.6, 2.7])
    belief = decoded[LATCHED_TOPIC][0]
    np.testing.assert_array_equal(belief.weights, belief_message().weights)
    assert belief.metadata.size_theta == 3 and belief.header.frame_id == "world"
    assert [m.header.stamp.sec for m in decoded["/rrg/joint_states"]] == list(range(10))


@pytest.mark.slow  # a recorder process
def test_foxglove_readers_decode_every_message(recorded_bag):
    result = ros_testing.foxglove_read(recorded_bag / "recorder_test_0.mcap")
    assert result["profile"] == "ros2"
    for name, n in VOLATILE_COUNTS.items():
        assert result["topics"][name]["count"] == n
    assert all(t["trailing_bytes"] == 0 for t in result["topics"].values())
    assert result["topics"][LATCHED_TOPIC]["schema"] == "rrg_msgs/msg/BeliefGrid"
    assert result["last"]["/rrg/observation"]["wrt_name"] == "info_2"
    assert result["last"]["/rrg/tip_wrench"]["wrench"]["force"]["z"] == 1.5
    assert len(result["last"][LATCHED_TOPIC]["weights"]) == 75


@pytest.mark.slow  # a recorder process
def test_bag_info_cli_prints_topics_counts_and_duration(recorded_bag, capsys):
    info = bag_info(recorded_bag)
    assert info.finalized and info.profile == "ros2" and info.duration_s > 0
    counts = {t.name: t.count for t in info.topics}
    assert {t: counts[t] for t in VOLATILE_COUNTS} == VOLATILE_COUNTS
    assert bag_cli_main(["info", str(recorded_bag)]) == 0
    text = capsys.readouterr().out
    assert "rrg_msgs/msg/Observation" in text and "Duration:" in text
    assert format_info(info) in text


@pytest.mark.slow  # a recorder process
def test_sigterm_also_finalizes_the_bag(ros_node, ros_env, tmp_path):
    node, executor = ros_node
    pub = node.create_publisher(String, "/sigterm_test", 10)
    bag = tmp_path / "sigterm"
    proc = start_recorder(bag, ros_env)
    try:
        assert spin_until(executor, lambda: pub.get_subscription_count() > 0, timeout_s=20)
        pub.publish(String(data="last words"))
        assert pub.wait_for_all_acked(Duration(seconds=10))  # in the recorder's queue
    except BaseException:
        proc.kill()
        raise
    stop(proc, signal.SIGTERM)
    node.destroy_publisher(pub)
    info = bag_info(bag)
    assert info.finalized
    assert {t.name: t.count for t in info.topics}["/sigterm_test"] == 1
    assert (bag / "metadata.yaml").is_file()


def test_a_stopping_recorder_writes_the_messages_it_has_received(ros_node, tmp_path):
    """What SIGINT or SIGTERM runs before the bag is closed: the messages already received (the
    recorder has not spun since they came) are written, and then it stops without waiting."""
    node, executor = ros_node
    writer = Rosbag2McapWriter(tmp_path / "drain")
    pub = node.create_publisher(String, "/drain_test", 10)
    recorder = BagRecorder(writer, context=node.context)
    recorder_executor = SingleThreadedExecutor(context=node.context)
    recorder_executor.add_node(recorder)
    try:
        assert spin_until(recorder_executor, lambda: "/drain_test" in writer.topics, 20)
        assert spin_until(executor, lambda: pub.get_subscription_count() > 0, timeout_s=20)
        for i in range(7):
            pub.publish(String(data=f"queued {i}"))
        assert pub.wait_for_all_acked(Duration(seconds=10))  # all in the recorder's queue
        topic = writer.topics["/drain_test"]
        assert topic.message_count == 0  # nothing taken yet
        assert recorder.drain(recorder_executor, budget_s=10.0) >= 7  # (and the test's /rosout)
        assert topic.message_count == 7
    finally:
        recorder_executor.shutdown()
        recorder.destroy_node()
        node.destroy_publisher(pub)
        writer.close()
    with AnyReader([tmp_path / "drain"]) as reader:
        ours = [c for c in reader.connections if c.topic == "/drain_test"]
        got = [reader.deserialize(raw, c.msgtype).data for c, _, raw in reader.messages(ours)]
    assert got == [f"queued {i}" for i in range(7)]


def test_recorder_refuses_an_existing_bag_folder(tmp_path, ros_env):
    out = subprocess.run(
        [sys.executable, "-m", "rrg_bags.recorder_node", "--output", str(tmp_path)],
        env=ros_env,
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert out.returncode == 1 and "already exists" in out.stderr


# ------------------------------------------------------------------ ROS-free parts
def test_schema_lists_each_nested_type_once_depth_first():
    text = full_definition("rrg_msgs/msg/Observation")
    headers = [line for line in text.splitlines() if line.startswith("MSG: ")]
    assert headers == [
        "MSG: std_msgs/Header",
        "MSG: builtin_interfaces/Time",
        "MSG: rrg_msgs/PlanarPose",
        "MSG: geometry_msgs/Pose",
        "MSG: geometry_msgs/Point",
        "MSG: geometry_msgs/Quaternion",
        "MSG: geometry_msgs/Vector3",
    ]
    assert text.count(SEPARATOR) == len(headers)
    assert text.startswith("# The observation o of one world-relative trajectory")


def test_writer_output_reads_back_without_a_ros_graph(tmp_path):
    bag = tmp_path / "offline"
    with Rosbag2McapWriter(bag) as writer:
        writer.add_topic("/a", "std_msgs/msg/String", [])
        for i in range(3):
            writer.write("/a", serialize_message(String(data=str(i))), log_time_ns=1_000 + i)
    with pytest.raises(FileExistsError):
        Rosbag2McapWriter(bag)
    with AnyReader([bag]) as reader:
        got = [(ts, reader.deserialize(raw, c.msgtype).data) for c, ts, raw in reader.messages()]
    assert got == [(1_000, "0"), (1_001, "1"), (1_002, "2")]


def test_info_reads_a_bag_whose_recorder_was_killed(tmp_path):
    bag = tmp_path / "killed"
    writer = Rosbag2McapWriter(bag)
    writer.add_topic("/a", "std_msgs/msg/String", [])
    for i in range(300):  # 3 MB: several 1 MiB chunks
        writer.write("/a", serialize_message(String(data="x" * 10_000)), log_time_ns=10**9 * i)
    writer.close()
    mcap = bag / "killed_0.mcap"
    truncated = tmp_path / "truncated.mcap"
    shutil.copy(mcap, truncated)
    with truncated.open("r+b") as f:  # cut off the summary and footer, as a SIGKILL would
        f.truncate(mcap.stat().st_size // 2 + 7)
    info = bag_info(truncated)
    assert not info.finalized
    assert info.topics[0].name == "/a" and info.topics[0].type == "std_msgs/msg/String"
    assert 0 < info.message_count < 300  # the complete chunks
    assert "no summary" in format_info(info)
