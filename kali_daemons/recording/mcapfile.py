"""An MCAP file written in batches (``recorder``): the servo ticks of a drain laid out as one
block of message records by numpy, every other record through ``mcap.records``.

mcap's ``Writer`` builds each message as a Python object and writes its fields one by one
(about 14 µs a message here); a recording of four arms at 1 kHz adds 12 000 a second.  The
recorder's messages of a tick never change their layout, so a drain's ticks are one array,
a row per tick (``TickBlock``), whose stamps, ticks and values are gathered into it at once,
and the message index entries are computed the same way.  The file is what ``Writer`` writes
(https://mcap.dev/spec): chunks compressed with zstd with their message indexes, and a
summary with the schemas, channels, statistics, chunk and metadata indexes.
"""

from __future__ import annotations

import struct
import zlib
from collections.abc import Sequence
from dataclasses import dataclass
from typing import BinaryIO

import numpy as np
import zstandard
from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import (
    Channel,
    Chunk,
    ChunkIndex,
    DataEnd,
    Footer,
    Header,
    McapRecord,
    Metadata,
    MetadataIndex,
    Schema,
    Statistics,
    SummaryOffset,
)

MAGIC = b"\x89MCAP0\r\n"
CHUNK_BYTES = 1 << 20  # a chunk is closed (compressed, written) once this much is in it
ZSTD_LEVEL = -1  # a fast level: the file is compressed as it is made, on a share of a core
# a message record's head: opcode, record length, channel id, sequence, log time, publish time
MESSAGE_HEAD = struct.Struct("<BQHIQQ")
LOG_TIME_AT, PUBLISH_TIME_AT = 15, 23  # offsets in a message record
# a message index entry: log time and offset, two little-endian uint64 (a row of an (n, 2)
# array: concatenated without a structured dtype's cost)
INDEX_ENTRY = np.dtype("<u8")


@dataclass(frozen=True)
class Field:
    """A value a tick block fills in each message: ``kind`` "time" (the stamp's sec and
    nanosec, and the record's two times), "tick" (an int64) or a flight-row column's values
    (``column``, taken at ``index``: a joint span or a robot's number)."""

    at: int  # the offset in a row of the block
    kind: str
    column: str = ""
    index: slice | int = 0
    count: int = 0


class TickBlock:
    """Every message of one servo tick, laid out once as a row of bytes: ``add`` appends a
    message (its channel and its CDR payload with the offsets of what changes each tick),
    ``fill`` writes ``n`` ticks' values into the first ``n`` rows."""

    def __init__(self) -> None:
        self._row = bytearray()
        self.channels: list[int] = []
        self.starts: list[int] = []  # each message's offset in a row
        self.offsets = np.zeros(0, np.uint64)  # the same, as the index entries want them
        self.fields: list[Field] = []
        self.block = np.zeros((0, 0), np.uint8)
        self._words: list[np.ndarray] = []  # the block as 8-byte words at each byte phase
        # the plan of ``fill`` for a flight row's layout: the row, its single-precision
        # columns (widened for the messages), the gathers
        self._plan_of: tuple[np.dtype, list[str], list[tuple[int, np.ndarray, np.ndarray]]] | None
        self._plan_of = None

    def add(
        self,
        channel: int,
        payload: bytes,
        tick_at: int,
        values: list[tuple[str, int, int]],
        index: slice | int,
    ) -> None:
        """A message on ``channel``: ``payload`` (CDR, its header's stamp at bytes 4..12),
        its tick at ``tick_at`` (-1: none) and ``values`` (flight-row column, offset, count)
        taken at ``index`` of each row."""
        start = len(self._row)
        self._row += MESSAGE_HEAD.pack(Opcode.MESSAGE, 22 + len(payload), channel, 0, 0, 0)
        body = len(self._row)
        self._row += payload
        self.channels.append(channel)
        self.starts.append(start)
        self.offsets = np.array(self.starts, np.uint64)
        self.fields.append(Field(start, "time"))
        if tick_at >= 0:
            self.fields.append(Field(body + tick_at, "tick"))
        for column, at, count in values:
            self.fields.append(Field(body + at, "values", column, index, count))

    @property
    def width(self) -> int:
        return len(self._row)

    def _rows(self, n: int) -> np.ndarray:
        """The block with at least ``n`` rows, each a copy of the laid-out row."""
        if self.block.shape[0] < n or self.block.shape[1] != self.width:
            rows = max(n, 2 * self.block.shape[0], 16)
            self.block = np.tile(np.frombuffer(bytes(self._row), np.uint8), (rows, 1))
            self._words = [
                np.ndarray((rows, (self.width - p) // 8), "<u8", self.block, p, (self.width, 8))
                for p in range(8)
            ]
        return self.block

    def _plan(self, row: np.dtype) -> list[tuple[int, np.ndarray, np.ndarray]]:
        """Where each 8-byte value of a block row comes from, as one gather per byte phase:
        (phase, the block's words at that phase, the source words).  The sources (``fill``)
        are a flight row's words, then its single-precision columns widened, then the log
        time and the stamp (sec, nanosec).  Made once for a flight row's layout."""
        if self._plan_of is not None and self._plan_of[0] == row:
            return self._plan_of[2]
        fields = row.fields
        assert fields is not None and row.itemsize % 8 == 0, f"a flight row of {row}"
        source = {c: fields[c][1] // 8 for c in fields}  # each column's first source word
        narrow = [c for c in fields if fields[c][0].base == np.float32]
        at = row.itemsize // 8
        for c in narrow:
            source[c], at = at, at + fields[c][0].shape[0]
        pairs: list[tuple[int, int]] = []  # (byte offset in a block row, source word)
        for f in self.fields:
            if f.kind == "time":
                body = f.at + MESSAGE_HEAD.size
                pairs += [
                    (f.at + LOG_TIME_AT, at),
                    (f.at + PUBLISH_TIME_AT, at),
                    (body + 4, at + 1),
                ]
            elif f.kind == "tick":
                pairs.append((f.at, source["tick"]))
            else:
                shape = fields[f.column][0].shape  # (joints,) or (robots, values)
                first = f.index.start if isinstance(f.index, slice) else f.index * shape[-1]
                pairs += [(f.at + 8 * e, source[f.column] + first + e) for e in range(f.count)]
        plan = []
        for p in range(8):
            mine = [(b // 8, w) for b, w in pairs if b % 8 == p]
            if mine:
                plan.append((p, np.array([b for b, _ in mine]), np.array([w for _, w in mine])))
        self._plan_of = (row, narrow, plan)
        return plan

    def fill(self, rows: np.ndarray, times: np.ndarray) -> np.ndarray:
        """The first ``len(rows)`` rows of the block, filled from flight rows ``rows`` at
        log times ``times`` (ns): every 8-byte value (the times, the ticks, the values) by
        one gather for each byte phase it has in a row (``_plan``)."""
        n = len(rows)
        block = self._rows(n)
        plan = self._plan(rows.dtype)
        words = rows.dtype.itemsize // 8
        assert self._plan_of is not None
        narrow = [rows[c].astype("<f8") for c in self._plan_of[1]]
        at = words + sum(c.shape[1] for c in narrow)
        src = np.empty((n, at + 2), "<u8")
        src[:, :words] = np.ascontiguousarray(rows).view("<u8").reshape(n, words)
        if narrow:
            src[:, words:at] = np.concatenate(narrow, axis=1).view("<u8")
        src[:, at] = times
        src[:, at + 1] = times // 1_000_000_000 + ((times % 1_000_000_000) << 32)
        for p, dst, source in plan:
            self._words[p][:n, dst] = src[:, source]
        return block[:n]


class McapFile:
    """An MCAP file on ``stream``: schemas, channels and metadata registered first, then
    messages one at a time (``message``) or a tick block at a time (``ticks``); ``finish``
    writes the summary.  Chunks are zstd-compressed, CRCs written as mcap's ``Writer`` does."""

    def __init__(self, stream: BinaryIO, profile: str, library: str) -> None:
        self.stream = stream
        self._zstd = zstandard.ZstdCompressor(level=ZSTD_LEVEL)
        self.schemas: list[Schema] = []
        self.channels: list[Channel] = []
        self._metadata: list[MetadataIndex] = []
        self._chunks: list[ChunkIndex] = []
        self._pieces: list[bytes] = []  # the open chunk
        self._size = 0  # its bytes
        # its message index entries: each tick block's (a column per channel), and each
        # single message's (channel, log time, offset)
        self._blocks: list[tuple[TickBlock, np.ndarray]] = []
        self._singles: list[tuple[int, int, int]] = []
        self._start = self._end = -1  # its messages' log times
        self.counts: dict[int, int] = {}  # messages per channel, in the whole file
        self.first = self.last = -1  # log times of the whole file
        self.chunk_count = 0
        stream.write(MAGIC)
        self._write_record(Header(profile, library))

    def _write_record(self, record: Header | DataEnd | Metadata) -> int:
        """Write ``record`` outside a chunk; its length."""
        builder = RecordBuilder()
        record.write(builder)
        data = builder.end()
        self.stream.write(data)
        return len(data)

    def _in_chunk(self, data: bytes) -> None:
        self._pieces.append(data)
        self._size += len(data)

    def schema(self, name: str, encoding: str, data: bytes) -> int:
        """Register a schema (in the chunk and the summary); its id."""
        schema = Schema(id=len(self.schemas) + 1, data=data, encoding=encoding, name=name)
        self.schemas.append(schema)
        builder = RecordBuilder()
        schema.write(builder)
        self._in_chunk(builder.end())
        return schema.id

    def channel(self, topic: str, encoding: str, schema_id: int) -> int:
        """Register a channel (in the chunk and the summary); its id."""
        channel = Channel(
            id=len(self.channels) + 1,
            topic=topic,
            message_encoding=encoding,
            metadata={},
            schema_id=schema_id,
        )
        self.channels.append(channel)
        builder = RecordBuilder()
        channel.write(builder)
        self._in_chunk(builder.end())
        self.counts[channel.id] = 0
        return channel.id

    def metadata(self, name: str, data: dict[str, str]) -> None:
        """A metadata record (outside chunks), indexed in the summary."""
        self._close_chunk()
        offset = self.stream.tell()
        length = self._write_record(Metadata(name=name, metadata=data))
        self._metadata.append(MetadataIndex(offset=offset, length=length, name=name))

    def _times(self, first: int, last: int) -> None:
        self._start = first if self._start < 0 else min(self._start, first)
        self._end = max(self._end, last)
        self.first = first if self.first < 0 else min(self.first, first)
        self.last = max(self.last, last)

    def message(self, channel: int, log_time: int, data: bytes, publish_time: int) -> None:
        """One message into the open chunk."""
        self._singles.append((channel, log_time, self._size))
        self._in_chunk(
            MESSAGE_HEAD.pack(Opcode.MESSAGE, 22 + len(data), channel, 0, log_time, publish_time)
            + data
        )
        self.counts[channel] += 1
        self._times(log_time, log_time)
        self._maybe_close()

    def ticks(self, block: TickBlock, rows: np.ndarray, times: np.ndarray) -> None:
        """Every message of ``block`` for each of ``rows`` (flight rows) at ``times``, in
        tick order, into the open chunk."""
        n = len(rows)
        if n == 0:
            return
        filled = block.fill(rows, times)
        entries = np.empty((n, len(block.channels), 2), INDEX_ENTRY)  # every channel's
        entries[:, :, 0] = times[:, None]
        base = self._size + np.arange(n, dtype=np.uint64) * np.uint64(block.width)
        entries[:, :, 1] = base[:, None] + block.offsets
        self._blocks.append((block, entries))
        for channel in block.channels:
            self.counts[channel] += n
        self._in_chunk(filled.tobytes())
        self._times(int(times[0]), int(times[-1]))
        self._maybe_close()

    def _maybe_close(self) -> None:
        if self._size >= CHUNK_BYTES:
            self._close_chunk()

    def _index(self) -> dict[int, np.ndarray]:
        """The open chunk's message index entries, by channel, in offset order: the tick
        blocks' (a column per channel) and the single messages', each already in offset
        order (a channel with both is sorted)."""
        parts: dict[int, list[np.ndarray]] = {}
        by_block: dict[int, tuple[TickBlock, list[np.ndarray]]] = {}
        for block, entries in self._blocks:
            by_block.setdefault(id(block), (block, []))[1].append(entries)
        for block, pieces in by_block.values():
            entries = np.concatenate(pieces)
            for j, channel in enumerate(block.channels):
                parts.setdefault(channel, []).append(entries[:, j, :])
        if self._singles:
            singles = np.array(self._singles, INDEX_ENTRY)
            for channel in np.unique(singles[:, 0]):
                parts.setdefault(int(channel), []).append(singles[singles[:, 0] == channel, 1:])
        index = {}
        for channel, pieces in parts.items():
            if len(pieces) == 1:
                index[channel] = pieces[0]
            else:
                entries = np.concatenate(pieces)
                index[channel] = entries[np.argsort(entries[:, 1], kind="stable")]
        return index

    def _close_chunk(self) -> None:
        """Compress the open chunk and write it, then its message indexes."""
        if not self._blocks and not self._singles and not self._pieces:
            return
        data = b"".join(self._pieces)
        compressed = self._zstd.compress(data)
        start = max(self._start, 0)
        chunk = Chunk(
            compression="zstd",
            data=compressed,
            message_start_time=start,
            message_end_time=max(self._end, 0),
            uncompressed_crc=zlib.crc32(data),
            uncompressed_size=len(data),
        )
        builder = RecordBuilder()
        chunk.write(builder)
        chunk_bytes = builder.end()
        chunk_at = self.stream.tell()
        self.stream.write(chunk_bytes)
        offsets: dict[int, int] = {}
        indexes = bytearray()
        index_at = chunk_at + len(chunk_bytes)
        for channel, index in sorted(self._index().items()):
            entries = index.tobytes()
            offsets[channel] = index_at + len(indexes)
            indexes += struct.pack(
                "<BQHI", Opcode.MESSAGE_INDEX, 6 + len(entries), channel, len(entries)
            )
            indexes += entries
        self.stream.write(indexes)
        self._chunks.append(
            ChunkIndex(
                message_start_time=start,
                message_end_time=max(self._end, 0),
                chunk_start_offset=chunk_at,
                chunk_length=len(chunk_bytes),
                message_index_offsets=offsets,
                message_index_length=len(indexes),
                compression="zstd",
                compressed_size=len(compressed),
                uncompressed_size=len(data),
            )
        )
        self.chunk_count += 1
        self._pieces, self._size, self._blocks, self._singles = [], 0, [], []
        self._start = self._end = -1

    def finish(self) -> None:
        """The last chunk, the data end and the summary: the file is whole."""
        self._close_chunk()
        self._write_record(DataEnd(0))
        summary_start = self.stream.tell()
        builder = RecordBuilder()
        offsets: list[SummaryOffset] = []
        stats = Statistics(
            attachment_count=0,
            channel_count=len(self.channels),
            channel_message_counts=dict(self.counts),
            chunk_count=self.chunk_count,
            message_count=sum(self.counts.values()),
            message_end_time=max(self.last, 0),
            message_start_time=max(self.first, 0),
            metadata_count=len(self._metadata),
            schema_count=len(self.schemas),
        )
        groups: tuple[tuple[Opcode, Sequence[McapRecord]], ...] = (
            (Opcode.SCHEMA, self.schemas),
            (Opcode.CHANNEL, self.channels),
            (Opcode.STATISTICS, [stats]),
            (Opcode.CHUNK_INDEX, self._chunks),
            (Opcode.ATTACHMENT_INDEX, []),
            (Opcode.METADATA_INDEX, self._metadata),
        )
        for opcode, records in groups:
            at = builder.count
            for record in records:
                record.write(builder)
            offsets.append(SummaryOffset(opcode, summary_start + at, builder.count - at))
        offset_start = summary_start + builder.count
        for offset in offsets:
            offset.write(builder)
        summary = builder.end()
        crc = zlib.crc32(summary)
        crc = zlib.crc32(struct.pack("<BQQQ", Opcode.FOOTER, 20, summary_start, offset_start), crc)
        self.stream.write(summary)
        builder = RecordBuilder()
        Footer(summary_start, offset_start, crc).write(builder)
        self.stream.write(builder.end())
        self.stream.write(MAGIC)
