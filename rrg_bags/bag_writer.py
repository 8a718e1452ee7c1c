"""A rosbag2-layout MCAP bag writer that needs no rosbag2 (operations §8).

Layout: ``<bag>/<name>_0.mcap`` plus ``<bag>/metadata.yaml`` (rosbag2 metadata version 9),
where ``<name>`` is the bag folder's name; a restarted recorder appends the splits
``<name>_1.mcap``, ``<name>_2.mcap``, …, and metadata.yaml lists them all, as rosbag2 lists its
splits. Each MCAP file has profile ``ros2``, ``cdr`` messages, ``ros2msg`` schemas with their
full dependency text, ``offered_qos_profiles`` and ``topic_type_hash`` in each channel's
metadata, and rosbag2's ``rosbag2`` metadata record, so rosbags and Foxglove read it as they
read rosbag2's own bags. ROS-free: it takes already serialized messages.

A write that fails (the disk is full, a file size limit) stops the writer for good
(``RecordingStopped``): the file is cut after its last complete chunk, closed as far as the space
allows (``bag_finalize``), and metadata.yaml names what it holds; later messages are dropped and
counted.
"""

from __future__ import annotations

import errno
import os
import shutil
import tempfile
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

import yaml
from mcap.writer import CompressionType, Writer

from rrg_bags.bag_finalize import (
    FOOTER,
    SUMMARY,
    close_unfinished,
    finalize_in_place,
    write_all,
)
from rrg_bags.bag_info import (
    BagInfo,
    file_info,
    is_finalized,
    iso_time,
    raw_messages,
    splits,
)
from rrg_bags.bag_schema import SCHEMA_ENCODING, full_definition

PROFILE = "ros2"
MESSAGE_ENCODING = "cdr"
METADATA_VERSION = 9
ROS_DISTRO = "jazzy"
LIBRARY = "rrg bag_writer (mcap python)"
#: Free space [bytes] below which rrg-launch warns before it records (chosen: a one-action grasp
#: of the box at low uncertainty bags 0.8 MiB, measured; this leaves room for tens of longer ones).
LOW_SPACE_BYTES = 100 * 2**20
#: Bytes the start check writes into the bags folder (one file system block).
PROBE_BYTES = 4096
#: Why a write failed, by errno, as the recorder's error says it.
WRITE_ERRORS = {
    errno.ENOSPC: "disk full",
    errno.EDQUOT: "disk quota exceeded",
    errno.EFBIG: "file size limit reached",
}


@dataclass
class TopicRecord:
    """One recorded topic: its MCAP channel and what metadata.yaml says about it."""

    name: str
    type: str  # pkg/msg/Type
    offered_qos_profiles: list[dict]  # rosbag2 v9 QoS dicts (see bag_recorder.qos_to_dict)
    type_description_hash: str  # RIHS01_<hex>, or "" when unknown
    channel_id: int
    message_count: int = 0


@dataclass
class BagStats:
    """Message count and time range [ns since the epoch] over the whole bag."""

    message_count: int = 0
    start_ns: int = 0
    end_ns: int = 0

    def add(self, log_time_ns: int) -> None:
        self.start_ns = log_time_ns if self.message_count == 0 else min(self.start_ns, log_time_ns)
        self.end_ns = max(self.end_ns, log_time_ns)
        self.message_count += 1

    @property
    def duration_ns(self) -> int:
        return self.end_ns - self.start_ns if self.message_count else 0

    @classmethod
    def merged(cls, parts: list[BagStats]) -> BagStats:
        """The stats of several files together."""
        spans = [p for p in parts if p.message_count]
        if not spans:
            return cls()
        return cls(
            sum(p.message_count for p in spans),
            min(p.start_ns for p in spans),
            max(p.end_ns for p in spans),
        )


@dataclass
class SplitRecord:
    """One MCAP file of the bag, as metadata.yaml lists it."""

    path: str  # relative to the bag folder
    stats: BagStats
    topics: list[TopicRecord]

    @classmethod
    def of(cls, info: BagInfo) -> SplitRecord:
        """An earlier split, from what its file holds (its channels carry the QoS and hash)."""
        return cls(
            info.files[0].name,
            BagStats(info.message_count, info.start_ns, info.end_ns),
            [
                TopicRecord(
                    t.name,
                    t.type,
                    load_qos_profiles(t.metadata.get("offered_qos_profiles", "")),
                    t.metadata.get("topic_type_hash", ""),
                    -1,
                    t.count,
                )
                for t in info.topics
            ],
        )


class RecordingStopped(Exception):
    """A write to the bag failed, so the writer stopped: it cut the file after its last complete
    chunk, closed it as far as the space allowed, and wrote metadata.yaml if it could. ``str()``
    says so in one line."""

    def __init__(
        self, error: OSError, path: Path, kept: BagStats, closed: str, metadata_written: bool
    ) -> None:
        self.error = error
        self.path = path  # the MCAP file that was being written
        self.kept = kept  # what the whole bag holds (every split)
        self.closed = closed  # how far the file was closed: bag_finalize.SUMMARY, FOOTER or CUT
        self.metadata_written = metadata_written
        cause = WRITE_ERRORS.get(error.errno, f"cannot write {path} ({error.strerror or error})")
        kept_part = (
            f"the bag up to {iso_time(kept.end_ns)} is readable"
            if kept.message_count
            else "the bag holds no messages"
        )
        how = {SUMMARY: "finalized", FOOTER: "closed without its index"}.get(closed, "not closed")
        super().__init__(
            f"{cause} after {kept.message_count} messages: recording stopped; {kept_part} "
            f"({path.name} {how}"
            + ("" if metadata_written else ", metadata.yaml not written")
            + ")"
        )


class _SplitFile:
    """The MCAP file as the mcap writer writes it: each write goes to the file at once, and
    ``complete`` is where the writer's last finished call left it (after whole records)."""

    def __init__(self, raw: BinaryIO) -> None:
        self.raw = raw
        self.position = 0
        self.complete = 0

    def write(self, data: bytes) -> int:
        write_all(self.raw, data)
        self.position += len(data)
        return len(data)

    def tell(self) -> int:
        return self.position

    def flush(self) -> None:
        self.raw.flush()


def probe_bag_folder(folder: Path) -> int:
    """Create ``folder`` when missing and write a file of PROBE_BYTES in it (removed at once);
    raises OSError when bags cannot be written there. Returns the free space there [bytes]."""
    if folder.exists() and not folder.is_dir():
        raise NotADirectoryError(errno.ENOTDIR, os.strerror(errno.ENOTDIR), str(folder))
    folder.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryFile(dir=folder) as f:
        f.write(bytes(PROBE_BYTES))
        f.flush()
    return shutil.disk_usage(folder).free


def dump_qos_profiles(profiles: list[dict]) -> str:
    """The ``offered_qos_profiles`` YAML text of an MCAP channel (a YAML list of QoS dicts)."""
    return (
        yaml.safe_dump(profiles, default_flow_style=False, sort_keys=False).strip()
        if profiles
        else ""
    )


def load_qos_profiles(text: str) -> list[dict]:
    """An MCAP channel's ``offered_qos_profiles`` YAML text back as QoS dicts."""
    return (yaml.safe_load(text) or []) if text else []


def is_latched(topic: TopicRecord) -> bool:
    """Whether a publisher offers the topic TRANSIENT_LOCAL (a new subscriber gets its history)."""
    return any(q.get("durability") == "transient_local" for q in topic.offered_qos_profiles)


class Rosbag2McapWriter:
    """Write serialized messages of any number of topics into a new bag folder, or into the next
    split of an existing one.

    Use as a context manager, or call ``close()``: it finalizes the MCAP file (summary and
    footer) and writes metadata.yaml. The folder must not exist yet (as with rosbag2), unless
    ``append``: then the writer adds the split after the folder's last one (a restarted
    recorder), lists every split in metadata.yaml, and skips the messages of latched topics that
    an earlier split holds (a restarted recorder receives their history again). An earlier split
    its killed recorder left open is first closed after its last complete record
    (bag_finalize.close_unfinished), so that every reader, rosbags' too, opens the bag. The
    first write that fails raises RecordingStopped (``failure``); the writer then drops every
    message.
    ``open_file`` opens the split for unbuffered writing (tests pass a file that fails).
    """

    def __init__(
        self,
        bag_dir: str | Path,
        append: bool = False,
        open_file: Callable[[Path], BinaryIO] = lambda path: path.open("wb", buffering=0),
    ) -> None:
        self.bag_dir = Path(bag_dir)
        self.topics: dict[str, TopicRecord] = {}
        self.stats = BagStats()  # of this split
        if self.bag_dir.exists() and not append:
            raise FileExistsError(f"bag folder already exists: {self.bag_dir}")
        self.bag_dir.mkdir(parents=True, exist_ok=True)
        earlier = splits(self.bag_dir)
        #: earlier splits a killed recorder left open, and how far each was closed now
        self.closed_earlier: dict[str, str] = {
            path.name: close_unfinished(path) for path in earlier.values() if not is_finalized(path)
        }
        self.earlier = [SplitRecord.of(file_info(path)) for path in earlier.values()]
        self.repeats = self._latched_messages(list(earlier.values()))
        self.repeats_skipped = 0
        self.failure: RecordingStopped | None = None
        self.dropped = 0  # messages not in the file: cut off or received after the failure
        self.metadata_error: OSError | None = None  # of the last metadata.yaml write
        self._kept: SplitRecord | None = None  # this split as the failure left it
        self.mcap_path = self.bag_dir / f"{self.bag_dir.name}_{max(earlier, default=-1) + 1}.mcap"
        self._file = _SplitFile(open_file(self.mcap_path))
        # Uncompressed chunks, as rosbag2's default: every reader decodes them without plugins.
        self._writer = Writer(self._file, compression=CompressionType.NONE)
        self._schemas: dict[str, int] = {}
        self._closed = False
        try:
            self._writer.start(profile=PROFILE, library=LIBRARY)
        except OSError:
            self._file.raw.close()
            raise
        self._file.complete = self._file.position

    def _latched_messages(self, paths: list[Path]) -> dict[str, set[tuple[int, int]]]:
        """Topic → (publish time, hash of the data) of each message of a latched topic that the
        earlier splits hold."""
        found: dict[str, set[tuple[int, int]]] = {}
        for path, split in zip(paths, self.earlier):
            latched = [t.name for t in split.topics if is_latched(t)]
            for _, channel, message in raw_messages(path, latched) if latched else ():
                found.setdefault(channel.topic, set()).add(
                    (message.publish_time, hash(message.data))
                )
        return found

    def add_topic(
        self,
        name: str,
        msg_type: str,
        offered_qos_profiles: list[dict],
        type_description_hash: str = "",
    ) -> TopicRecord:
        """Register a topic of ``msg_type`` (``pkg/msg/Type``); raises UnknownMessageType when
        its .msg definition cannot be found. A topic that an earlier split holds keeps that
        split's QoS profiles and hash, so that every split's channel is the one topic that
        metadata.yaml lists (readers such as rosbags match them exactly)."""
        if name in self.topics:
            raise ValueError(f"topic already registered: {name}")
        for split in self.earlier:
            known = next((t for t in split.topics if t.name == name and t.type == msg_type), None)
            if known is not None:
                offered_qos_profiles = known.offered_qos_profiles
                type_description_hash = known.type_description_hash
                break
        if self.failure is not None:  # not in the file: nothing to register
            record = TopicRecord(name, msg_type, offered_qos_profiles, type_description_hash, -1)
            self.topics[name] = record
            return record
        definition = full_definition(msg_type) if msg_type not in self._schemas else ""
        with self._stopping_on_error():
            if msg_type not in self._schemas:
                self._schemas[msg_type] = self._writer.register_schema(
                    name=msg_type, encoding=SCHEMA_ENCODING, data=definition.encode("utf-8")
                )
            metadata = {
                "offered_qos_profiles": dump_qos_profiles(offered_qos_profiles),
                "topic_type_hash": type_description_hash,
            }
            channel_id = self._writer.register_channel(
                topic=name,
                message_encoding=MESSAGE_ENCODING,
                schema_id=self._schemas[msg_type],
                metadata=metadata,
            )
        record = TopicRecord(
            name, msg_type, offered_qos_profiles, type_description_hash, channel_id
        )
        self.topics[name] = record
        return record

    def write(
        self,
        topic: str,
        data: bytes,
        log_time_ns: int | None = None,
        publish_time_ns: int | None = None,
    ) -> bool:
        """Append one CDR-serialized message of a registered topic (times: ns since the epoch;
        log time defaults to now, publish time to the log time). False: not written, because an
        earlier split holds it (a latched message received again) or the writer has stopped
        (``failure``; counted in ``dropped``). Raises RecordingStopped when this write fails."""
        if self.failure is not None:
            self.dropped += 1
            return False
        record = self.topics[topic]
        log_time_ns = time.time_ns() if log_time_ns is None else log_time_ns
        publish_time_ns = log_time_ns if publish_time_ns is None else publish_time_ns
        repeats = self.repeats.get(topic)
        if repeats and (publish_time_ns, hash(data)) in repeats:
            self.repeats_skipped += 1
            return False
        with self._stopping_on_error(pending=1):
            self._writer.add_message(
                channel_id=record.channel_id,
                log_time=log_time_ns,
                data=data,
                publish_time=publish_time_ns,
                sequence=record.message_count,
            )
        record.message_count += 1
        self.stats.add(log_time_ns)
        return True

    def flush(self) -> None:
        """Write the messages so far to the file as a complete chunk: what a killed recorder's
        file keeps (the MCAP writer otherwise holds up to 1 MiB of them in memory). Raises
        RecordingStopped when the write fails."""
        if not self._closed and self.failure is None:
            with self._stopping_on_error():
                self._writer.flush()

    @contextmanager
    def _stopping_on_error(self, pending: int = 0) -> Iterator[None]:
        """Run a call of the mcap writer; when it fails, stop (``pending``: messages it was
        given that are not counted yet) and raise RecordingStopped. After a call that returns,
        the file ends after whole records."""
        try:
            yield
        except OSError as exc:
            self.dropped += pending
            raise self._stop(exc) from exc
        self._file.complete = self._file.position

    def _stop(self, error: OSError) -> RecordingStopped:
        """Stop writing after ``error``: cut the file after its last complete records, close it
        as far as the space allows, and write metadata.yaml of what it holds."""
        closed = finalize_in_place(self._file.raw, self.mcap_path, self._file.complete)
        try:
            self._file.raw.close()
        except OSError:
            pass  # closing releases the file whatever it reports
        self._closed = True
        self._kept = SplitRecord.of(file_info(self.mcap_path))
        self.dropped += self.stats.message_count - self._kept.stats.message_count
        self.stats = self._kept.stats
        metadata_written = self._write_metadata()
        kept = BagStats.merged([f.stats for f in [*self.earlier, self._kept]])
        self.failure = RecordingStopped(error, self.mcap_path, kept, closed, metadata_written)
        return self.failure

    def this_split(self) -> SplitRecord:
        """This writer's file as metadata.yaml lists it (after a failure: what the file holds)."""
        return self._kept or SplitRecord(
            self.mcap_path.name, self.stats, list(self.topics.values())
        )

    def metadata(self) -> dict:
        """rosbag2's metadata.yaml content (version 9), over every split of the bag."""
        files = [*self.earlier, self.this_split()]
        s = BagStats.merged([f.stats for f in files])
        topics: dict[str, dict] = {}
        for t in (t for f in files for t in f.topics):
            entry = topics.setdefault(
                t.name,
                {
                    "topic_metadata": {
                        "name": t.name,
                        "type": t.type,
                        "serialization_format": MESSAGE_ENCODING,
                        "offered_qos_profiles": t.offered_qos_profiles,
                        "type_description_hash": t.type_description_hash,
                    },
                    "message_count": 0,
                },
            )
            entry["message_count"] += t.message_count
        return {
            "rosbag2_bagfile_information": {
                "version": METADATA_VERSION,
                "storage_identifier": "mcap",
                "duration": {"nanoseconds": s.duration_ns},
                "starting_time": {"nanoseconds_since_epoch": s.start_ns},
                "message_count": s.message_count,
                "topics_with_message_count": list(topics.values()),
                "compression_format": "",
                "compression_mode": "",
                "relative_file_paths": [f.path for f in files],
                "files": [
                    {
                        "path": f.path,
                        "starting_time": {"nanoseconds_since_epoch": f.stats.start_ns},
                        "duration": {"nanoseconds": f.stats.duration_ns},
                        "message_count": f.stats.message_count,
                    }
                    for f in files
                ],
                "custom_data": None,
                "ros_distro": ROS_DISTRO,
            }
        }

    def close(self) -> None:
        """Finalize the MCAP file and write metadata.yaml; safe to call more than once. When the
        disk fills meanwhile, it stops as a failed write does (``failure``) instead of raising;
        a metadata.yaml that cannot be written leaves ``metadata_error``."""
        if self._closed:
            return
        try:
            with self._stopping_on_error():
                self._writer.flush()  # the data first, kept if the summary does not fit
            with self._stopping_on_error():
                info = self.metadata()["rosbag2_bagfile_information"]
                self._writer.add_metadata(
                    "rosbag2",
                    {
                        "serialized_metadata": yaml.safe_dump(info, sort_keys=False),
                        "ros_distro": ROS_DISTRO,
                    },
                )
                self._writer.finish()
        except RecordingStopped:
            return
        self._closed = True
        try:
            self._file.raw.close()
        except OSError:
            pass  # every write succeeded; the file is complete
        self._write_metadata()

    def _write_metadata(self) -> bool:
        """Write metadata.yaml (through a temporary file); False, with ``metadata_error``, when
        it cannot be written."""
        tmp = self.bag_dir / "metadata.yaml.tmp"
        text = yaml.safe_dump(self.metadata(), default_flow_style=False, sort_keys=False)
        try:
            tmp.write_text(text, encoding="utf-8")
            tmp.replace(self.bag_dir / "metadata.yaml")
        except OSError as exc:
            self.metadata_error = exc
            try:
                tmp.unlink(missing_ok=True)
            except OSError:
                pass  # e.g. not a file; the bag is read without metadata.yaml
            return False
        self.metadata_error = None
        return True

    def __enter__(self) -> Rosbag2McapWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
