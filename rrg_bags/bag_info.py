"""What a bag holds: its MCAP files (the splits ``<name>_0.mcap``, ``<name>_1.mcap``, … that a
restarted recorder adds), topics, types, message counts and time range, read from each file's
summary or, for a file without one (its recorder was killed, or the disk filled), by scanning its
complete records."""

from __future__ import annotations

import struct
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path

from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Channel, Message, Schema
from mcap.stream_reader import StreamReader

#: What reading a truncated MCAP file raises (a file cut inside its header: struct.error).
TRUNCATED = (McapError, ValueError, EOFError, struct.error)


@dataclass
class TopicSummary:
    name: str
    type: str  # schema name, pkg/msg/Type
    message_encoding: str
    count: int = 0
    metadata: dict[str, str] = field(default_factory=dict)  # the channel's (QoS, type hash)


@dataclass
class BagInfo:
    """What ``info`` prints: a bag's topics, counts and time range [ns since the epoch] over its
    MCAP files, in split order."""

    files: list[Path]
    size_bytes: int
    profile: str
    unfinalized: list[Path]  # files without their summary section and footer
    message_count: int = 0
    start_ns: int = 0
    end_ns: int = 0
    topics: list[TopicSummary] = field(default_factory=list)

    @property
    def finalized(self) -> bool:
        """Every file has its summary section and footer."""
        return not self.unfinalized

    @property
    def duration_s(self) -> float:
        return (self.end_ns - self.start_ns) / 1e9 if self.message_count else 0.0


def splits(bag_dir: Path) -> dict[int, Path]:
    """The bag folder's split files ``<folder>_<k>.mcap`` by index k, in order."""
    found = {}
    for path in bag_dir.glob("*.mcap"):
        stem, _, index = path.stem.rpartition("_")
        if stem == bag_dir.name and index.isdigit():
            found[int(index)] = path
    return dict(sorted(found.items()))


def bag_files(bag: Path) -> list[Path]:
    """The bag's MCAP files: ``bag`` itself, or the folder's splits ``<bag>_0.mcap``,
    ``<bag>_1.mcap``, … in order (else the folder's only one)."""
    if bag.is_file():
        return [bag]
    if not bag.is_dir():
        raise FileNotFoundError(f"no bag at {bag}")
    found = list(splits(bag).values())
    if found:
        return found
    others = sorted(bag.glob("*.mcap"))
    if len(others) != 1:
        raise FileNotFoundError(f"expected one .mcap file in {bag}, found {len(others)}")
    return others


def _topics(channels: dict[int, Channel], schemas: dict[int, Schema]) -> dict[int, TopicSummary]:
    return {
        cid: TopicSummary(
            c.topic,
            schemas[c.schema_id].name if c.schema_id in schemas else "",
            c.message_encoding,
            metadata=dict(c.metadata),
        )
        for cid, c in channels.items()
    }


def complete_records(path: Path) -> Iterator[object]:
    """Every MCAP record of a file in order, stopping quietly where a truncated file ends
    (a recorder killed before writing its summary leaves such a file)."""
    with path.open("rb") as f:
        try:
            yield from StreamReader(f).records
        except TRUNCATED:
            return  # truncated: keep what was complete


def is_finalized(path: Path) -> bool:
    """Whether the file has its summary section (with the footer that points to it)."""
    with path.open("rb") as f:
        try:
            return make_reader(f).get_summary() is not None
        except TRUNCATED:
            return False


def _scanned(
    path: Path, topics: set[str] | None, schemas: dict[int, Schema], channels: dict[int, Channel]
) -> Iterator[tuple[Schema, Channel, Message]]:
    """The complete messages of the given topics (None: all) in file order, filling ``schemas``
    and ``channels`` with the file's as they come."""
    for record in complete_records(path):
        if isinstance(record, Schema):
            schemas[record.id] = record
        elif isinstance(record, Channel):
            channels[record.id] = record
        elif isinstance(record, Message):
            ch = channels[record.channel_id]
            if topics is None or ch.topic in topics:
                yield schemas[ch.schema_id], ch, record


def raw_messages(
    path: Path, topics: Iterable[str] | None = None
) -> Iterator[tuple[Schema, Channel, Message]]:
    """One MCAP file's undecoded messages of the given topics (default: all) in log-time order,
    through its index, or by scanning a file that has none."""
    wanted = set(topics) if topics is not None else None
    if not is_finalized(path):
        yield from sorted(_scanned(path, wanted, {}, {}), key=lambda t: t[2].log_time)
        return
    with path.open("rb") as f:
        yield from make_reader(f).iter_messages(
            topics=sorted(wanted) if wanted is not None else None, log_time_order=True
        )


def _scan(path: Path, info: BagInfo) -> None:
    """Count messages by reading every complete record."""
    channels: dict[int, Channel] = {}
    schemas: dict[int, Schema] = {}
    counts: dict[int, int] = {}
    times: list[int] = []
    for _, channel, message in _scanned(path, None, schemas, channels):
        counts[channel.id] = counts.get(channel.id, 0) + 1
        times.append(message.log_time)
    topics = _topics(channels, schemas)
    for cid, n in counts.items():
        topics[cid].count = n
    info.topics = list(topics.values())
    info.message_count = len(times)
    if times:
        info.start_ns, info.end_ns = min(times), max(times)


def file_info(path: Path) -> BagInfo:
    """One MCAP file's topics, counts and time range, from its summary when it has one."""
    profile, summary = "", None
    with path.open("rb") as f:
        try:
            reader = make_reader(f)
            profile = reader.get_header().profile
            summary = reader.get_summary()
        except TRUNCATED:
            pass  # no summary: counted by scanning
    info = BagInfo([path], path.stat().st_size, profile, [] if summary is not None else [path])
    if summary is None or summary.statistics is None:
        _scan(path, info)
        return info
    stats = summary.statistics
    topics = _topics(summary.channels, summary.schemas)
    for cid, n in stats.channel_message_counts.items():
        topics[cid].count = n
    info.topics = list(topics.values())
    info.message_count = stats.message_count
    info.start_ns, info.end_ns = stats.message_start_time, stats.message_end_time
    return info


def merged_info(parts: list[BagInfo]) -> BagInfo:
    """The files' infos as one bag's: counts summed per topic, the overall time range."""
    info = BagInfo(
        [p for part in parts for p in part.files],
        sum(part.size_bytes for part in parts),
        next((part.profile for part in parts if part.profile), ""),
        [p for part in parts for p in part.unfinalized],
    )
    topics: dict[str, TopicSummary] = {}
    for part in parts:
        for t in part.topics:
            if t.name in topics:
                topics[t.name].count += t.count
            else:
                topics[t.name] = TopicSummary(
                    t.name, t.type, t.message_encoding, t.count, dict(t.metadata)
                )
    info.topics = list(topics.values())
    spans = [part for part in parts if part.message_count]
    info.message_count = sum(part.message_count for part in spans)
    if spans:
        info.start_ns = min(part.start_ns for part in spans)
        info.end_ns = max(part.end_ns for part in spans)
    return info


def bag_info(bag: str | Path) -> BagInfo:
    """Read a bag's topics, counts and time range over all its files."""
    return merged_info([file_info(path) for path in bag_files(Path(bag))])


def iso_time(ns: int) -> str:
    """A time [ns since the epoch] as ISO 8601 UTC, to the millisecond."""
    return datetime.fromtimestamp(ns / 1e9, tz=UTC).isoformat(timespec="milliseconds")


def format_info(info: BagInfo) -> str:
    """``ros2 bag info``-style text."""
    lines = [
        f"Files:      {info.files[0]}",
        *(f"            {path}" for path in info.files[1:]),
        f"Bag size:   {info.size_bytes / 2**20:.2f} MiB",
        f"Profile:    {info.profile}",
        "Finalized:  "
        + (
            "yes"
            if info.finalized
            else f"no: {', '.join(p.name for p in info.unfinalized)} (no summary; "
            "counted by scanning)"
        ),
        f"Duration:   {info.duration_s:.3f} s",
    ]
    if info.message_count:
        lines += [
            f"Start:      {iso_time(info.start_ns)} ({info.start_ns})",
            f"End:        {iso_time(info.end_ns)} ({info.end_ns})",
        ]
    lines.append(f"Messages:   {info.message_count}")
    lines.append(f"Topics:     {len(info.topics)}")
    width = max((len(t.name) for t in info.topics), default=0)
    type_width = max((len(t.type) for t in info.topics), default=0)
    for t in sorted(info.topics, key=lambda t: t.name):
        lines.append(
            f"  {t.name:<{width}}  {t.type:<{type_width}}  {t.count:>7}  {t.message_encoding}"
        )
    return "\n".join(lines)
