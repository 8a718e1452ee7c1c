"""Close an MCAP file whose writer could not finish it (a write failed: the disk
filled), operations §8.

The file is cut after its last complete record (what the writer last wrote in full: a chunk and
its message indexes), then closed as far as the space allows: with the summary that makes it a
finalized file (schemas, channels, statistics, chunk and metadata indexes, as the mcap writer
writes them), else with the footer alone (a valid MCAP file without an index: readers scan it),
else not at all (readers scan it up to where it ends). Every reader then finds exactly the
complete messages before the cut.
"""

from __future__ import annotations

import struct
import zlib
from collections.abc import Iterator
from io import BytesIO
from pathlib import Path
from typing import BinaryIO

from mcap.data_stream import ReadDataStream, RecordBuilder
from mcap.opcode import Opcode
from mcap.records import (
    Channel,
    Chunk,
    ChunkIndex,
    DataEnd,
    Footer,
    McapRecord,
    Message,
    Metadata,
    MetadataIndex,
    Schema,
    Statistics,
    SummaryOffset,
)
from mcap.stream_reader import MAGIC_SIZE, breakup_chunk
from mcap.writer import MCAP0_MAGIC

from rrg_bags.bag_info import TRUNCATED

#: How far ``finalize_in_place`` closed a file.
SUMMARY = "summary"  # finalized: summary section, footer and magic
FOOTER = "footer"  # footer and magic, no summary: readers scan the data section
CUT = "cut"  # cut after its last complete record only: readers scan up to the end

RECORD_PREFIX = 9  # opcode (1 byte) and content length (8 bytes)


def write_all(file: BinaryIO, data: bytes) -> None:
    """Write all of ``data`` to an unbuffered file, whose ``write`` may write only part."""
    view = memoryview(data)
    while view:
        written = file.write(view)
        if not written:
            raise OSError(f"wrote nothing of {len(view)} bytes")
        view = view[written:]


def data_records(path: Path, end: int) -> Iterator[tuple[int, int, bytes]]:
    """(offset, opcode, content) of each complete record of the file that ends by ``end``."""
    with path.open("rb") as f:
        f.seek(MAGIC_SIZE)
        offset = MAGIC_SIZE
        while offset + RECORD_PREFIX <= end:
            opcode, length = struct.unpack("<BQ", f.read(RECORD_PREFIX))
            if offset + RECORD_PREFIX + length > end:
                return
            yield offset, opcode, f.read(length)
            offset += RECORD_PREFIX + length


def summary_tail(path: Path, end: int) -> bytes:
    """What closes the file cut at ``end`` as a finalized one: DataEnd, the summary of the
    records before ``end``, the summary offsets, the footer and the closing magic."""
    return closing_records(end, *summarize(path, end))


def summarize(path: Path, end: int):
    """(schemas, channels, chunk indexes, metadata indexes, statistics) of the records before
    ``end``."""
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    chunks: list[ChunkIndex] = []
    metadata: list[MetadataIndex] = []
    stats = Statistics(
        attachment_count=0,
        channel_count=0,
        channel_message_counts={},
        chunk_count=0,
        message_count=0,
        message_end_time=0,
        message_start_time=0,
        metadata_count=0,
        schema_count=0,
    )

    def add(record: McapRecord) -> None:
        if isinstance(record, Schema):
            schemas[record.id] = record
        elif isinstance(record, Channel):
            channels[record.id] = record
        elif isinstance(record, Message):
            first = stats.message_count == 0
            stats.message_start_time = (
                record.log_time if first else min(stats.message_start_time, record.log_time)
            )
            stats.message_end_time = max(stats.message_end_time, record.log_time)
            counts = stats.channel_message_counts
            counts[record.channel_id] = counts.get(record.channel_id, 0) + 1
            stats.message_count += 1

    chunk = None  # the index of the chunk whose message indexes follow it
    for offset, opcode, content in data_records(path, end):
        stream = ReadDataStream(BytesIO(content))
        if opcode == Opcode.MESSAGE_INDEX and chunk is not None:
            chunk.message_index_offsets[stream.read2()] = offset
            chunk.message_index_length += RECORD_PREFIX + len(content)
            continue
        chunk = None
        if opcode == Opcode.CHUNK:
            record = Chunk.read(stream)
            for inner in breakup_chunk(record):
                add(inner)
            chunk = ChunkIndex(
                chunk_length=RECORD_PREFIX + len(content),
                chunk_start_offset=offset,
                compression=record.compression,
                compressed_size=len(record.data),
                message_end_time=record.message_end_time,
                message_index_length=0,
                message_index_offsets={},
                message_start_time=record.message_start_time,
                uncompressed_size=record.uncompressed_size,
            )
            chunks.append(chunk)
        elif opcode == Opcode.METADATA:
            name = Metadata.read(stream).name
            metadata.append(MetadataIndex(offset, RECORD_PREFIX + len(content), name))
        elif opcode == Opcode.SCHEMA:
            add(Schema.read(stream))
        elif opcode == Opcode.CHANNEL:
            add(Channel.read(stream))
        elif opcode == Opcode.MESSAGE:
            add(Message.read(stream, len(content)))
    stats.schema_count, stats.channel_count = len(schemas), len(channels)
    stats.chunk_count, stats.metadata_count = len(chunks), len(metadata)
    return schemas, channels, chunks, metadata, stats


def closing_records(end: int, schemas, channels, chunks, metadata, stats) -> bytes:
    """DataEnd, the summary (the mcap writer's groups, in its order), the summary offsets, the
    footer and the closing magic of a file whose data section ends at ``end``."""
    head = RecordBuilder()
    DataEnd(data_section_crc=0).write(head)
    summary_start = end + head.count
    summary = RecordBuilder()
    offsets = []
    groups: list[tuple[Opcode, list]] = [  # the mcap writer's groups, in its order
        (Opcode.SCHEMA, list(schemas.values())),
        (Opcode.CHANNEL, list(channels.values())),
        (Opcode.STATISTICS, [stats]),
        (Opcode.CHUNK_INDEX, chunks),
        (Opcode.ATTACHMENT_INDEX, []),
        (Opcode.METADATA_INDEX, metadata),
    ]
    for opcode, records in groups:
        start = summary.count
        for record in records:
            record.write(summary)
        offsets.append(SummaryOffset(opcode, summary_start + start, summary.count - start))
    summary_offset_start = summary_start + summary.count
    for record in offsets:
        record.write(summary)
    data = summary.end()
    footer_prefix = struct.pack(
        "<BQQQ", Opcode.FOOTER, 8 + 8 + 4, summary_start, summary_offset_start
    )
    crc = zlib.crc32(footer_prefix, zlib.crc32(data))
    Footer(summary_start, summary_offset_start, crc).write(summary)
    return head.end() + data + summary.end() + MCAP0_MAGIC


def footer_tail() -> bytes:
    """What closes a file without a summary: DataEnd, a footer that names none, the magic."""
    builder = RecordBuilder()
    DataEnd(data_section_crc=0).write(builder)
    Footer(summary_start=0, summary_offset_start=0, summary_crc=0).write(builder)
    return builder.end() + MCAP0_MAGIC


def finalize_in_place(file: BinaryIO, path: Path, end: int) -> str:
    """Cut the MCAP file at ``path``, open for writing (unbuffered) as ``file``, at ``end`` (after
    its last complete record) and close it as far as the space allows; returns how far (SUMMARY,
    FOOTER or CUT). A tail that does not fit is cut off again."""
    for how, tail in ((SUMMARY, lambda: summary_tail(path, end)), (FOOTER, footer_tail)):
        try:
            file.truncate(end)
            file.seek(end)
            write_all(file, tail())
            file.flush()
            return how
        except (OSError, *TRUNCATED):
            continue
    try:
        file.truncate(end)
    except OSError:
        pass  # the readers stop at the last complete record anyway
    return CUT


def close_unfinished(path: Path) -> str:
    """Close the MCAP file of a writer that was killed (no summary, perhaps cut inside a record)
    after its last complete record, as ``finalize_in_place`` does; returns how far. A file that
    does not even hold the opening magic is left as it is (CUT): readers skip it."""
    with path.open("rb") as file:
        if file.read(MAGIC_SIZE) != MCAP0_MAGIC:
            return CUT
    end = MAGIC_SIZE
    for offset, opcode, content in data_records(path, path.stat().st_size):
        if opcode in (Opcode.DATA_END, Opcode.FOOTER):
            break
        end = offset + RECORD_PREFIX + len(content)
    with path.open("r+b", buffering=0) as file:
        return finalize_in_place(file, path, end)
