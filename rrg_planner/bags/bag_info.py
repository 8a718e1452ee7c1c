"""What a bag holds: its MCAP file, topics, types, message counts and time range, read from
the file's summary or, for a bag whose recorder was killed before writing it, by scanning its
complete records."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path

from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Channel, Message, Schema
from mcap.stream_reader import StreamReader


@dataclass
class TopicSummary:
    name: str
    type: str  # schema name, pkg/msg/Type
    message_encoding: str
    count: int = 0


@dataclass
class BagInfo:
    """What ``info`` prints: one MCAP file's topics, counts and time range [ns since the epoch]."""

    mcap_path: Path
    size_bytes: int
    profile: str
    finalized: bool  # the file has its summary section and footer
    message_count: int = 0
    start_ns: int = 0
    end_ns: int = 0
    topics: list[TopicSummary] = field(default_factory=list)

    @property
    def duration_s(self) -> float:
        return (self.end_ns - self.start_ns) / 1e9 if self.message_count else 0.0


def find_mcap(bag: Path) -> Path:
    """The bag's MCAP file: ``bag`` itself, or ``<bag>/<bag>_0.mcap`` (else the
    folder's only one)."""
    if bag.is_file():
        return bag
    if not bag.is_dir():
        raise FileNotFoundError(f"no bag at {bag}")
    standard = bag / f"{bag.name}_0.mcap"
    if standard.is_file():
        return standard
    found = sorted(bag.glob("*.mcap"))
    if len(found) != 1:
        raise FileNotFoundError(f"expected one .mcap file in {bag}, found {len(found)}")
    return found[0]


def _topics(channels: dict[int, Channel], schemas: dict[int, Schema]) -> dict[int, TopicSummary]:
    return {
        cid: TopicSummary(
            c.topic, schemas[c.schema_id].name if c.schema_id in schemas else "", c.message_encoding
        )
        for cid, c in channels.items()
    }


def complete_records(path: Path) -> Iterator[object]:
    """Every MCAP record of a file in order, stopping quietly where a truncated file ends
    (a recorder killed before writing its summary leaves such a file)."""
    with path.open("rb") as f:
        try:
            yield from StreamReader(f).records
        except (McapError, ValueError, EOFError):
            return  # truncated: keep what was complete


def _scan(path: Path, info: BagInfo) -> None:
    """Count messages by reading every complete record."""
    channels: dict[int, Channel] = {}
    schemas: dict[int, Schema] = {}
    counts: dict[int, int] = {}
    times: list[int] = []
    for record in complete_records(path):
        if isinstance(record, Schema):
            schemas[record.id] = record
        elif isinstance(record, Channel):
            channels[record.id] = record
        elif isinstance(record, Message):
            counts[record.channel_id] = counts.get(record.channel_id, 0) + 1
            times.append(record.log_time)
    topics = _topics(channels, schemas)
    for cid, n in counts.items():
        topics[cid].count = n
    info.topics = list(topics.values())
    info.message_count = len(times)
    if times:
        info.start_ns, info.end_ns = min(times), max(times)


def bag_info(bag: str | Path) -> BagInfo:
    """Read a bag's topics, counts and time range, from its summary when it has one."""
    path = find_mcap(Path(bag))
    with path.open("rb") as f:
        reader = make_reader(f)
        profile = reader.get_header().profile
        try:
            summary = reader.get_summary()
        except (McapError, ValueError, EOFError):
            summary = None
    info = BagInfo(path, path.stat().st_size, profile, finalized=summary is not None)
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


def _time(ns: int) -> str:
    return datetime.fromtimestamp(ns / 1e9, tz=UTC).isoformat(timespec="milliseconds")


def format_info(info: BagInfo) -> str:
    """``ros2 bag info``-style text."""
    lines = [
        f"Files:      {info.mcap_path}",
        f"Bag size:   {info.size_bytes / 2**20:.2f} MiB",
        f"Profile:    {info.profile}",
        f"Finalized:  {'yes' if info.finalized else 'no (no summary/footer; counted by scanning)'}",
        f"Duration:   {info.duration_s:.3f} s",
    ]
    if info.message_count:
        lines += [
            f"Start:      {_time(info.start_ns)} ({info.start_ns})",
            f"End:        {_time(info.end_ns)} ({info.end_ns})",
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
