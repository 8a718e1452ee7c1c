"""Record every topic of a running ROS 2 graph into a rosbag2-layout MCAP bag (operations §8).

Run as a process, e.g. as the launcher's child::

    python -m rrg_bags.recorder_node --output bags/NAME [--append] \
        [--ros-args -p discovery_period:=0.2]

It polls the graph for topics, subscribes to each new one with ``raw=True`` (CDR bytes as they
came off the wire), and matches its publishers' durability, so latched (TRANSIENT_LOCAL) topics
are captured even when they were published before the recorder saw them. Hidden topics (a
name part starting with ``_``, e.g. actions' internal topics) are skipped, as ``ros2 bag record
--all`` does. SIGINT, SIGTERM or Ctrl-C stop it: it first writes the messages it has already
received (``BagRecorder.drain``, at most DRAIN_S; a second signal cuts that short), then
finalizes the bag, which it always does. Every ``flush_period`` it writes what it has received
to the file as a complete chunk, so a SIGKILL loses at most that much. With ``--append`` (the
launcher restarting a recorder that died) it writes the next split of an existing bag folder
(operations §8). When a write fails (the disk is full) it logs one error, stops recording (the bag
written so far is closed and stays readable; later messages are dropped and counted) and keeps
running, so the launcher does not restart it. A bag it cannot create ends it with one line and
exit status 1. Its health (the bag, messages written and dropped) goes on ``/diagnostics`` once
a second (``rrg_bag_recorder: status``), which it records too.
"""

from __future__ import annotations

import argparse
import signal
import sys
import time
from pathlib import Path

import rclpy
import rclpy.logging
from rclpy.duration import Duration
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor, TimeoutException
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from rclpy.subscription import Subscription
from rclpy.topic_endpoint_info import TopicEndpointInfo
from rclpy.utilities import remove_ros_args

from rrg_bags.bag_schema import UnknownMessageType, message_class
from rrg_bags.bag_writer import RecordingStopped, Rosbag2McapWriter
from rrg_common.ros.diagnostics import ERROR, Health, NodeDiagnostics
from rrg_common.ros.parameters import Param, declare

NODE_NAME = "rrg_bag_recorder"
#: Longest time [s] spent writing the already received messages after a stop signal (below the
#: launcher's STOP_ESCALATE_S, so the bag is closed before a second signal comes).
DRAIN_S = 2.0


def is_hidden(topic: str) -> bool:
    """True for hidden topics: any name part starting with an underscore."""
    return any(part.startswith("_") for part in topic.split("/"))


def _duration_dict(d: Duration) -> dict:
    sec, nsec = divmod(d.nanoseconds, 1_000_000_000)
    return {"sec": sec, "nsec": nsec}


def qos_to_dict(q: QoSProfile) -> dict:
    """A QoS profile as rosbag2 metadata version 9 writes it (lower-case policy names)."""
    return {
        "history": q.history.name.lower(),
        "depth": q.depth,
        "reliability": q.reliability.name.lower(),
        "durability": q.durability.name.lower(),
        "deadline": _duration_dict(q.deadline),
        "lifespan": _duration_dict(q.lifespan),
        "liveliness": q.liveliness.name.lower(),
        "liveliness_lease_duration": _duration_dict(q.liveliness_lease_duration),
        "avoid_ros_namespace_conventions": q.avoid_ros_namespace_conventions,
    }


def subscription_qos(publishers: list[TopicEndpointInfo], depth: int) -> QoSProfile:
    """QoS that receives from every publisher (rosbag2's rule): reliable and transient-local
    only when all publishers offer it, so latched messages are delivered to the recorder."""
    qos = [p.qos_profile for p in publishers]
    all_reliable = all(q.reliability == ReliabilityPolicy.RELIABLE for q in qos)
    all_latched = all(q.durability == DurabilityPolicy.TRANSIENT_LOCAL for q in qos)
    return QoSProfile(
        depth=depth,
        reliability=ReliabilityPolicy.RELIABLE if all_reliable else ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.TRANSIENT_LOCAL if all_latched else DurabilityPolicy.VOLATILE,
    )


#: The node's parameters (rrg_common.ros.parameters).
PARAMETERS: tuple[Param, ...] = (
    Param("discovery_period", 0.2, "Period [s] of the poll for new topics", low=0.05, high=10.0),
    Param(
        "qos_depth",
        1000,
        "History depth of each subscription (messages queued per topic)",
        low=1,
        high=10000,
    ),
    Param(
        "flush_period",
        1.0,
        (
            "Period [s] of writing the received messages to the file as a "
            "complete chunk (at most this much is lost when the recorder is killed)"
        ),
        read_only=True,
        low=0.1,
        high=60.0,
    ),
    Param(
        "exclude_topics",
        [""],
        "Topics not to record (e.g. a driver's 500 Hz joint states)",
        read_only=True,
    ),
)


class BagRecorder(Node):
    """Subscribes to every (non-hidden) topic as it appears and writes all messages to a bag."""

    def __init__(self, writer: Rosbag2McapWriter, context: rclpy.Context | None = None) -> None:
        super().__init__(NODE_NAME, context=context)
        declare(self, PARAMETERS)
        self._excluded = {t for t in self.get_parameter("exclude_topics").value if t}
        self._depth = self.get_parameter("qos_depth").value
        self.writer = writer
        self._recorded: dict[str, Subscription] = {}
        self._skipped: set[str] = set()
        self._discovery = self.create_timer(
            self.get_parameter("discovery_period").value, self.discover
        )
        self._flush = self.create_timer(self.get_parameter("flush_period").value, self.flush)
        self.diagnostics = NodeDiagnostics(self, self.health)
        self.discover()
        self.get_logger().info(
            f"recording all topics to {writer.mcap_path}"
            + (f" except {', '.join(sorted(self._excluded))}" if self._excluded else "")
            + (f" (after the bag's {len(writer.earlier)} earlier files)" if writer.earlier else "")
        )

    def health(self) -> Health:
        """For /diagnostics: the bag file, the topics recorded and skipped, the messages
        written to this file and those dropped; ERROR once recording stopped (a failed
        write)."""
        writer = self.writer
        health = Health(message="recording")
        health.values["bag"] = str(writer.mcap_path)
        health.values["topics recorded"] = str(len(self._recorded))
        health.values["topics skipped (type unknown)"] = ", ".join(sorted(self._skipped)) or "none"
        health.values["messages written"] = str(writer.stats.message_count)
        health.values["messages dropped"] = str(writer.dropped)
        if writer.failure is not None:
            health.escalate(ERROR, f"recording stopped: {writer.failure}")
        return health

    def discover(self) -> None:
        """Subscribe to every topic that has a publisher and is not recorded yet."""
        for topic, types in self.get_topic_names_and_types():
            if (
                topic in self._recorded
                or topic in self._skipped
                or topic in self._excluded
                or is_hidden(topic)
            ):
                continue
            publishers = self.get_publishers_info_by_topic(topic)
            if not publishers:
                continue  # only subscribers so far: wait for a publisher's QoS
            if len(types) > 1:
                self.get_logger().warning(
                    f"{topic} has several types {types}; recording {types[0]}"
                )
            self._subscribe(topic, types[0], publishers)

    def _subscribe(self, topic: str, msg_type: str, publishers: list[TopicEndpointInfo]) -> None:
        try:
            cls = message_class(msg_type)
            self.writer.add_topic(
                topic,
                msg_type,
                [qos_to_dict(p.qos_profile) for p in publishers],
                str(publishers[0].topic_type_hash),
            )
        except (ImportError, AttributeError, ValueError, UnknownMessageType) as exc:
            self.get_logger().error(f"not recording {topic} ({msg_type}): {exc}")
            self._skipped.add(topic)
            return
        except RecordingStopped as stop:
            self.stopped(stop)
            return
        qos = subscription_qos(publishers, self._depth)
        self._recorded[topic] = self.create_subscription(
            cls, topic, lambda data, info, t=topic: self._on_message(t, data, info), qos, raw=True
        )
        self.get_logger().info(f"recording {topic} [{msg_type}] ({qos.durability.name.lower()})")

    def _on_message(self, topic: str, data: bytes, info: dict) -> None:
        log_time = info.get("received_timestamp") or time.time_ns()
        try:
            self.writer.write(topic, data, log_time, info.get("source_timestamp") or log_time)
        except RecordingStopped as stop:
            self.stopped(stop)

    def flush(self) -> None:
        """Write the received messages to the file as a complete chunk (the flush timer)."""
        try:
            self.writer.flush()
        except RecordingStopped as stop:
            self.stopped(stop)

    def stopped(self, stop: RecordingStopped) -> None:
        """The bag cannot be written any more: say so once, and stop discovering and flushing.
        The subscriptions stay, so the dropped messages are counted, and the node keeps running
        (a recorder that exited would be restarted into the same full disk)."""
        self.get_logger().error(str(stop))
        self._discovery.cancel()
        self._flush.cancel()

    def drain(self, executor: SingleThreadedExecutor, budget_s: float, stop=lambda: False) -> int:
        """Write the messages already received, without waiting for new ones: run every ready
        callback until none is ready, for at most ``budget_s`` or until ``stop()``. Stops the
        topic discovery first. Returns the number of messages written."""
        self._discovery.cancel()
        before = self.writer.stats.message_count
        deadline = time.monotonic() + budget_s
        idle = False
        while time.monotonic() < deadline and not stop():
            try:
                handler, _, _ = executor.wait_for_ready_callbacks(timeout_sec=0.0)
            except TimeoutException:
                # the callbacks one zero-timeout wait found are done: wait again, unless that
                # wait found none
                if idle:
                    break
                idle = True
                continue
            idle = False
            handler()
            handler.result()  # raise what the callback raised
        return max(0, self.writer.stats.message_count - before)  # (0 once recording stopped)


def parse_args(argv: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        prog="python -m rrg_bags.recorder_node",
        description="Record every topic into a rosbag2-layout MCAP bag.",
    )
    parser.add_argument(
        "--output",
        "-o",
        required=True,
        type=Path,
        help="bag folder to create (e.g. bags/NAME); must not exist, unless --append",
    )
    parser.add_argument(
        "--append",
        action="store_true",
        help="write the next split <NAME>_<k>.mcap of an existing bag folder (a restarted "
        "recorder); messages of latched topics that an earlier split holds are not written again",
    )
    return parser.parse_args(remove_ros_args(argv)[1:])


def closing_report(writer: Rosbag2McapWriter) -> str:
    """The recorder's last line: what the bag file holds, and what it does not."""
    split = writer.this_split()
    return (
        f"bag closed: {writer.mcap_path} ({split.stats.message_count} messages on "
        f"{len(split.topics)} topics, {split.stats.duration_ns / 1e9:.3f} s"
        + (
            f"; {writer.repeats_skipped} latched messages an earlier file holds not written"
            if writer.repeats_skipped
            else ""
        )
        + (
            f"; recording had stopped: {writer.dropped} messages not recorded"
            if writer.failure is not None
            else ""
        )
        + ")"
    )


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv if argv is None else argv
    args = parse_args(argv)
    if args.output.exists() and not args.append:
        print(f"bag folder already exists: {args.output}", file=sys.stderr)
        return 1
    try:
        writer = Rosbag2McapWriter(args.output, append=args.append)
    except OSError as exc:  # not writable, not a folder, the disk full, ...
        print(
            f"{NODE_NAME}: cannot create the bag {args.output}: {exc.strerror or exc}",
            file=sys.stderr,
        )
        return 1
    signals: list[int] = []
    recorder = None
    try:
        # rclpy's own handlers would shut the context down at the signal, and with it the
        # subscriptions whose received messages are still to be written: count the signals
        rclpy.init(args=argv, signal_handler_options=SignalHandlerOptions.NO)
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, lambda signum, _frame: signals.append(signum))
        recorder = BagRecorder(writer)
        for name, how in writer.closed_earlier.items():
            recorder.get_logger().warning(
                f"closed the split {name} its killed recorder left open ({how})"
            )
        executor = SingleThreadedExecutor()
        executor.add_node(recorder)
        # spin_once in a loop: a node blocked in spin() sometimes misses the first SIGINT.
        while rclpy.ok() and not signals:
            executor.spin_once(timeout_sec=0.1)
        if signals and rclpy.ok():
            n = recorder.drain(executor, DRAIN_S, stop=lambda: len(signals) > 1)
            recorder.get_logger().info(
                "stopping"
                if writer.failure is not None
                else f"stopping: wrote {n} messages received before the signal"
            )
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        reported = writer.failure
        writer.close()  # always: the MCAP summary and footer, then metadata.yaml
        if recorder is not None:
            recorder.destroy_node()  # first, so the messages below do not go to /rosout
        logger = rclpy.logging.get_logger(NODE_NAME)
        if writer.failure is not None and writer.failure is not reported:
            logger.error(str(writer.failure))  # the disk filled while the bag was closed
        elif writer.metadata_error is not None and writer.failure is None:
            logger.error(
                f"cannot write {args.output / 'metadata.yaml'} "
                f"({writer.metadata_error.strerror or writer.metadata_error}); "
                "the MCAP files are complete and read without it"
            )
        logger.info(closing_report(writer))
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
