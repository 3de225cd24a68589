"""The ``/viz`` documents against Foxglove's published JSON schemas (vendored, MIT)."""

from __future__ import annotations

import json

import jsonschema
import numpy as np
import pytest

from fusion_center.viewer.foxglove import GRID, SCENE, FoxgloveScene
from protocol import Image, NodeInfo, Track, Tracks, Truth
from protocol.messages import Target
from sim_nodes.driver import SimulatedDriver
from sim_nodes.network import SimNetwork
from tests.viz_schemas import check


@pytest.fixture(scope="module")
def infos() -> list[NodeInfo]:
    net = SimNetwork("foyer3", 1)
    out = []
    for n in sorted(net.node_infos()):
        with SimulatedDriver(net, n) as drv:
            out.append(NodeInfo(src=n, seq=0, t=1.0, **drv.describe()))
    return out


def _tracks(t: float, n: int) -> Tracks:
    return Tracks(
        src="fusion",
        seq=0,
        t=t,
        tracks=tuple(
            Track(id=i, x=1.0 + i + t, y=2.0, vx=1.0, vy=0.0, cov=np.eye(4).tolist(), w=0.9)
            for i in range(n)
        ),
        n_estimate=float(n),
    )


def test_scene_updates_and_grid_validate_against_the_published_schemas(infos) -> None:
    scene = FoxgloveScene([[0, 0, 12, 0], [0, 0, 0, 9]])
    docs = []
    for info in infos:
        docs += scene.on_message(info)
    for k in range(20):
        docs += scene.on_message(_tracks(2.0 + 0.05 * k, 3))  # 20 Hz in, 10 Hz out
    truth = Truth(
        src="sim", seq=0, t=4.0, targets=(Target(id=1, x=1.0, y=2.0, vx=0.0, vy=0.0),), nodes={}
    )
    docs += scene.on_message(truth)
    img = np.arange(12, dtype=np.float32).reshape(3, 4)
    docs += scene.on_message(
        Image(
            src="fusion",
            seq=0,
            t=4.1,
            x0=-1.0,
            y0=-2.0,
            dx=0.1,
            dy=0.2,
            method="kirchhoff",
            img=img,
        )
    )
    topics = {topic for topic, _, _ in docs}
    assert topics == {"/viz/walls", "/viz/sensors", "/viz/tracks", "/viz/truth", "/viz/image"}
    for _, schema, doc in docs:
        check(schema, doc)
    # Tracks: one entity per track, with a tail that grew over the 20 updates.
    last = [d for topic, _, d in docs if topic == "/viz/tracks"][-1]
    assert [e["id"] for e in last["entities"]] == ["track/0", "track/1", "track/2"]
    assert len(last["entities"][0]["lines"][0]["points"]) == 10
    assert sum(topic == "/viz/tracks" for topic, _, _ in docs) == 10
    # Sensors: all six foyer3 nodes; the grid: 4 columns of FLOAT32, origin at pixel corner.
    sensors = [d for topic, _, d in docs if topic == "/viz/sensors"][-1]
    assert len(sensors["entities"]) == 6
    grid = next(d for topic, _, d in docs if topic == "/viz/image")
    assert grid["column_count"] == 4 and grid["cell_size"] == {"x": 0.1, "y": 0.2}
    assert grid["pose"]["position"]["x"] == pytest.approx(-1.05)


def test_the_validator_rejects_a_broken_document() -> None:
    scene = FoxgloveScene()
    doc = scene.tracks(_tracks(1.0, 1))
    check(SCENE, doc)
    broken = json.loads(json.dumps(doc))
    del broken["entities"][0]["cylinders"][0]["color"]
    with pytest.raises(jsonschema.ValidationError):
        check(SCENE, broken)
    grid = scene.grid(
        Image(
            src="f", seq=0, t=1.0, x0=0, y0=0, dx=1, dy=1, method="m", img=np.zeros((2, 2), "<f4")
        )
    )
    grid["fields"][0]["type"] = 42
    with pytest.raises(jsonschema.ValidationError):
        check(GRID, grid)
