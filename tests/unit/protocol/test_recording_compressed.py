"""Recordings written by outside tools with compressed chunks (the mcap writer's default)."""

from __future__ import annotations

from pathlib import Path

import msgpack
import pytest
from mcap.writer import CompressionType, Writer

from protocol.recording import read_recording


@pytest.mark.parametrize("compression", [CompressionType.ZSTD, CompressionType.LZ4])
def test_compressed_chunks_read_back(tmp_path: Path, compression: CompressionType) -> None:
    path = tmp_path / f"outside_{compression.name}.mcap"
    payloads = [
        msgpack.packb(
            {
                "v": 1,
                "kind": "truth",
                "src": "sim",
                "seq": i,
                "t": 0.02 * i,
                "targets": [],
                "nodes": {},
            },
            use_bin_type=True,
        )
        for i in range(50)
    ]
    with open(path, "wb") as f:
        w = Writer(f, compression=compression)
        w.start()
        schema = w.register_schema(name="uwbnet.truth", encoding="jsonschema", data=b"{}")
        ch = w.register_channel(
            topic="uwbnet/hall/sim/truth", message_encoding="msgpack", schema_id=schema
        )
        for i, p in enumerate(payloads):
            ns = 20_000_000 * i
            w.add_message(channel_id=ch, log_time=ns, publish_time=ns, data=p)
        w.finish()
    got = list(read_recording(path))
    assert [m.payload for m in got] == payloads
    assert {m.kind for m in got} == {"truth"}
    assert [m.log_time for m in got] == [20_000_000 * i for i in range(50)]
