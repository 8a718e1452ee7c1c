"""Read and decode the messages of an RRG bag (rosbag2 layout, MCAP storage) in log-time order.

Messages are decoded with rclpy's own deserializer into the generated Python classes, so the
bag tools work with the same types as the nodes. A bag whose recorder was killed before it
wrote the MCAP summary is read by scanning its records up to where the file ends.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Channel, Message, Schema
from rclpy.serialization import deserialize_message

from rrg_planner.bags.bag_info import complete_records, find_mcap
from rrg_planner.bags.bag_schema import message_class


@dataclass(frozen=True)
class BagMessage:
    topic: str
    log_time_ns: int
    msg: Any


def _raw_finalized(
    path: Path, topics: set[str] | None
) -> Iterator[tuple[Schema, Channel, Message]]:
    with path.open("rb") as f:
        yield from make_reader(f).iter_messages(
            topics=sorted(topics) if topics else None, log_time_order=True
        )


def _raw_scanned(path: Path, topics: set[str] | None) -> Iterator[tuple[Schema, Channel, Message]]:
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    found = []
    for record in complete_records(path):
        if isinstance(record, Schema):
            schemas[record.id] = record
        elif isinstance(record, Channel):
            channels[record.id] = record
        elif isinstance(record, Message):
            ch = channels[record.channel_id]
            if topics is None or ch.topic in topics:
                found.append((schemas[ch.schema_id], ch, record))
    found.sort(key=lambda t: t[2].log_time)
    yield from found


def is_finalized(path: Path) -> bool:
    with path.open("rb") as f:
        try:
            make_reader(f).get_summary()
        except (McapError, ValueError, EOFError):
            return False
    return True


def read_messages(bag: str | Path, topics: Iterable[str] | None = None) -> Iterator[BagMessage]:
    """Decoded messages of the given topics (default: all), in log-time order."""
    path = find_mcap(Path(bag))
    wanted = set(topics) if topics is not None else None
    raw = _raw_finalized if is_finalized(path) else _raw_scanned
    classes: dict[str, type] = {}
    for schema, channel, message in raw(path, wanted):
        cls = classes.get(schema.name) or classes.setdefault(
            schema.name, message_class(schema.name)
        )
        yield BagMessage(channel.topic, message.log_time, deserialize_message(message.data, cls))


#: Topics the bag tools read (the nodes publish them under the /rrg namespace).
BELIEF_TOPIC = "/rrg/belief"
OBSERVATION_TOPIC = "/rrg/observation"
GRASP_STEP_TOPIC = "/rrg/grasp_step"
TRUE_POSE_TOPIC = "/rrg/eval/object_pose"
GRASP_OUTCOME_TOPIC = "/rrg/eval/grasp_outcome"
