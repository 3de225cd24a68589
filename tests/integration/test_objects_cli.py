"""``uwbnet sim`` of a circular scan and ``uwbnet objects`` on it, as a user runs them."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import sim_nodes
from protocol import Ir, NodeInfo, Truth
from protocol.recording import read_recording
from tests.cli import assert_one_line_error, last_json, uwbnet
from uwbnet.bench_objects import _edge_distance

pytestmark = pytest.mark.integration


@pytest.fixture(scope="module")
def scan(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("scan") / "l.mcap"
    proc = uwbnet("sim", "circle_L", "--seed", "3", "--out", str(out))
    assert proc.returncode == 0, proc.stderr
    return out


def test_recording_layout(scan: Path) -> None:
    msgs = list(read_recording(scan))
    info = NodeInfo.from_wire(msgs[0].payload)
    assert info.mobile and set(info.antennas) >= {"tx_v", "tx_h", "tx_p", "rx_v", "rx_h"}
    assert info.antennas["rx_h"].extra["pol"] == pytest.approx(np.pi / 2)
    irs = [Ir.from_wire(m.payload) for m in msgs if m.message_kind == "ir"]
    assert len(irs) == 3 * 360
    assert {(ir.tx, ir.rx) for ir in irs} == {
        ("scan/tx_v", ("rx_v", "rx_h")),
        ("scan/tx_h", ("rx_h", "rx_v")),
        ("scan/tx_p", ("rx_p", "rx_m")),
    }
    assert all(ir.pose is not None and ir.h.shape == (2, 4095) for ir in irs)
    truth = Truth.from_wire(next(m.payload for m in msgs if m.message_kind == "truth"))
    assert len(truth.extra["object"]["vertices"]) == 6


def test_objects_reports_contour_material_and_class(scan: Path) -> None:
    proc = uwbnet("objects", str(scan), "--json")
    assert proc.returncode == 0, proc.stderr
    report = last_json(proc)
    assert report["class"] == "L_45"
    assert report["closed_track"] is True
    truth = next(
        Truth.from_wire(m.payload) for m in read_recording(scan) if m.message_kind == "truth"
    )
    verts = np.array(truth.extra["object"]["vertices"])
    err = _edge_distance(np.array(report["contour"]), verts)
    assert len(err) > 250
    assert np.median(err) < 0.01
    m = report["material"]
    assert m["surface"] == "smooth" and m["metal_like"] is False
    assert report["corners_45deg"]  # the 45-degree cross-polar channel sees corners


def test_objects_one_line_errors(tmp_path: Path) -> None:
    assert_one_line_error(uwbnet("objects", str(tmp_path / "none.mcap")), "no such recording")
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"not an mcap file")
    assert_one_line_error(uwbnet("objects", str(bad)), "bad.mcap")
    foyer = tmp_path / "f.mcap"
    assert uwbnet("sim", "foyer3", "--duration", "0.2", "--out", str(foyer)).returncode == 0
    assert_one_line_error(uwbnet("objects", str(foyer)), "scan positions")


def test_objects_permittivity_of_a_brick_like_slab_with_a_wide_baseline(tmp_path: Path) -> None:
    # circle_slab (0.8 m baseline) with eps_r 4.5: the bistatic specular geometry from the
    # recording alone (no truth) must put eq. (16) within 3 %.
    shipped = Path(sim_nodes.__file__).parent / "scenarios" / "circle_slab.toml"
    text = shipped.read_text()
    assert "permittivity = 2.9" in text
    toml = tmp_path / "slab45.toml"
    toml.write_text(text.replace("permittivity = 2.9", "permittivity = 4.5"))
    rec = tmp_path / "slab45.mcap"
    proc = uwbnet("sim", str(toml), "--seed", "2", "--out", str(rec))
    assert proc.returncode == 0, proc.stderr
    proc = uwbnet("objects", str(rec), "--json")
    assert proc.returncode == 0, proc.stderr
    m = last_json(proc)["material"]
    assert m["face_positions"] >= 30
    assert m["permittivity"] == pytest.approx(4.5, rel=0.03)
    assert m["metal_like"] is False
