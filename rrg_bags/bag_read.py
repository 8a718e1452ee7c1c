"""Read and decode the messages of an RRG bag (rosbag2 layout, MCAP storage) in log-time order.

Messages are decoded with rclpy's own deserializer into the generated Python classes, so the
bag tools work with the same types as the nodes. A bag whose recorder was killed before it
wrote the MCAP summary is read by scanning its records up to where the file ends, and a bag of
several files (a restarted recorder's splits) is read across all of them.
"""

from __future__ import annotations

import heapq
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rclpy.serialization import deserialize_message

from rrg_bags.bag_info import bag_files, raw_messages
from rrg_bags.bag_schema import message_class


@dataclass(frozen=True)
class BagMessage:
    topic: str
    log_time_ns: int
    msg: Any


def read_messages(bag: str | Path, topics: Iterable[str] | None = None) -> Iterator[BagMessage]:
    """Decoded messages of the given topics (default: all), in log-time order over all the bag's
    files."""
    wanted = set(topics) if topics is not None else None
    files = [raw_messages(path, wanted) for path in bag_files(Path(bag))]
    classes: dict[str, type] = {}
    for schema, channel, message in heapq.merge(*files, key=lambda t: t[2].log_time):
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
NODE_EVENTS_TOPIC = "/rrg/launch/node_events"
