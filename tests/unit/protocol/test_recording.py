"""MCAP recordings (PROTOCOL.md, "Recordings"): written by RecordingWriter, read back by
read_recording and independently by mcap's own reader."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.writer import Writer

import protocol
from protocol import Ir, RecordingError, Status
from protocol.recording import RecordingWriter, read_recording

GOLDEN = Path(__file__).resolve().parents[2] / "data" / "golden"
NET = "demo"


def golden(name: str) -> bytes:
    return (GOLDEN / f"{name}.msgpack").read_bytes()


def topic_of(msg: protocol.Message) -> str:
    """Key expressions from the PROTOCOL.md table, written out (not via protocol.keys)."""
    node = {"node_info": "info", "ir": "ir", "detections": "det", "status": "status"}
    fusion = {"tracks": "tracks", "poses": "poses", "image": "image", "map": "map"}
    if msg.KIND in node:
        return f"uwbnet/{NET}/node/{msg.src}/{node[msg.KIND]}"
    if msg.KIND in fusion:
        return f"uwbnet/{NET}/fusion/{fusion[msg.KIND]}"
    return {"tdma_schedule": f"uwbnet/{NET}/tdma/schedule", "truth": f"uwbnet/{NET}/sim/truth"}[
        msg.KIND
    ]


def sample_messages() -> list[tuple[str, str, bytes, float]]:
    """(topic, kind, payload, t): every golden payload, then a few generated ir/status."""
    out = []
    for path in sorted(GOLDEN.glob("*.msgpack")):
        payload = path.read_bytes()
        msg = protocol.decode(payload)
        out.append((topic_of(msg), msg.KIND, payload, msg.t))
    rng = np.random.default_rng(7)
    for i in range(5):
        t = 1234.567890123 + i * 0.1  # t * 1e9 is not an integer: rounding matters
        h = rng.normal(size=(2, 16)).astype("<f4")
        ir = Ir(src="n-2", seq=i, t=t, tx="n-2/a", rx=("a", "b"), slot=1, frame=i, h=h)
        out.append((topic_of(ir), "ir", ir.to_wire(), t))
    return out


@pytest.fixture
def recording(tmp_path: Path) -> tuple[Path, list[tuple[str, str, bytes, float]]]:
    path = tmp_path / "run.mcap"
    messages = sample_messages()
    with RecordingWriter(path) as writer:
        for topic, kind, payload, t in messages:
            writer.write(topic, kind, payload, t)
        assert writer.count == len(messages)
    return path, messages


def test_read_recording_returns_every_payload(recording) -> None:
    path, messages = recording
    got = list(read_recording(path))
    assert [(m.topic, m.kind, m.payload) for m in got] == [(s, k, p) for s, k, p, _ in messages]
    for m, (_, _, _, t) in zip(got, messages, strict=True):
        assert m.log_time == round(t * 1e9)
        assert m.t == pytest.approx(t, abs=1e-9)
        assert protocol.decode(m.payload).to_wire() == m.payload


def test_mcap_reader_sees_the_contract_layout(recording) -> None:
    path, messages = recording
    with path.open("rb") as f:
        reader = make_reader(f, validate_crcs=True)
        got = list(reader.iter_messages(log_time_order=False))
        summary = reader.get_summary()
    assert summary is not None
    assert len(got) == len(messages)
    for (schema, channel, message), (topic, kind, payload, t) in zip(got, messages, strict=True):
        assert channel.topic == topic
        assert channel.message_encoding == "msgpack"
        assert schema is not None
        assert schema.name == f"uwbnet.{kind}"
        assert schema.encoding == "jsonschema"
        body = json.loads(schema.data) if schema.data else {}
        assert body.get("type", "object") == "object"
        assert message.log_time == message.publish_time == round(t * 1e9)
        assert message.data == payload
    # One channel per key expression, one schema per kind.
    assert sorted(c.topic for c in summary.channels.values()) == sorted({m[0] for m in messages})
    assert sorted(s.name for s in summary.schemas.values()) == sorted(
        {f"uwbnet.{m[1]}" for m in messages}
    )


def test_write_message_returns_the_bytes_written(tmp_path: Path) -> None:
    path = tmp_path / "one.mcap"
    status = protocol.decode(golden("status"))
    assert isinstance(status, Status)
    with RecordingWriter(path) as writer:
        written = writer.write_message("uwbnet/demo/node/anchor1/status", status)
    assert written == golden("status")
    (only,) = read_recording(path)
    assert only.payload == written and only.kind == "status"
    assert only.log_time == 110_000_000_000


def test_file_appears_only_on_close(tmp_path: Path) -> None:
    path = tmp_path / "late.mcap"
    partial = tmp_path / "late.mcap.partial"
    writer = RecordingWriter(path)
    writer.write("uwbnet/demo/node/anchor1/status", "status", golden("status"), 110.0)
    assert not path.exists()
    assert partial.exists()
    writer.close()
    assert path.exists() and not partial.exists()
    writer.close()  # idempotent
    assert len(list(read_recording(path))) == 1
    with pytest.raises(RecordingError, match="already closed"):
        writer.write("uwbnet/demo/node/anchor1/status", "status", golden("status"), 111.0)


def test_exception_inside_with_leaves_no_file(tmp_path: Path) -> None:
    path = tmp_path / "broken.mcap"

    class BoomError(Exception):
        pass

    with pytest.raises(BoomError), RecordingWriter(path) as writer:
        writer.write("uwbnet/demo/node/anchor1/status", "status", golden("status"), 110.0)
        raise BoomError
    assert sorted(tmp_path.iterdir()) == []


def test_unwritable_path_is_a_recording_error(tmp_path: Path) -> None:
    with pytest.raises(RecordingError, match="cannot write"):
        RecordingWriter(tmp_path / "no" / "such" / "dir.mcap")


def test_missing_file_is_a_recording_error(tmp_path: Path) -> None:
    with pytest.raises(RecordingError, match="cannot read") as info:
        list(read_recording(tmp_path / "missing.mcap"))
    assert "\n" not in str(info.value)


def _expect_recording_error(path: Path) -> str:
    with pytest.raises(RecordingError) as info:
        list(read_recording(path))
    assert type(info.value) is RecordingError
    message = str(info.value)
    assert "\n" not in message and str(path) in message
    return message


@pytest.mark.parametrize("fraction", [0.0, 0.001, 0.1, 0.33, 0.5, 0.77, 0.9, 0.999])
def test_truncated_copy_raises_recording_error(recording, tmp_path: Path, fraction: float) -> None:
    path, _ = recording
    data = path.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: int(len(data) * fraction)])
    message = _expect_recording_error(cut)
    assert "corrupt or truncated" in message


def test_payload_bytes_flipped_raise_recording_error(recording, tmp_path: Path) -> None:
    """Bytes flipped inside a message's data keep the MCAP well formed: only a CRC sees them."""
    path, messages = recording
    data = bytearray(path.read_bytes())
    payload = messages[len(messages) // 2][2]
    start = data.find(payload)
    assert start > 0
    for i in range(start + len(payload) // 2, start + len(payload) // 2 + 4):
        data[i] ^= 0xFF
    bad = tmp_path / "flipped.mcap"
    bad.write_bytes(bytes(data))
    _expect_recording_error(bad)


def test_one_byte_short_raises_recording_error(recording, tmp_path: Path) -> None:
    path, _ = recording
    cut = tmp_path / "short.mcap"
    cut.write_bytes(path.read_bytes()[:-1])
    _expect_recording_error(cut)


@pytest.mark.parametrize("where", [0.3, 0.5, 0.6])
def test_corrupt_copy_raises_recording_error(recording, tmp_path: Path, where: float) -> None:
    """Bytes flipped in the middle (inside the message data) must not pass as good payloads."""
    path, _ = recording
    data = bytearray(path.read_bytes())
    mid = int(len(data) * where)
    for i in range(mid, mid + 8):
        data[i] ^= 0xFF
    bad = tmp_path / "corrupt.mcap"
    bad.write_bytes(bytes(data))
    _expect_recording_error(bad)


def test_single_byte_flips_never_yield_altered_payloads(recording, tmp_path: Path) -> None:
    """Any one flipped byte either raises RecordingError or reads back the original payloads
    (a flip in an index or padding may be harmless), never other payloads and never another
    exception type."""
    path, messages = recording
    data = path.read_bytes()
    expected = [p for _, _, p, _ in messages]
    rng = np.random.default_rng(2024)
    bad = tmp_path / "flip.mcap"
    raised = 0
    for pos in rng.choice(len(data), size=150, replace=False):
        flipped = bytearray(data)
        flipped[pos] ^= int(rng.integers(1, 256))
        bad.write_bytes(bytes(flipped))
        try:
            got = [m.payload for m in read_recording(bad)]
        except RecordingError as exc:
            assert "\n" not in str(exc)
            raised += 1
            continue
        assert got == expected, f"flip at byte {pos} changed the payloads silently"
    assert raised > 0


@pytest.mark.parametrize("chunked", [True, False], ids=["chunked", "unchunked"])
def test_viz_channels_are_skipped(tmp_path: Path, chunked: bool) -> None:
    """An outside tool's recording, chunked or not, with viewer channels beside ours."""
    path = tmp_path / "viz.mcap"
    with path.open("wb") as f:
        writer = Writer(f, use_chunking=chunked)
        writer.start(profile="", library="outside-tool")
        viz_schema = writer.register_schema(
            name="foxglove.SceneUpdate", encoding="jsonschema", data=b"{}"
        )
        uwb_schema = writer.register_schema(name="uwbnet.status", encoding="jsonschema", data=b"")
        viz = writer.register_channel(
            topic="/viz/scene", message_encoding="json", schema_id=viz_schema
        )
        viz_msgpack = writer.register_channel(
            topic="/viz/raw", message_encoding="msgpack", schema_id=uwb_schema
        )
        status = writer.register_channel(
            topic="uwbnet/demo/node/anchor1/status",
            message_encoding="msgpack",
            schema_id=uwb_schema,
        )
        ns = 110_000_000_000
        writer.add_message(viz, log_time=ns, publish_time=ns, data=b'{"entities": []}')
        writer.add_message(viz_msgpack, log_time=ns, publish_time=ns, data=golden("status"))
        writer.add_message(status, log_time=ns, publish_time=ns, data=golden("status"))
        writer.finish()
    (only,) = read_recording(path)
    assert only.topic == "uwbnet/demo/node/anchor1/status"
    assert only.kind == "status" and only.payload == golden("status")


def test_viz_topics_written_by_our_writer_are_skipped(tmp_path: Path) -> None:
    path = tmp_path / "viz2.mcap"
    with RecordingWriter(path) as writer:
        writer.write("/viz/status", "status", golden("status"), 110.0)
        writer.write("uwbnet/demo/node/anchor1/status", "status", golden("status"), 110.0)
    assert [m.topic for m in read_recording(path)] == ["uwbnet/demo/node/anchor1/status"]


def test_empty_recording_reads_empty(tmp_path: Path) -> None:
    path = tmp_path / "empty.mcap"
    with RecordingWriter(path):
        pass
    assert list(read_recording(path)) == []


def test_not_an_mcap_file(tmp_path: Path) -> None:
    path = tmp_path / "junk.mcap"
    path.write_bytes(golden("ir"))
    _expect_recording_error(path)


def test_decoded_messages_counts_skips_and_rejects(tmp_path: Path) -> None:
    """Every record counts; only the asked kinds are decoded; a bad payload of an asked kind
    is counted as rejected and skipped, and the pass goes on."""
    from dataclasses import dataclass

    from protocol.recording import decoded_messages

    @dataclass
    class Counts:
        messages: int = 0
        rejected: int = 0

    path = tmp_path / "mixed.mcap"
    messages = sample_messages()
    irs = [payload for _, kind, payload, _ in messages if kind == "ir"]
    bad_topic = f"uwbnet/{NET}/node/n-2/ir"
    with RecordingWriter(path) as writer:
        for topic, kind, payload, t in messages:
            writer.write(topic, kind, payload, t)
        writer.write(bad_topic, "ir", b"\xc1 not msgpack", 2000.0)
    counts, sizes = Counts(), []
    got = list(decoded_messages(path, ("ir",), counts, sizes.append))
    assert [m.to_wire() for m in got] == irs
    assert counts.messages == len(messages) + 1 and counts.rejected == 1
    assert len(sizes) == counts.messages
