"""A live recording opens in Foxglove: ``uwbnet demo --record`` writes ``/viz`` channels whose
every message validates against Foxglove's published JSON schemas, and contract readers still
see only the msgpack channels."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from mcap.reader import make_reader

from fusion_center.viewer.foxglove import foxglove_schema
from protocol.recording import read_recording
from tests.cli import uwbnet
from tests.viz_schemas import check

pytestmark = [pytest.mark.integration, pytest.mark.slow]


def test_demo_recording_has_foxglove_channels_that_validate(tmp_path: Path) -> None:
    rec = tmp_path / "demo.mcap"
    proc = uwbnet("demo", "--duration", "8", "--record", str(rec), timeout=120)
    assert proc.returncode == 0, proc.stderr
    counts: dict[str, int] = {}
    n_track_entities = 0
    with open(rec, "rb") as f:
        reader = make_reader(f)
        for schema, channel, message in reader.iter_messages():
            if not channel.topic.startswith("/viz/"):
                assert channel.message_encoding == "msgpack"
                continue
            assert channel.message_encoding == "json"
            assert schema is not None and schema.encoding == "jsonschema"
            assert schema.data == foxglove_schema(schema.name)
            doc = json.loads(message.data)
            check(schema.name, doc)
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
            if channel.topic == "/viz/tracks":
                n_track_entities = max(n_track_entities, len(doc["entities"]))
    print(f"validated /viz messages: {counts}")
    assert {"/viz/walls", "/viz/sensors", "/viz/tracks", "/viz/truth"} <= set(counts)
    assert counts["/viz/tracks"] > 10 and n_track_entities >= 2
    # Readers of the contract skip the viewer channels.
    assert not any(m.topic.startswith("/viz/") for m in read_recording(rec))
