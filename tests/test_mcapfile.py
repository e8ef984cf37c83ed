"""The recorder's MCAP writer (``recording.mcapfile``) against independent readers: the
``mcap`` package's (its CRCs checked, its summary read, each message decoded as ROS 2) and
``rosbags``: ticks written a block at a time read back as the messages mcap's own ``Writer``
would have written, one at a time."""

from __future__ import annotations

import io
import struct
from pathlib import Path

import numpy as np
import pytest
import zstandard
from mcap import records
from mcap.opcode import Opcode
from mcap.reader import make_reader
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, Writer
from mcap_ros2.decoder import DecoderFactory

from kali_daemons.core import layout
from kali_daemons.recording import mcapfile
from kali_daemons.recording.mcapfile import McapFile, TickBlock
from kali_daemons.recording.messages import (
    GAP_DEF,
    JOINT_STATE_DEF,
    SERVO_DEF,
    WRENCH_DEF,
    Cdr,
    Laid,
)

N_ROBOTS, N = 2, 3  # two arms of three joints
ROW = layout.flight_row(N_ROBOTS * N, N_ROBOTS)
COLUMNS = ("q", "qd", "torque")


def rows(first_tick: int, count: int, rng: np.random.Generator) -> np.ndarray:
    """``count`` flight rows from ``first_tick`` with random values."""
    out = np.zeros(count, ROW)
    out["tick"] = np.arange(first_tick, first_tick + count)
    for f in ("q", "qd", "torque", "demand", "servo_torque"):
        out[f] = rng.normal(size=out[f].shape)
    out["shadow_torque"] = rng.normal(size=out["shadow_torque"].shape).astype(np.float32)
    out["wrench"] = rng.normal(size=out["wrench"].shape)
    return out


def arm_messages(c: Cdr, k: int) -> list[tuple[str, bytes, int, list[tuple[str, int, int]]]]:
    """Arm ``k``'s joint state (q, qd, torque), a servo message (tick, demand, servo torque,
    shadow torque) and its wrench, laid out as the recorder lays them out."""
    zeros, out = np.zeros(N), []
    c.reset()
    c.header(0)
    c.strings([f"a{k}_joint{j}".encode() for j in range(N)])
    cols = [(col, c.float64s(zeros), N) for col in COLUMNS]
    out.append(("joints", c.bytes(), -1, cols))
    c.reset()
    c.header(0)
    tick_at = c.int64(0)
    cols = [(col, c.float64s(zeros), N) for col in ("demand", "servo_torque", "shadow_torque")]
    out.append(("servo", c.bytes(), tick_at, cols))
    c.reset()
    c.header(0, f"a{k}_tool".encode())
    at = c.float64_fixed(np.zeros(6))
    out.append(("wrench", c.bytes(), -1, [("wrench", at, 6)]))
    return out


SCHEMAS = (
    ("joints", "sensor_msgs/msg/JointState", JOINT_STATE_DEF),
    ("servo", "kali_msgs/msg/Test", SERVO_DEF.split("\n", 1)[0] + "\nint64 tick\n"
     "float64[] demand\nfloat64[] servo_torque\nfloat64[] shadow_torque\n"
     + SERVO_DEF[SERVO_DEF.index("=====") :]),
    ("wrench", "geometry_msgs/msg/WrenchStamped", WRENCH_DEF),
    ("gap", "kali_msgs/msg/Gap", GAP_DEF),
)  # fmt: skip


def rosbags_positions(path: Path, topic: str) -> tuple[list[np.ndarray], int]:
    """Each ``sensor_msgs/msg/JointState``'s positions on ``topic`` as ``rosbags`` (an
    independent reader of ROS 2 recordings, no mcap package) decodes them, and the number of
    messages in the file."""
    from rosbags.highlevel import AnyReader

    with AnyReader([path]) as reader:
        states = [c for c in reader.connections if c.topic == topic]
        assert states and states[0].msgtype == "sensor_msgs/msg/JointState"
        positions = [
            reader.deserialize(raw, c.msgtype).position
            for c, _t, raw in reader.messages(connections=states)
        ]
        return positions, reader.message_count


def write(stream: io.BytesIO | Path, batches: list[np.ndarray]) -> dict[str, int]:
    """A file with the schemas, a channel per arm and kind, the batches as tick blocks and
    a gap message between each two; the channels' ids by topic."""
    out = stream if isinstance(stream, io.BytesIO) else open(stream, "wb")  # noqa: SIM115
    f = McapFile(out, "ros2", "kali-test")
    f.metadata("kali", {"instance": "test"})
    schemas = {kind: f.schema(name, "ros2msg", text.encode()) for kind, name, text in SCHEMAS}
    block, c, topics = TickBlock(), Cdr(), {}
    for k in range(N_ROBOTS):
        span = slice(k * N, (k + 1) * N)
        for kind, payload, tick_at, cols in arm_messages(c, k):
            topic = f"/a{k}/{kind}"
            topics[topic] = f.channel(topic, "cdr", schemas[kind])
            block.add(topics[topic], payload, tick_at, cols, k if kind == "wrench" else span)
    topics["/gaps"] = f.channel("/gaps", "cdr", schemas["gap"])
    for batch in batches:
        f.ticks(block, batch, batch["tick"] * 1_000_000)
        t = int(batch["tick"][-1]) * 1_000_000
        c.reset()
        c.header(t)
        c.int64(int(batch["tick"][-1]))
        c.int64(0)
        f.message(topics["/gaps"], t, c.bytes(), t)
    f.finish()
    if not isinstance(stream, io.BytesIO):
        out.close()
    return topics


@pytest.mark.parametrize("chunk_bytes", [1 << 20, 3000])  # one chunk; a block fills one
def test_tick_blocks_read_back_whole_by_the_mcap_reader(
    monkeypatch: pytest.MonkeyPatch, chunk_bytes: int
) -> None:
    monkeypatch.setattr(mcapfile, "CHUNK_BYTES", chunk_bytes)
    rng = np.random.default_rng(7)
    batches = [rows(100, 7, rng), rows(107, 1, rng), rows(108, 30, rng), rows(138, 12, rng)]
    every = np.concatenate(batches)
    buf = io.BytesIO()
    topics = write(buf, batches)
    buf.seek(0)
    reader = make_reader(buf, decoder_factories=[DecoderFactory()], validate_crcs=True)
    summary = reader.get_summary()
    assert summary is not None and summary.statistics is not None
    stats = summary.statistics
    assert stats.message_count == 3 * N_ROBOTS * len(every) + len(batches)
    assert stats.message_start_time == 100 * 1_000_000
    assert stats.message_end_time == 149 * 1_000_000
    assert stats.chunk_count == len(summary.chunk_indexes) == (1 if chunk_bytes > 5000 else 4)
    assert {c.topic for c in summary.channels.values()} == set(topics)
    assert [m.name for m in reader.iter_metadata()] == ["kali"]
    seen: dict[str, list] = {}
    for _schema, channel, message, msg in reader.iter_decoded_messages(log_time_order=True):
        seen.setdefault(channel.topic, []).append((message.log_time, msg))
    for k in range(N_ROBOTS):
        span = slice(k * N, (k + 1) * N)
        joints, servo, wrench = (seen[f"/a{k}/{kind}"] for kind in ("joints", "servo", "wrench"))
        assert len(joints) == len(servo) == len(wrench) == len(every)
        for row, (t, j), (_, s), (_, w) in zip(every, joints, servo, wrench, strict=True):
            assert t == int(row["tick"]) * 1_000_000
            assert j.header.stamp.sec * 1_000_000_000 + j.header.stamp.nanosec == t
            assert list(j.name) == [f"a{k}_joint{i}" for i in range(N)]
            for col in COLUMNS:
                np.testing.assert_array_equal(getattr(j, {"q": "position", "qd": "velocity",
                                                          "torque": "effort"}[col]),
                                              row[col][span])  # fmt: skip
            assert s.tick == int(row["tick"])
            np.testing.assert_array_equal(s.demand, row["demand"][span])
            np.testing.assert_array_equal(s.shadow_torque, row["shadow_torque"][span])
            assert w.header.frame_id == f"a{k}_tool"
            force, torque = w.wrench.force, w.wrench.torque
            np.testing.assert_array_equal(
                [force.x, force.y, force.z, torque.x, torque.y, torque.z], row["wrench"][k]
            )
    assert [m.first_tick for _, m in seen["/gaps"]] == [106, 107, 137, 149]


def test_the_file_is_the_bytes_of_what_mcaps_writer_writes_a_message_at_a_time() -> None:
    """Every message's bytes are those mcap's ``Writer`` would hold for them, message by
    message (the reference: ``Cdr`` encoded each time, no template)."""
    rng = np.random.default_rng(3)
    batch = rows(5, 4, rng)
    buf = io.BytesIO()
    write(buf, [batch])
    ref = io.BytesIO()
    w = Writer(ref, compression=CompressionType.NONE)
    w.start(profile="ros2", library="ref")
    schema = w.register_schema("sensor_msgs/msg/JointState", "ros2msg", JOINT_STATE_DEF.encode())
    ch = w.register_channel("/a1/joints", "cdr", schema)
    c = Cdr()
    for row in batch:
        t = int(row["tick"]) * 1_000_000
        c.reset()
        c.header(t)
        c.strings([f"a1_joint{j}".encode() for j in range(N)])
        for col in COLUMNS:
            c.float64s(row[col][N : 2 * N])
        w.add_message(ch, t, c.bytes(), t)
    w.finish()
    for out in (buf, ref):
        out.seek(0)
    ours = [m.data for _, ch_, m in make_reader(buf).iter_messages(topics=["/a1/joints"])]
    theirs = [m.data for _, ch_, m in make_reader(ref).iter_messages()]
    assert ours == theirs


def test_rosbags_reads_the_file(tmp_path: Path) -> None:
    """``rosbags`` (no Kali, no mcap package) finds every topic and message type and
    decodes each joint state."""
    rng = np.random.default_rng(11)
    batches = [rows(0, 20, rng), rows(20, 5, rng)]
    path = tmp_path / "run.mcap"
    write(path, batches)
    every = np.concatenate(batches)
    q, count = rosbags_positions(path, "/a0/joints")
    assert count == 3 * N_ROBOTS * len(every) + len(batches)
    np.testing.assert_array_equal(np.array(q), every["q"][:, :N])


def test_a_laid_message_refilled_is_the_message_encoded_anew() -> None:
    """``Laid`` (the set-points' and the truth's messages, laid out once and refilled each
    drain) gives the bytes ``Cdr`` encodes field by field, for any values."""
    rng = np.random.default_rng(7)
    c = Cdr()
    c.header(0)
    at = [(c.int64(0), "<i8", 1), (c.float64(0.0), "<f8", 1), (c.uint64(0), "<u8", 1)]
    at += [(c.float64s(np.zeros(6)), "<f8", 6), (c.float64_fixed(np.zeros(6)), "<f8", 6)]
    at.append((c.uint8(0), "u1", 1))
    laid = Laid(c)
    views = [laid.field(*a) for a in at]
    for _ in range(3):
        ns, tick, sim, ticks = 1_234_567_890_123, 4567, 1.25, 2**40 + 3
        q, wrench, flag = rng.normal(size=6), rng.normal(size=6), int(rng.integers(0, 2))
        laid.stamp(ns)
        for view, value in zip(views, (tick, sim, ticks, q, wrench, flag), strict=True):
            view[:] = value
        c.reset()
        c.header(ns)
        c.int64(tick)
        c.float64(sim)
        c.uint64(ticks)
        c.float64s(q)
        c.float64_fixed(wrench)
        c.uint8(flag)
        assert laid.bytes() == c.bytes()


@pytest.mark.parametrize("chunk_bytes", [1 << 20, 3000])
def test_every_message_index_entry_points_at_its_message(
    monkeypatch: pytest.MonkeyPatch, chunk_bytes: int
) -> None:
    """Each chunk's message indexes (what a reader seeks by) list every message of the chunk
    on their channel, in offset order, each entry's offset at a message record of that
    channel and log time: the tick blocks' entries and the single messages' alike."""
    monkeypatch.setattr(mcapfile, "CHUNK_BYTES", chunk_bytes)
    rng = np.random.default_rng(5)
    buf = io.BytesIO()
    write(buf, [rows(10, 9, rng), rows(19, 3, rng), rows(22, 25, rng)])
    buf.seek(0)
    chunk, checked = None, 0
    counted: dict[int, int] = {}
    for record in StreamReader(buf, emit_chunks=True).records:
        if isinstance(record, records.Chunk):
            chunk = zstandard.ZstdDecompressor().decompress(
                record.data, max_output_size=record.uncompressed_size
            )
            in_chunk: dict[int, int] = {}
            at = 0
            while at < len(chunk):  # every message record of the chunk, by channel
                opcode, length = struct.unpack_from("<BQ", chunk, at)
                if opcode == Opcode.MESSAGE:
                    channel = struct.unpack_from("<H", chunk, at + 9)[0]
                    in_chunk[channel] = in_chunk.get(channel, 0) + 1
                at += 9 + length
        elif isinstance(record, records.MessageIndex):
            assert chunk is not None
            offsets = [offset for _, offset in record.records]
            assert offsets == sorted(offsets) and len(offsets) == in_chunk[record.channel_id]
            for log_time, offset in record.records:
                opcode, _, channel, _, log = struct.unpack_from("<BQHIQ", chunk, offset)
                assert (opcode, channel, log) == (Opcode.MESSAGE, record.channel_id, log_time)
                checked += 1
            counted[record.channel_id] = counted.get(record.channel_id, 0) + len(offsets)
    assert checked == 3 * N_ROBOTS * 37 + 3 and sum(counted.values()) == checked
