"""``uwbnet image``: multistatic recordings of point targets, written with protocol/ directly."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from protocol import Ir, NodeInfo, keys
from protocol.messages import Antenna, RadarInfo
from protocol.recording import RecordingWriter
from tests.cli import assert_one_line_error, last_json, uwbnet
from tests.unit.imaging.synth import FS, N, responses

TARGETS = np.array([[2.2, 3.1, 1.0], [4.1, 1.6, 1.0]])
ANCHORS = {"a1": (0.0, 0.0), "a2": (6.0, 0.0), "a3": (6.0, 5.0), "a4": (0.0, 5.0)}
OMNI = 2 * np.pi


def _info(node: str, pose: tuple[float, ...], *, mobile: bool = False, fs: float = FS) -> NodeInfo:
    ant = {
        "tx": Antenna(pos=(0.0, 0.0, 0.0), tx=True, rx=False, boresight=0.0, beamwidth=OMNI),
        "rx": Antenna(pos=(0.0, 0.0, 0.0), tx=False, rx=True, boresight=0.0, beamwidth=OMNI),
    }
    radar = RadarInfo(fs=fs, n=N, t0=0.0, f_low=4e9, f_high=8e9, rate=50.0)
    role = "robot" if mobile else "anchor"
    return NodeInfo(
        src=node, seq=0, t=0.0, role=role, pose=pose, mobile=mobile, antennas=ant, radar=radar
    )


def _anchor_recording(path: Path, *, fs_a4: float = FS, frames: int = 2) -> None:
    """Four anchors at 1 m height; every anchor transmits in turn, every anchor receives."""
    pos = {k: np.array([x, y, 1.0]) for k, (x, y) in ANCHORS.items()}
    with RecordingWriter(path) as rec:
        for node, (x, y) in ANCHORS.items():
            info = _info(node, (x, y, 1.0, 0.0), fs=fs_a4 if node == "a4" else FS)
            rec.write_message(keys.node_key("demo", node, "info"), info)
        seq = 0
        for frame in range(frames):
            for slot, tx in enumerate(ANCHORS):
                for node in ANCHORS:
                    h = responses(pos[tx][None], pos[node][None], TARGETS, seed=seq)
                    ir = Ir(
                        src=node,
                        seq=seq,
                        t=0.1 * frame + 0.01 * slot,
                        tx=f"{tx}/tx",
                        rx=("rx",),
                        slot=slot,
                        frame=frame,
                        h=h,
                    )
                    rec.write_message(keys.node_key("demo", node, "ir"), ir)
                    seq += 1


@pytest.mark.parametrize("method", ["kirchhoff", "xcorr"])
def test_image_of_an_anchor_network_finds_the_point_targets(tmp_path: Path, method: str) -> None:
    rec = tmp_path / "anchors.mcap"
    _anchor_recording(rec)
    out = tmp_path / "img.npz"
    png = tmp_path / "img.png"
    args = ["--nx", "121", "--ny", "101", "--bounds", "0", "6", "0", "5"]
    proc = uwbnet(
        "image", str(rec), "--method", method, "--out", str(out), "--png", str(png), *args
    )
    assert proc.returncode == 0, proc.stderr
    assert last_json(proc)["observations"] == 32
    with np.load(out) as z:
        assert set(z.files) >= {"img", "x0", "y0", "dx", "dy"}
        img, x0, y0, dx, dy = z["img"], z["x0"], z["y0"], z["dx"], z["dy"]
    assert img.shape == (101, 121) and img.dtype == np.float32
    assert float(x0) == 0.0 and float(dx) == pytest.approx(0.05)
    for tx_, ty_ in TARGETS[:, :2]:
        X, Y = np.meshgrid(x0 + dx * np.arange(121), y0 + dy * np.arange(101))
        near = np.hypot(X - tx_, Y - ty_) < 0.6
        k = np.argmax(np.where(near, img, -np.inf))
        assert np.hypot(X.flat[k] - tx_, Y.flat[k] - ty_) < 0.05
    assert png.stat().st_size > 10_000


def test_moving_node_without_poses_is_one_line(tmp_path: Path) -> None:
    rec = tmp_path / "robot.mcap"
    with RecordingWriter(rec) as w:
        w.write_message(
            keys.node_key("demo", "bot", "info"), _info("bot", (1, 1, 1, 0), mobile=True)
        )
        h = np.zeros((1, N), np.float32)
        ir = Ir(src="bot", seq=0, t=0.0, tx="bot/tx", rx=("rx",), slot=0, frame=0, h=h)
        w.write_message(keys.node_key("demo", "bot", "ir"), ir)
    out = tmp_path / "x.npz"
    assert_one_line_error(
        uwbnet("image", str(rec), "--out", str(out)), "no pose for mobile node bot"
    )
    assert not out.exists()


def test_mismatched_sampling_and_empty_recordings_are_one_line(tmp_path: Path) -> None:
    rec = tmp_path / "mixed.mcap"
    _anchor_recording(rec, fs_a4=10e9, frames=1)
    out = tmp_path / "x.npz"
    assert_one_line_error(uwbnet("image", str(rec), "--out", str(out)), "mismatched sampling")
    empty = tmp_path / "empty.mcap"
    with RecordingWriter(empty) as w:
        w.write_message(keys.node_key("demo", "a1", "info"), _info("a1", (0, 0, 1, 0)))
    assert_one_line_error(uwbnet("image", str(empty), "--out", str(out)), "no ir messages")
    assert_one_line_error(
        uwbnet("image", str(tmp_path / "nope.mcap"), "--out", str(out)), "no such"
    )
    assert not out.exists()
