"""Same detections in, same tracks out: the fusion center's decode, frame assembly and GM-PHD
frame update give the tracks they gave before their CPU was cut (issue 11, stop 20
notes), to float tolerance. The reference file was written by the code
before those changes (``python -m tests.unit.fusion.test_hub_regression`` rewrites it)."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path
from typing import Any

import numpy as np

from fusion_center.core import FusionCore
from fusion_center.offline import make_tracker
from protocol import Detections, NodeInfo, decode
from uwbnet.bench_hub import node_infos, synthetic_detections

REFERENCE = Path(__file__).resolve().parents[2] / "data" / "hub_tracks_reference.json"
NODES, FRAMES = 12, 150


def _stream() -> tuple[list[NodeInfo], list[bytes]]:
    """Node descriptions of a 12-node building and seeded synthetic ``detections`` payloads
    (:func:`uwbnet.bench_hub.synthetic_detections`): three people walking through it.
    Synthetic, so that the node DSP's own changes do not move the reference."""
    infos = node_infos(NODES, seed=1)
    start = np.array([[1.0, 2.0], [28.0, 6.0], [12.0, 1.5]])
    velocity = np.array([[1.2, 0.3], [-1.0, -0.2], [0.4, 0.9]])
    rng = np.random.default_rng(11)
    return infos, synthetic_detections(infos, FRAMES, start, velocity, rng=rng)


def _tracks() -> list[dict[str, Any]]:
    """Every tracker output of the stream, decoded and fused as the fusion center does."""
    infos, payloads = _stream()
    core = FusionCore(make_tracker("gmphd"))
    for info in infos:
        core.add_node(info)
    core.expected = frozenset(info.src for info in infos)
    outputs = []
    for payload in payloads:
        det = decode(payload)
        assert isinstance(det, Detections)
        outputs += core.add_detections(det)
    outputs += core.flush()
    return [
        {
            "t": o.t,
            "n": round(o.n_estimate, 10),
            "acquired": len(o.acquired),
            "tracks": [
                [tr.id, *(round(v, 10) for v in (tr.x, tr.vx, tr.y, tr.vy, tr.w))]
                for tr in o.tracks
            ],
        }
        for o in outputs
    ]


def test_same_detections_give_the_same_tracks() -> None:
    want = json.loads(REFERENCE.read_text())
    got = _tracks()
    assert len(got) == len(want) == FRAMES
    assert sum(len(o["tracks"]) for o in want) > FRAMES  # people are tracked at all
    for g, w in zip(got, want, strict=True):
        assert g["t"] == w["t"] and g["acquired"] == w["acquired"]
        assert math.isclose(g["n"], w["n"], rel_tol=1e-8, abs_tol=1e-8)
        assert [tr[0] for tr in g["tracks"]] == [tr[0] for tr in w["tracks"]], g["t"]
        np.testing.assert_allclose(
            np.array(g["tracks"]).reshape(-1, 6), np.array(w["tracks"]).reshape(-1, 6),
            rtol=1e-8, atol=1e-8,
        )  # fmt: skip


if __name__ == "__main__":
    REFERENCE.write_text(json.dumps(_tracks()) + "\n")
    print(f"wrote {REFERENCE}", file=sys.stderr)
