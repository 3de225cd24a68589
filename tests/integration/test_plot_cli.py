"""``uwbnet plot``: figures from a short simulated recording, an image .npz and a scenario."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tests.cli import assert_one_line_error, last_json, uwbnet

pytestmark = [pytest.mark.slow]


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    d = tmp_path_factory.mktemp("plot")
    rec, tracks = d / "r.mcap", d / "t.jsonl"
    assert uwbnet("sim", "foyer3", "--duration", "2", "--out", str(rec)).returncode == 0
    assert uwbnet("track", str(rec), "--out", str(tracks)).returncode == 0
    return rec, tracks


def _is_png(p: Path) -> bool:
    return p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and p.stat().st_size > 10_000


def test_tracks_and_channel_figures_from_a_recording(run, tmp_path: Path) -> None:
    rec, tracks = run
    out = tmp_path / "tracks.png"
    proc = uwbnet(
        "plot", "tracks", str(rec), str(tracks), "--scenario", "foyer3", "--out", str(out)
    )
    assert proc.returncode == 0, proc.stderr
    assert last_json(proc)["targets"] >= 2 and _is_png(out)
    out = tmp_path / "radargram.svg"
    proc = uwbnet("plot", "channel", str(rec), "--node", "bat2", "--out", str(out))
    assert proc.returncode == 0, proc.stderr
    assert last_json(proc)["impulse_responses"] == 100
    assert "<svg" in out.read_text()[:500] and "bistatic range (m)" in out.read_text()
    proc = uwbnet("plot", "channel", str(rec), "--node", "nope", "--out", str(tmp_path / "x.png"))
    assert_one_line_error(proc, "no node_info and ir of node 'nope'")
    assert not (tmp_path / "x.png").exists()


def test_image_and_topology_figures(tmp_path: Path) -> None:
    y, x = np.mgrid[0:40, 0:60]
    img = np.exp(-((x - 20.0) ** 2 + (y - 25.0) ** 2) / 30.0).astype(np.float32)
    npz = tmp_path / "img.npz"
    np.savez(npz, img=img, x0=-1.0, y0=0.5, dx=0.1, dy=0.1, method="kirchhoff")
    out = tmp_path / "img.png"
    proc = uwbnet("plot", "image", str(npz), "--out", str(out))
    assert proc.returncode == 0, proc.stderr
    assert last_json(proc)["shape"] == [40, 60] and _is_png(out)
    bad = tmp_path / "bad.npz"
    np.savez(bad, img=img, x0=0.0, y0=0.0, dx=0.1)
    proc = uwbnet("plot", "image", str(bad), "--out", str(tmp_path / "b.png"))
    assert_one_line_error(proc, "missing array 'dy'")
    out = tmp_path / "topo.png"
    proc = uwbnet("plot", "topology", "foyer3", "--out", str(out))
    assert proc.returncode == 0, proc.stderr
    assert last_json(proc) == {"out": str(out), "nodes": 6, "people": 3} and _is_png(out)
    proc = uwbnet("plot", "topology", "foyer3", "--out", str(tmp_path / "t.txt"))
    assert_one_line_error(proc, "output must end in one of")
