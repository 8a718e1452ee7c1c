"""A rosbag2-layout MCAP bag writer that needs no rosbag2 (design §8).

Layout: ``<bag>/<name>_0.mcap`` plus ``<bag>/metadata.yaml`` (rosbag2 metadata version 9),
where ``<name>`` is the bag folder's name. The MCAP file has profile ``ros2``, ``cdr``
messages, ``ros2msg`` schemas with their full dependency text, ``offered_qos_profiles`` and
``topic_type_hash`` in each channel's metadata, and rosbag2's ``rosbag2`` metadata record, so
rosbags and Foxglove read it as they read rosbag2's own bags. ROS-free: it takes already
serialized messages.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import yaml
from mcap.writer import CompressionType, Writer

from rrg_planner.bags.bag_schema import SCHEMA_ENCODING, full_definition

PROFILE = "ros2"
MESSAGE_ENCODING = "cdr"
METADATA_VERSION = 9
ROS_DISTRO = "jazzy"
LIBRARY = "rrg bag_writer (mcap python)"


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


def dump_qos_profiles(profiles: list[dict]) -> str:
    """The ``offered_qos_profiles`` YAML text of an MCAP channel (a YAML list of QoS dicts)."""
    return (
        yaml.safe_dump(profiles, default_flow_style=False, sort_keys=False).strip()
        if profiles
        else ""
    )


class Rosbag2McapWriter:
    """Write serialized messages of any number of topics into a new bag folder.

    Use as a context manager, or call ``close()``: it finalizes the MCAP file (summary and
    footer) and writes metadata.yaml. The folder must not exist yet (as with rosbag2).
    """

    def __init__(self, bag_dir: str | Path) -> None:
        self.bag_dir = Path(bag_dir)
        self.topics: dict[str, TopicRecord] = {}
        self.stats = BagStats()
        if self.bag_dir.exists():
            raise FileExistsError(f"bag folder already exists: {self.bag_dir}")
        self.bag_dir.mkdir(parents=True)
        self.mcap_path = self.bag_dir / f"{self.bag_dir.name}_0.mcap"
        self._file = self.mcap_path.open("wb")
        # Uncompressed chunks, as rosbag2's default: every reader decodes them without plugins.
        self._writer = Writer(self._file, compression=CompressionType.NONE)
        self._writer.start(profile=PROFILE, library=LIBRARY)
        self._schemas: dict[str, int] = {}
        self._closed = False

    def add_topic(
        self,
        name: str,
        msg_type: str,
        offered_qos_profiles: list[dict],
        type_description_hash: str = "",
    ) -> TopicRecord:
        """Register a topic of ``msg_type`` (``pkg/msg/Type``); raises UnknownMessageType when
        its .msg definition cannot be found."""
        if name in self.topics:
            raise ValueError(f"topic already registered: {name}")
        if msg_type not in self._schemas:
            self._schemas[msg_type] = self._writer.register_schema(
                name=msg_type,
                encoding=SCHEMA_ENCODING,
                data=full_definition(msg_type).encode("utf-8"),
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
    ) -> None:
        """Append one CDR-serialized message of a registered topic (times: ns since the epoch;
        log time defaults to now, publish time to the log time)."""
        record = self.topics[topic]
        log_time_ns = time.time_ns() if log_time_ns is None else log_time_ns
        publish_time_ns = log_time_ns if publish_time_ns is None else publish_time_ns
        self._writer.add_message(
            channel_id=record.channel_id,
            log_time=log_time_ns,
            data=data,
            publish_time=publish_time_ns,
            sequence=record.message_count,
        )
        record.message_count += 1
        self.stats.add(log_time_ns)

    def metadata(self) -> dict:
        """rosbag2's metadata.yaml content (version 9)."""
        s = self.stats
        return {
            "rosbag2_bagfile_information": {
                "version": METADATA_VERSION,
                "storage_identifier": "mcap",
                "duration": {"nanoseconds": s.duration_ns},
                "starting_time": {"nanoseconds_since_epoch": s.start_ns},
                "message_count": s.message_count,
                "topics_with_message_count": [
                    {
                        "topic_metadata": {
                            "name": t.name,
                            "type": t.type,
                            "serialization_format": MESSAGE_ENCODING,
                            "offered_qos_profiles": t.offered_qos_profiles,
                            "type_description_hash": t.type_description_hash,
                        },
                        "message_count": t.message_count,
                    }
                    for t in self.topics.values()
                ],
                "compression_format": "",
                "compression_mode": "",
                "relative_file_paths": [self.mcap_path.name],
                "files": [
                    {
                        "path": self.mcap_path.name,
                        "starting_time": {"nanoseconds_since_epoch": s.start_ns},
                        "duration": {"nanoseconds": s.duration_ns},
                        "message_count": s.message_count,
                    }
                ],
                "custom_data": None,
                "ros_distro": ROS_DISTRO,
            }
        }

    def close(self) -> None:
        """Finalize the MCAP file and write metadata.yaml; safe to call more than once."""
        if self._closed:
            return
        self._closed = True
        meta = self.metadata()
        info = meta["rosbag2_bagfile_information"]
        self._writer.add_metadata(
            "rosbag2",
            {
                "serialized_metadata": yaml.safe_dump(info, sort_keys=False),
                "ros_distro": ROS_DISTRO,
            },
        )
        self._writer.finish()
        self._file.close()
        tmp = self.bag_dir / "metadata.yaml.tmp"
        tmp.write_text(
            yaml.safe_dump(meta, default_flow_style=False, sort_keys=False), encoding="utf-8"
        )
        tmp.replace(self.bag_dir / "metadata.yaml")

    def __enter__(self) -> Rosbag2McapWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
