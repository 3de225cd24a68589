"""Same detections in, same tracks out: the fusion center's decode, frame assembly and GM-PHD
frame update give the tracks they gave before their CPU was cut (stop 20, docs/capacity.md,
"Eighth round, hub side"), to float tolerance. The reference file was written by the code
before those changes (``python -m tests.unit.fusion.test_hub_regression`` rewrites it)."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path
from typing import Any

import msgpack
import numpy as np

from fusion_center.core import FusionCore
from fusion_center.offline import make_tracker
from protocol import Detections, NodeInfo, decode
from sim_nodes.building import building_scenario
from sim_nodes.network import SimNetwork

REFERENCE = Path(__file__).resolve().parents[2] / "data" / "hub_tracks_reference.json"
NODES, FRAMES, PERIOD = 12, 150, 0.02


def _stream() -> tuple[list[NodeInfo], list[bytes]]:
    """Node descriptions of a 12-node building and seeded synthetic ``detections`` payloads:
    three people walking through it, each sensor seeing those within 8 m and 60 degrees of its
    heading with p_D 0.8 and 0.1 m noise, plus Poisson clutter (0.3 per scan) in front of it.
    Synthetic, so that the node DSP's own changes do not move the reference."""
    rng = np.random.default_rng(11)
    infos = []
    for nid, info in SimNetwork(building_scenario(NODES, 2, 1), 1).node_infos().items():
        wire = {"v": 1, "kind": "node_info", "src": nid, "seq": 0, "t": 0.0, **info}
        infos.append(NodeInfo.from_wire(msgpack.packb(wire)))
    start = np.array([[1.0, 2.0], [28.0, 6.0], [12.0, 1.5]])
    velocity = np.array([[1.2, 0.3], [-1.0, -0.2], [0.4, 0.9]])
    no = {"rx1": (), "rx2": ()}
    payloads = []
    for f in range(FRAMES):
        for s, info in enumerate(infos):
            t = 1.0 + f * PERIOD + s * PERIOD / NODES
            people = start + velocity * (t - 1.0)
            x, y, _, yaw = info.pose
            d = people - np.array([x, y])
            off = np.abs((np.arctan2(d[:, 1], d[:, 0]) - yaw + math.pi) % (2 * math.pi) - math.pi)
            seen = (np.hypot(d[:, 0], d[:, 1]) < 8.0) & (off < math.radians(60))
            seen &= rng.random(seen.size) < 0.8
            z = people[seen] + rng.normal(0.0, 0.1, (int(seen.sum()), 2))
            k = rng.poisson(0.3)
            r, a = rng.uniform(1.0, 7.0, k), yaw + rng.uniform(-0.8, 0.8, k)
            z = np.concatenate([z, np.stack([x + r * np.cos(a), y + r * np.sin(a)], axis=1)])
            cov = np.broadcast_to(np.eye(2) * 0.01, (z.shape[0], 2, 2))
            det = Detections(
                src=info.src, seq=f, t=t, tx=f"{info.src}/tx", frame=f, ranges=no,
                amplitudes=no, positions=z, cov=cov,
            )  # fmt: skip
            payloads.append(det.to_wire())
    return infos, payloads


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
