"""Live imaging in the fusion center over real zenoh sessions: ``ir`` in, ``image`` out."""

from __future__ import annotations

import contextlib
import threading
import time

import numpy as np
import pytest
import zenoh

from fusion_center.image_runtime import LiveImagingConfig
from fusion_center.imaging.migration import Grid
from fusion_center.imaging.quality import peak_errors
from fusion_center.service import FusionConfig, FusionService
from protocol import Image, Ir, PoseEstimate, Poses, decode, keys
from protocol.transport import FifoChannel, session_config
from tests.integration.test_image_cli import ANCHORS, TARGETS, _info
from tests.unit.imaging.synth import responses

pytestmark = pytest.mark.integration

NET = "imgtest"


def test_fusion_center_publishes_an_improving_image(hub_endpoint) -> None:
    cfg = FusionConfig(
        net=NET,
        imaging=LiveImagingConfig(rate=5.0, bounds=(0.0, 6.0, 0.0, 5.0), nx=61, ny=51),
    )
    got: FifoChannel[bytes] = FifoChannel(1000)
    pos = {k: np.array([x, y, 1.0]) for k, (x, y) in ANCHORS.items()}
    with contextlib.ExitStack() as stack:
        fs = stack.enter_context(zenoh.open(session_config(listen=[hub_endpoint])))
        fusion = FusionService(fs, cfg)
        fusion.start()
        stack.callback(fusion.stop)
        ns = stack.enter_context(zenoh.open(session_config(connect=[hub_endpoint])))
        sub = ns.declare_subscriber(
            keys.fusion_key(NET, "image"), lambda s: got.put(s.payload.to_bytes())
        )
        stack.callback(sub.undeclare)
        time.sleep(0.5)
        for node, (x, y) in ANCHORS.items():
            ns.put(keys.node_key(NET, node, "info"), _info(node, (x, y, 1.0, 0.0)).to_wire())
        time.sleep(0.3)
        seq = 0
        for slot, tx in enumerate(ANCHORS):
            for node in ANCHORS:
                h = responses(pos[tx][None], pos[node][None], TARGETS, seed=seq)
                ir = Ir(
                    src=node, seq=seq, t=0.0, tx=f"{tx}/tx", rx=("rx",), slot=slot, frame=0, h=h
                )
                ns.put(keys.node_key(NET, node, "ir"), ir.to_wire())
                seq += 1
            time.sleep(0.3)
        ns.put(keys.node_key(NET, "a1", "ir"), b"\x00not msgpack")
        deadline = time.monotonic() + 10
        while fusion.imaging.counters.rows < 16 and time.monotonic() < deadline:
            threading.Event().wait(0.05)
        time.sleep(0.5)
        images = [decode(p) for p in got.drain()]
        assert fusion.decode_errors == 1
    assert len(images) >= 2 and all(isinstance(m, Image) for m in images)
    last = images[-1]
    assert last.img.shape == (51, 61) and last.method == "kirchhoff"
    assert fusion.imaging.counters.rows == 16 and fusion.imaging.counters.rejected == 0
    grid = Grid(last.x0, last.y0, last.dx, last.dy, 61, 51, 1.0)
    assert np.all(peak_errors(last.img, grid, TARGETS[:, :2], radius=0.6) < 0.1)
    # The image improves as the nodes' responses arrive: energy grows over the messages.
    energy = [float(np.sum(m.img**2)) for m in images]
    assert energy[-1] > energy[0]


def test_a_mobile_node_without_ir_poses_is_placed_by_the_poses_on_the_wire(hub_endpoint) -> None:
    """An ``ir`` of a mobile node that carries no pose is rejected (counted) until a ``poses``
    message places the node; from then on its rows are imaged."""
    cfg = FusionConfig(
        net=NET,
        imaging=LiveImagingConfig(rate=5.0, bounds=(0.0, 6.0, 0.0, 5.0), nx=31, ny=26),
    )
    pos = {k: np.array([x, y, 1.0]) for k, (x, y) in ANCHORS.items()}
    mobile = next(iter(ANCHORS))
    with contextlib.ExitStack() as stack:
        fs = stack.enter_context(zenoh.open(session_config(listen=[hub_endpoint])))
        fusion = FusionService(fs, cfg)
        fusion.start()
        stack.callback(fusion.stop)
        ns = stack.enter_context(zenoh.open(session_config(connect=[hub_endpoint])))
        time.sleep(0.5)
        for node, (x, y) in ANCHORS.items():
            info = _info(node, (x, y, 1.0, 0.0), mobile=node == mobile)
            ns.put(keys.node_key(NET, node, "info"), info.to_wire())
        time.sleep(0.3)

        def send(seq: int) -> None:
            h = responses(pos[mobile][None], pos[mobile][None], TARGETS, seed=seq)
            ir = Ir(src=mobile, seq=seq, t=0.0, tx=f"{mobile}/tx", rx=("rx",), slot=0, frame=0, h=h)
            ns.put(keys.node_key(NET, mobile, "ir"), ir.to_wire())

        def wait(counter: str, value: int) -> None:
            deadline = time.monotonic() + 10
            while getattr(fusion.imaging.counters, counter) < value:
                assert time.monotonic() < deadline, fusion.imaging.counters
                threading.Event().wait(0.05)

        send(0)
        wait("rejected", 1)
        assert fusion.imaging.counters.rows == 0
        x, y, z = (float(v) for v in pos[mobile])
        est = PoseEstimate(
            pose=(x, y, z, 0.0), cov=((0.01, 0, 0), (0, 0.01, 0), (0, 0, 0.01)), los={}
        )
        ns.put(
            keys.fusion_key(NET, "poses"),
            Poses(src="loc", seq=0, t=0.0, poses={mobile: est}).to_wire(),
        )
        time.sleep(0.5)
        send(1)
        wait("rows", 1)
    assert fusion.imaging.counters.rejected == 1 and fusion.decode_errors == 0
