"""Bags of several files: a recorder restarted after it was killed (operations §8) writes the next
split ``<name>_<k>.mcap`` into the same folder, metadata.yaml names every split as rosbag2 does,
and the bag tools read them all. ROS-free: synthetic messages, a truncated file for the kill."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml
from rclpy.serialization import serialize_message
from std_msgs.msg import String

from rrg_bags.bag_info import bag_files, bag_info, format_info
from rrg_bags.bag_read import read_messages
from rrg_bags.bag_writer import Rosbag2McapWriter

QOS = {
    "history": "keep_last",
    "depth": 10,
    "reliability": "reliable",
    "durability": "volatile",
    "deadline": {"sec": 0, "nsec": 0},
    "lifespan": {"sec": 0, "nsec": 0},
    "liveliness": "automatic",
    "liveliness_lease_duration": {"sec": 0, "nsec": 0},
    "avoid_ros_namespace_conventions": False,
}
LATCHED = {**QOS, "depth": 1, "durability": "transient_local"}
S = 1_000_000_000  # ns


def text(data: str) -> bytes:
    return serialize_message(String(data=data))


@pytest.fixture
def killed_bag(tmp_path) -> Path:
    """A bag whose recorder was killed: 300 messages of 10 kB on /a (several 1 MiB chunks), and
    on the latched /l one message early and one in the last chunk, which the kill loses. The
    file is cut where a SIGKILL leaves it (no summary, no footer) and has no metadata.yaml."""
    bag = tmp_path / "run"
    with Rosbag2McapWriter(bag) as writer:
        writer.add_topic("/a", "std_msgs/msg/String", [QOS])
        writer.add_topic("/l", "std_msgs/msg/String", [LATCHED])
        writer.write("/l", text("early"), log_time_ns=1 * S, publish_time_ns=1 * S)
        for i in range(300):
            writer.write("/a", text(f"{i:05d}" + "x" * 10_000), log_time_ns=(2 + i) * S)
        writer.write("/l", text("late"), log_time_ns=302 * S, publish_time_ns=302 * S)
    split = bag / "run_0.mcap"
    with split.open("r+b") as f:
        f.truncate(split.stat().st_size // 2 + 7)
    (bag / "metadata.yaml").unlink()
    return bag


def restart(bag: Path) -> Rosbag2McapWriter:
    """What the restarted recorder writes: the latched history again (both messages), then new
    messages on /a."""
    writer = Rosbag2McapWriter(bag, append=True)
    writer.add_topic("/l", "std_msgs/msg/String", [LATCHED])
    writer.add_topic("/a", "std_msgs/msg/String", [QOS])
    assert not writer.write("/l", text("early"), log_time_ns=400 * S, publish_time_ns=1 * S)
    assert writer.write("/l", text("late"), log_time_ns=400 * S, publish_time_ns=302 * S)
    for i in range(3):
        writer.write("/a", text(f"after {i}"), log_time_ns=(401 + i) * S)
    writer.close()
    return writer


def test_a_restarted_recorder_writes_the_next_split_and_metadata_names_both(killed_bag):
    with pytest.raises(FileExistsError):
        Rosbag2McapWriter(killed_bag)  # only a restart appends
    writer = restart(killed_bag)
    assert writer.mcap_path.name == "run_1.mcap" and writer.repeats_skipped == 1
    # the killed split was closed after its last complete chunk before the new one began
    assert writer.closed_earlier == {"run_0.mcap": "summary"}
    first, second = (bag_info(p) for p in bag_files(killed_bag))
    assert first.finalized and second.finalized
    assert 0 < first.message_count < 302  # the complete chunks of the killed file
    meta = yaml.safe_load((killed_bag / "metadata.yaml").read_text())
    info = meta["rosbag2_bagfile_information"]
    assert info["relative_file_paths"] == ["run_0.mcap", "run_1.mcap"]
    assert [(f["path"], f["message_count"]) for f in info["files"]] == [
        ("run_0.mcap", first.message_count),
        ("run_1.mcap", 4),
    ]
    assert info["files"][0]["starting_time"]["nanoseconds_since_epoch"] == 1 * S
    assert info["files"][1]["duration"]["nanoseconds"] == 3 * S
    assert info["message_count"] == first.message_count + 4
    assert info["starting_time"]["nanoseconds_since_epoch"] == 1 * S
    assert info["duration"]["nanoseconds"] == 402 * S
    topics = {t["topic_metadata"]["name"]: t for t in info["topics_with_message_count"]}
    assert topics["/a"]["message_count"] == first.message_count - 1 + 3
    assert topics["/l"]["message_count"] == 2  # each latched message once
    assert topics["/l"]["topic_metadata"]["offered_qos_profiles"] == [LATCHED]


def test_the_bag_tools_read_every_split(killed_bag):
    restart(killed_bag)
    info = bag_info(killed_bag)
    assert [p.name for p in info.files] == ["run_0.mcap", "run_1.mcap"]
    assert info.unfinalized == []
    assert {t.name: t.count for t in info.topics}["/l"] == 2
    assert (info.start_ns, info.end_ns) == (1 * S, 403 * S)
    printed = format_info(info)
    assert "run_0.mcap" in printed and "run_1.mcap" in printed
    messages = list(read_messages(killed_bag))
    assert len(messages) == info.message_count
    assert [m.log_time_ns for m in messages] == sorted(m.log_time_ns for m in messages)
    assert [m.msg.data for m in messages if m.topic == "/l"] == ["early", "late"]
    assert [m.msg.data for m in messages[-3:]] == ["after 0", "after 1", "after 2"]
    from rosbags.highlevel import AnyReader

    with AnyReader([killed_bag]) as reader:  # needs every file finalized
        assert sum(1 for _ in reader.messages()) == info.message_count


def test_a_recorder_killed_before_its_first_record_leaves_a_split_that_is_skipped(tmp_path):
    bag = tmp_path / "empty"
    bag.mkdir()
    (bag / "empty_0.mcap").write_bytes(b"")
    with Rosbag2McapWriter(bag, append=True) as writer:
        writer.add_topic("/a", "std_msgs/msg/String", [QOS])
        writer.write("/a", text("first"), log_time_ns=S)
    assert writer.mcap_path.name == "empty_1.mcap"
    info = bag_info(bag)
    assert info.message_count == 1 and [p.name for p in info.unfinalized] == ["empty_0.mcap"]
    assert [m.msg.data for m in read_messages(bag)] == ["first"]


def test_splits_are_in_numeric_order(tmp_path):
    bag = tmp_path / "many"
    bag.mkdir()
    for k in (0, 1, 2, 10, 9):
        (bag / f"many_{k}.mcap").touch()  # only the names matter here
    (bag / "other_3.mcap").touch()
    assert [p.name for p in bag_files(bag)] == [f"many_{k}.mcap" for k in (0, 1, 2, 9, 10)]
