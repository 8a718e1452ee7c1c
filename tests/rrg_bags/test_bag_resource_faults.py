"""Resource faults while recording (operations §8): a bags folder that cannot be written stops
``rrg-launch`` before any node starts, a recorder that cannot create its bag exits with one line,
and a write that fails (a full disk, a file size limit) stops the recording while the recorder
keeps running: the bag up to the last complete chunk stays readable by ``rrg-bag``, rosbags and
Foxglove's reader, which agree on its messages, and nothing after the failure is claimed.

Real OS limits: RLIMIT_FSIZE on the recorder process and on the launcher (writes beyond it fail
with EFBIG, as Python ignores SIGXFSZ), and paths under a regular file (ENOTDIR, for root too).
The writer's unit tests use a file on a simulated small disk (ENOSPC past its capacity, after
writing what fits, as a full file system does).
"""

from __future__ import annotations

import errno
import io
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

import pytest
import ros_testing
import yaml
from mcap.reader import make_reader
from rclpy.duration import Duration
from rclpy.serialization import serialize_message
from ros_testing import RosClient, foxglove_read, start_node, stop_process
from rosbags.highlevel import AnyReader
from std_msgs.msg import String

from rrg_bags.bag_finalize import CUT, FOOTER, SUMMARY, finalize_in_place
from rrg_bags.bag_info import bag_info, iso_time
from rrg_bags.bag_read import read_messages
from rrg_bags.bag_writer import RecordingStopped, Rosbag2McapWriter
from rrg_bringup import launch

ROOT = Path(__file__).resolve().parents[2]
S = 1_000_000_000  # ns
TOPIC = "/fill"


class SmallDisk(io.FileIO):
    """A file on a disk with room for ``capacity`` bytes of it: a write past that writes what
    fits, then fails with ENOSPC; cutting the file frees the space again."""

    capacity = 2**40

    def write(self, data) -> int:
        room = self.capacity - self.tell()
        if room >= len(data):
            return super().write(data)
        if room > 0:
            super().write(memoryview(data)[:room])
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


def message(i: int, size: int = 2000) -> bytes:
    return serialize_message(String(data=f"{i:04d}" + "x" * size))


def small_disk_writer(bag: Path) -> tuple[Rosbag2McapWriter, list[SmallDisk]]:
    files: list[SmallDisk] = []

    def open_file(path: Path) -> SmallDisk:
        files.append(SmallDisk(path, "w"))
        return files[-1]

    writer = Rosbag2McapWriter(bag, open_file=open_file)
    writer.add_topic(TOPIC, "std_msgs/msg/String", [])
    return writer, files


def rosbags_counts(bag: Path) -> dict[str, int]:
    with AnyReader([bag]) as reader:
        counts: dict[str, int] = {}
        for connection, _, _ in reader.messages():
            counts[connection.topic] = counts.get(connection.topic, 0) + 1
    return counts


def metadata_counts(bag: Path) -> dict[str, int]:
    info = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    return {
        t["topic_metadata"]["name"]: t["message_count"] for t in info["topics_with_message_count"]
    }


# ------------------------------------------------------------------ the writer on a full disk
@pytest.mark.parametrize(
    ("room", "closed"),
    [(60_000, SUMMARY), (300, FOOTER), (20, CUT)],
    ids=["summary-fits", "footer-fits", "nothing-fits"],
)
def test_a_full_disk_stops_the_writer_and_every_reader_finds_the_bag_up_to_it(
    tmp_path, room, closed
):
    """20 messages of 2 kB are flushed, then the disk has ``room`` bytes left and 40 more do not
    fit. The file is cut after the 20 and closed as far as the room allows: with its summary
    (60 kB), its footer alone (300 B), or not at all (20 B)."""
    bag = tmp_path / "full"
    writer, files = small_disk_writer(bag)
    for i in range(20):
        writer.write(TOPIC, message(i), log_time_ns=(1 + i) * S)
    writer.flush()
    complete = files[0].tell()
    files[0].capacity = complete + room
    with pytest.raises(RecordingStopped) as stopped:
        for i in range(20, 60):
            writer.write(TOPIC, message(i), log_time_ns=(1 + i) * S)
        writer.flush()
    failure = stopped.value
    assert failure is writer.failure and failure.closed == closed
    assert str(failure).startswith(
        f"disk full after 20 messages: recording stopped; the bag up to {iso_time(20 * S)} "
        "is readable (full_0.mcap "
    )
    assert not writer.write(TOPIC, message(60), log_time_ns=61 * S)
    assert writer.dropped == 41  # the 40 that did not fit and the one after
    writer.close()  # does nothing more, raises nothing
    writer.close()

    mcap = bag / "full_0.mcap"
    if closed == CUT:
        assert mcap.stat().st_size == complete  # nothing after the last complete chunk
    info = bag_info(bag)
    assert info.finalized == (closed == SUMMARY)
    assert (info.message_count, info.start_ns, info.end_ns) == (20, 1 * S, 20 * S)
    assert [m.msg.data[:4] for m in read_messages(bag)] == [f"{i:04d}" for i in range(20)]
    assert metadata_counts(bag) == {TOPIC: 20} and failure.metadata_written
    seen = foxglove_read(mcap)
    assert seen["indexed"] == (closed == SUMMARY)
    assert seen["topics"][TOPIC]["count"] == 20 and seen["last"][TOPIC]["data"][:4] == "0019"
    if closed != CUT:  # rosbags needs the footer
        assert rosbags_counts(bag) == {TOPIC: 20}
    assert sorted(p.name for p in bag.iterdir()) == ["full_0.mcap", "metadata.yaml"]


def test_a_chunk_that_fills_the_disk_while_messages_are_added_stops_the_writer(tmp_path):
    """Without a flush, the mcap writer writes a chunk once it holds 1 MiB: that write fails."""
    bag = tmp_path / "chunks"
    writer, files = small_disk_writer(bag)
    files[0].capacity = 1_500_000  # one chunk of 1 MiB and its summary, not two
    calls = 0
    with pytest.raises(RecordingStopped):
        for i in range(40):
            calls += 1
            writer.write(TOPIC, message(i, size=100_000), log_time_ns=(1 + i) * S)
    kept = bag_info(bag)
    assert kept.finalized and kept.message_count == 11  # the first chunk: 11 × 100 kB > 1 MiB
    assert writer.stats.message_count == 11 and writer.dropped == calls - 11 == 11
    assert [m.msg.data[:4] for m in read_messages(bag)] == [f"{i:04d}" for i in range(11)]


def test_a_disk_that_fills_at_close_keeps_every_message(tmp_path):
    """The data fit; the summary does not: the file is closed with its footer alone."""
    bag = tmp_path / "closing"
    writer, files = small_disk_writer(bag)
    for i in range(5):
        writer.write(TOPIC, message(i), log_time_ns=(1 + i) * S)
    writer.flush()
    files[0].capacity = files[0].tell() + 300
    writer.close()  # no exception: the failure is recorded
    assert writer.failure is not None and writer.failure.closed == FOOTER
    assert writer.dropped == 0 and bag_info(bag).message_count == 5
    assert rosbags_counts(bag) == {TOPIC: 5} and metadata_counts(bag) == {TOPIC: 5}


def test_a_metadata_yaml_that_cannot_be_written_leaves_the_mcap_readable(tmp_path):
    bag = tmp_path / "nometa"
    writer, _ = small_disk_writer(bag)
    writer.write(TOPIC, message(0), log_time_ns=S)
    (bag / "metadata.yaml.tmp").mkdir()  # writing the temporary file fails, for root too
    writer.close()
    assert isinstance(writer.metadata_error, IsADirectoryError) and writer.failure is None
    assert not (bag / "metadata.yaml").exists()
    assert bag_info(bag).finalized and [m.msg.data[:4] for m in read_messages(bag)] == ["0000"]


def test_finalizing_a_cut_file_writes_the_summary_the_mcap_writer_writes(tmp_path):
    """The summary that closes a cut file lists what mcap's own writer lists for the same data
    (schemas, channels, statistics, chunk indexes, the rosbag2 metadata record's index)."""
    bag = tmp_path / "whole"
    with Rosbag2McapWriter(bag) as writer:
        writer.add_topic("/a", "std_msgs/msg/String", [])
        writer.add_topic("/b", "std_msgs/msg/String", [])
        for i in range(30):
            writer.write("/a" if i % 3 else "/b", message(i, 50_000), log_time_ns=(1 + i) * S)
            if i % 7 == 6:
                writer.flush()
    mcap = bag / "whole_0.mcap"
    with mcap.open("rb") as f:
        expected = make_reader(f).get_summary()
        f.seek(-37, os.SEEK_END)  # the footer: summary_start is after its opcode and length
        summary_start = int.from_bytes(f.read(17)[9:17], "little")
    copy = tmp_path / "cut.mcap"
    copy.write_bytes(mcap.read_bytes()[: summary_start - 13])  # before DataEnd
    with copy.open("r+b", buffering=0) as f:
        assert finalize_in_place(f, copy, copy.stat().st_size) == SUMMARY
    with copy.open("rb") as f:
        got = make_reader(f, validate_crcs=True).get_summary()
        assert len(list(make_reader(f).iter_messages())) == 30
    assert got.schemas == expected.schemas and got.channels == expected.channels
    assert got.statistics == expected.statistics
    assert got.chunk_indexes == expected.chunk_indexes
    assert got.metadata_indexes == expected.metadata_indexes
    assert copy.read_bytes() == mcap.read_bytes()  # byte for byte, summary offsets included


# ------------------------------------------------------------------ at start
def test_rrg_launch_refuses_a_bags_folder_it_cannot_write(tmp_path, capsys):
    """Before any node starts: a bags folder under a regular file, or a regular file."""
    blocker = tmp_path / "a_file"
    blocker.write_text("")
    for bags in (blocker / "bags", blocker):
        assert launch.main(["--bags", str(bags), "--bag-name", "b"]) == 2
        err = capsys.readouterr().err
        assert err == f"rrg-launch: cannot write bags to {bags}: Not a directory\n"


def test_rrg_launch_refuses_a_bags_folder_it_cannot_write_a_block_into(tmp_path):
    """A file size limit below one block: the launcher's probe write fails (EFBIG), as on a
    full disk (ENOSPC)."""
    run = (
        "import resource, runpy, sys; "
        "resource.setrlimit(resource.RLIMIT_FSIZE, (1000, resource.RLIM_INFINITY)); "
        f"sys.argv = ['rrg-launch', '--bags', {str(tmp_path / 'bags')!r}]; "
        "runpy.run_module('rrg_bringup.launch', run_name='__main__')"
    )
    out = subprocess.run(
        [sys.executable, "-c", run], capture_output=True, text=True, timeout=120, cwd=ROOT
    )
    assert out.returncode == 2, out.stderr
    assert out.stderr == f"rrg-launch: cannot write bags to {tmp_path / 'bags'}: File too large\n"
    assert list((tmp_path / "bags").iterdir()) == []  # the probe is gone


def test_rrg_launch_warns_when_little_space_is_left(tmp_path, capsys):
    assert launch.bags_writable(tmp_path / "bags", low_space_bytes=2**62)
    err = capsys.readouterr().err
    assert err.startswith("rrg-launch: warning: ") and "MiB free for bags in" in err
    assert launch.bags_writable(tmp_path / "bags", low_space_bytes=0)
    assert capsys.readouterr().err == ""


def test_the_recorder_exits_with_one_line_when_it_cannot_create_its_bag(tmp_path, ros_env):
    """Under a regular file (ENOTDIR), and with a file size limit of 10 bytes (EFBIG: not even
    the MCAP header fits). Exit status 1; the launcher's bounded respawn gives up on it."""
    blocker = tmp_path / "a_file"
    blocker.write_text("")
    run = (
        "import resource, runpy, sys; "
        "resource.setrlimit(resource.RLIMIT_FSIZE, (10, resource.RLIM_INFINITY)); "
        f"sys.argv = ['recorder', '--output', {str(tmp_path / 'limited')!r}]; "
        "runpy.run_module('rrg_bags.recorder_node', run_name='__main__')"
    )
    cases = [
        (["-m", "rrg_bags.recorder_node", "--output", str(blocker / "bag")], blocker),
        (["-c", run], tmp_path / "limited"),
    ]
    reasons = []
    for args, where in cases:
        out = subprocess.run(
            [sys.executable, *args], env=ros_env, capture_output=True, text=True, timeout=60
        )
        assert out.returncode == 1, out.stderr
        line = out.stderr.strip()
        assert "\n" not in line, out.stderr
        prefix = "rrg_bag_recorder: cannot create the bag "
        assert line.startswith(prefix + str(where if where != blocker else blocker / "bag"))
        reasons.append(line.rsplit(": ", 1)[1])
    assert reasons == ["Not a directory", "File too large"]


# ------------------------------------------------------------------ the recorder node
@pytest.fixture(scope="module")
def ros_env(ros_domain):
    return ros_testing.ros_env(ros_domain)


@pytest.mark.slow  # a recorder process
def test_a_recorder_whose_file_reaches_its_limit_stops_recording_and_keeps_running(
    ros_env, tmp_path
):
    """The real recorder with RLIMIT_FSIZE set to its file's size + 500 kB once it records
    /fill: 100 messages of 10 kB at 50 Hz (about 100 kB per 0.2 s flush) do not fit. It logs
    one error, stays alive and drops (and counts) what follows; on SIGINT it exits 0. Every
    reader finds the same first k messages, 0 < k < 100, the last at the time the error names.
    (Before, the recorder died of the OSError, leaving a cut file and no metadata.yaml.)"""
    client = RosClient(ros_env, "fault_publisher")
    node, executor = client.node, client.executor
    bag = tmp_path / "limited"
    log_path = tmp_path / "recorder.log"
    params = {
        "discovery_period": 0.1,
        "flush_period": 0.2,
        "exclude_topics": "['/rosout','/parameter_events','/diagnostics']",
    }
    proc = start_node("rrg_bags.recorder_node", ros_env, log_path, params, ["--output", str(bag)])
    try:
        pub = node.create_publisher(String, TOPIC, 200)
        deadline = time.monotonic() + 20
        while pub.get_subscription_count() == 0:
            assert time.monotonic() < deadline, "the recorder did not subscribe"
            executor.spin_once(timeout_sec=0.05)
        limit = (bag / "limited_0.mcap").stat().st_size + 500_000
        resource.prlimit(proc.pid, resource.RLIMIT_FSIZE, (limit, resource.RLIM_INFINITY))
        for i in range(100):
            pub.publish(String(data=f"{i:04d}" + "x" * 10_000))
            time.sleep(0.02)
        assert pub.wait_for_all_acked(Duration(seconds=10))
        time.sleep(1.0)  # past the next flush
        assert proc.poll() is None, "the recorder exited"
        for i in range(100, 120):  # dropped
            pub.publish(String(data=f"{i:04d}" + "x" * 10_000))
        assert pub.wait_for_all_acked(Duration(seconds=10))
        time.sleep(0.5)
        assert proc.poll() is None, "the recorder exited"
    finally:
        status = stop_process(proc, timeout_s=20)
        client.close()
    log = log_path.read_text()
    assert status == 0, log
    errors = [line for line in log.splitlines() if "[ERROR]" in line]
    assert len(errors) == 1, log
    error = errors[0].split("]: ", 1)[1]

    mcap = bag / "limited_0.mcap"
    info = bag_info(bag)
    k = info.message_count
    assert 0 < k < 100 and mcap.stat().st_size <= limit
    assert error.startswith(
        f"file size limit reached after {k} messages: recording stopped; "
        f"the bag up to {iso_time(info.end_ns)} is readable (limited_0.mcap "
    )
    assert f"({k} messages on 1 topics" in log and f"{120 - k} messages not recorded" in log
    expected = [f"{i:04d}" for i in range(k)]
    assert [m.msg.data[:4] for m in read_messages(bag)] == expected
    assert metadata_counts(bag) == {TOPIC: k}
    seen = foxglove_read(mcap)
    assert seen["topics"][TOPIC]["count"] == k
    assert seen["last"][TOPIC]["data"][:4] == expected[-1]
    if "(limited_0.mcap not closed" not in error:  # a footer was written: rosbags reads it
        assert rosbags_counts(bag) == {TOPIC: k}
