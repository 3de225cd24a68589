"""``uwbnet ranging`` as a user runs it: real MCAP files in, JSONL out, one-line errors."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from node_agent.offline import range_recording
from protocol import Antenna, C, Ir, NodeInfo, RadarInfo, keys
from protocol.recording import RecordingWriter
from tests.cli import assert_one_line_error, last_json, uwbnet
from tests.unit.dsp.cir import DW1000, synth_cir

pytestmark = pytest.mark.integration


@pytest.fixture(scope="module")
def foyer(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("foyer") / "f.mcap"
    proc = uwbnet("sim", "foyer3", "--duration", "1", "--seed", "5", "--out", str(out))
    assert proc.returncode == 0, proc.stderr
    return out


def test_foyer_recording_ranges_the_tx_rx_coupling(foyer: Path, tmp_path: Path) -> None:
    """Each bat node's own transmitter reaches its receivers first over the 0.5 m
    Tx -> Rx coupling (a LOS path): every row's first path is that coupling."""
    out = tmp_path / "r.jsonl"
    proc = uwbnet("ranging", str(foyer), "--out", str(out))
    assert proc.returncode == 0, proc.stderr
    stats = last_json(proc)
    assert stats["ir"] == 50 * 6 and stats["rejected"] == 0
    lines = [json.loads(x) for x in out.read_text().splitlines()]
    assert len(lines) == stats["lines"] == 2 * stats["ir"]
    assert all(set(x) == {"t", "node", "tx", "rx", "range", "los", "method"} for x in lines)
    assert {x["method"] for x in lines} == {"adaptive"}
    ranges = np.array([x["range"] for x in lines], dtype=float)
    # one 7 GHz sample is 4.3 cm of path: the coupling within a quarter of it
    assert np.all(np.abs(ranges - 0.5) < 0.011)
    assert all(x["los"] for x in lines)
    assert not Path(str(out) + ".partial").exists()


@pytest.mark.parametrize("method", ["threshold", "adaptive", "peak"])
def test_every_method_runs(foyer: Path, tmp_path: Path, method: str) -> None:
    # in process: the command line itself is covered above
    out = tmp_path / "r.jsonl"
    stats = range_recording(foyer, out, method=method)
    assert stats.lines == 2 * stats.ir and stats.rejected == 0
    first = json.loads(out.read_text().splitlines()[0])
    assert first["method"] == method
    assert abs(first["range"] - 0.5) < 0.011


# --- complex baseband, written by hand ----------------------------------------------------

T0 = 20e-9  # the CIR window starts 20 ns after emission
LOS_RANGE = 7.5
NLOS_RANGE = 12.0


def _anchor_info(n: int = DW1000.n) -> NodeInfo:
    omni = 2.0 * np.pi
    return NodeInfo(
        src="anchor1",
        seq=0,
        t=0.0,
        role="anchor",
        pose=(0.0, 0.0, 1.0, 0.0),
        mobile=False,
        antennas={
            "rx1": Antenna(pos=(0.0, 0.1, 0.0), tx=False, rx=True, boresight=0.0, beamwidth=omni),
            "rx2": Antenna(pos=(0.0, -0.1, 0.0), tx=False, rx=True, boresight=0.0, beamwidth=omni),
        },
        radar=RadarInfo(
            fs=DW1000.fs,
            n=n,
            t0=T0,
            f_low=DW1000.f_low,
            f_high=DW1000.f_high,
            rate=10.0,
            fc=DW1000.fc,
        ),
    )


def _complex_irs(rng: np.random.Generator, count: int) -> list[Ir]:
    """rx1: LOS (direct path strongest, weak multipath); rx2: NLOS (direct path 14 dB under
    the multipath arriving 6 to 20 ns later)."""
    los = LOS_RANGE / C - T0 + np.array([0.0, 4e-9, 11e-9])
    nlos = NLOS_RANGE / C - T0 + np.array([0.0, 6e-9, 9e-9, 14e-9, 20e-9])
    irs = []
    for k in range(count):
        h = np.vstack(
            [
                synth_cir(DW1000, los, [1.0, 0.35, 0.2], 32.0, rng),
                synth_cir(DW1000, nlos, [0.2, 1.0, 0.7, 0.8, 0.5], 32.0, rng),
            ]
        ).astype(np.complex64)
        irs.append(
            Ir(
                src="anchor1",
                seq=k,
                t=0.1 * k,
                tx="tag7/tx",
                rx=("rx1", "rx2"),
                slot=0,
                frame=k,
                h=h,
            )
        )
    return irs


def _write(path: Path, messages: list) -> None:
    with RecordingWriter(path) as w:
        for m in messages:
            w.write_message(keys.topic_for("demo", m.KIND, m.src), m)


def test_complex_baseband_recording(tmp_path: Path) -> None:
    rng = np.random.default_rng(11)
    rec = tmp_path / "c8.mcap"
    _write(rec, [_anchor_info(), *_complex_irs(rng, 20)])
    out = tmp_path / "r.jsonl"
    proc = uwbnet("ranging", str(rec), "--out", str(out))
    assert proc.returncode == 0, proc.stderr
    assert last_json(proc)["lines"] == 40
    lines = [json.loads(x) for x in out.read_text().splitlines()]
    by_rx = {rx: [x for x in lines if x["rx"] == rx] for rx in ("rx1", "rx2")}
    r1 = np.array([x["range"] for x in by_rx["rx1"]])
    r2 = np.array([x["range"] for x in by_rx["rx2"]])
    # a 1 ns sample is 30 cm of path; sub-sample refinement at 32 dB keeps within 5 cm
    assert np.median(np.abs(r1 - LOS_RANGE)) < 0.05
    assert np.median(np.abs(r2 - NLOS_RANGE)) < 0.05
    assert np.mean([x["los"] for x in by_rx["rx1"]]) >= 0.9
    assert np.mean([not x["los"] for x in by_rx["rx2"]]) >= 0.9
    # the multipath fit on the same complex samples: the same first paths
    ml = tmp_path / "ml.jsonl"
    range_recording(rec, ml, method="ml")
    got = [json.loads(x) for x in ml.read_text().splitlines()]
    m1 = np.array([x["range"] for x in got if x["rx"] == "rx1"])
    m2 = np.array([x["range"] for x in got if x["rx"] == "rx2"])
    assert np.median(np.abs(m1 - LOS_RANGE)) < 0.05
    assert np.median(np.abs(m2 - NLOS_RANGE)) < 0.05


def test_zero_padded_windows_range_and_classify_as_unpadded(tmp_path: Path) -> None:
    """A recording whose rows start with 300 zero-filled taps, then 400 of noise before the
    paths (another tool's export of a later-starting accumulator read): the zeros are no
    noise. Counted as noise they pulled the noise estimate down, and noise into the shape
    features' profile: 30 % of these rows were then called wrong (on dense multipath the
    first path also started on noise, 10 m early in the median)."""
    rng = np.random.default_rng(13)
    irs = _complex_irs(rng, 20)
    shift = 700
    for ir in irs:
        ir.h[:] = np.roll(ir.h, shift, axis=1)
        ir.h[:, :300] = 0
    rec = tmp_path / "padded.mcap"
    _write(rec, [_anchor_info(), *irs])
    out = tmp_path / "r.jsonl"
    proc = uwbnet("ranging", str(rec), "--out", str(out))
    assert proc.returncode == 0, proc.stderr
    lines = [json.loads(x) for x in out.read_text().splitlines()]
    assert len(lines) == 40
    offset = C * shift / DW1000.fs
    for rx, true_range, los in (("rx1", LOS_RANGE, True), ("rx2", NLOS_RANGE, False)):
        got = [x for x in lines if x["rx"] == rx]
        assert np.median([abs(x["range"] - true_range - offset) for x in got]) < 0.05
        assert np.mean([x["los"] == los for x in got]) >= 0.9


@pytest.mark.parametrize("with_fc", [True, False], ids=["fc", "no-fc"])
def test_magnitude_rows_are_ranged_as_the_envelope(with_fc: bool, tmp_path: Path) -> None:
    """Rows exported as magnitudes (``<f4``, never negative) of a complex-baseband radar: they
    are the envelope. With ``fc`` in node_info, or without it when the band (6.2-6.7 GHz at
    998.4 MHz sampling) straddles 13 fs / 2 and so cannot be a real sampled passband, they are
    ranged around the band's centre. Taken for a real passband signal, their band aliased and
    the matched filter smeared the envelope: LOS rows called NLOS, ranges 1.2 m off."""
    rng = np.random.default_rng(14)
    irs = [dataclasses.replace(ir, h=np.abs(ir.h)) for ir in _complex_irs(rng, 20)]
    info = _anchor_info()
    if not with_fc:
        info = dataclasses.replace(info, radar=dataclasses.replace(info.radar, fc=None))
    rec = tmp_path / "abs.mcap"
    _write(rec, [info, *irs])
    out = tmp_path / "r.jsonl"
    proc = uwbnet("ranging", str(rec), "--out", str(out))
    assert proc.returncode == 0, proc.stderr
    lines = [json.loads(x) for x in out.read_text().splitlines()]
    assert len(lines) == 40
    for rx, true_range, los in (("rx1", LOS_RANGE, True), ("rx2", NLOS_RANGE, False)):
        got = [x for x in lines if x["rx"] == rx]
        # the magnitudes lost the paths' phases, which the matched filter would use: within a
        # third of a sample (10 cm) rather than the complex rows' 5 cm
        assert np.median([abs(x["range"] - true_range) for x in got]) < 0.1
        # (the NLOS rows' few paths overlap incoherently without their phases: 3-5 of 20
        # called LOS here, against none from the complex rows)
        assert np.mean([x["los"] == los for x in got]) >= 0.7


def test_bad_messages_are_counted_not_fatal(tmp_path: Path) -> None:
    rng = np.random.default_rng(12)
    good = _complex_irs(rng, 3)
    early = good[0]  # before any node_info: rejected
    short = Ir(
        src="anchor1",
        seq=9,
        t=1.0,
        tx="tag7/tx",
        rx=("rx1",),
        slot=0,
        frame=9,
        h=np.zeros((1, 100), np.complex64),  # node_info says 1016 samples
    )
    rec = tmp_path / "bad.mcap"
    _write(rec, [early, _anchor_info(), *good[1:], short])
    out = tmp_path / "r.jsonl"
    proc = uwbnet("ranging", str(rec), "--out", str(out))
    assert proc.returncode == 0, proc.stderr
    stats = last_json(proc)
    assert stats["ir"] == 4
    assert stats["rejected"] == 2
    assert stats["lines"] == 4 == len(out.read_text().splitlines())


def test_corrupt_truncated_missing_and_empty_inputs(foyer: Path, tmp_path: Path) -> None:
    out = tmp_path / "r.jsonl"
    data = foyer.read_bytes()
    truncated = tmp_path / "trunc.mcap"
    truncated.write_bytes(data[: len(data) // 2])
    assert_one_line_error(uwbnet("ranging", str(truncated), "--out", str(out)), "trunc.mcap")
    garbage = tmp_path / "garbage.mcap"
    garbage.write_bytes(b"\x89MCAP0\r\n" + bytes(range(256)) * 8)
    assert_one_line_error(uwbnet("ranging", str(garbage), "--out", str(out)), "garbage.mcap")
    assert_one_line_error(
        uwbnet("ranging", str(tmp_path / "none.mcap"), "--out", str(out)), "no such recording"
    )
    no_ir = tmp_path / "info_only.mcap"
    _write(no_ir, [_anchor_info()])
    assert_one_line_error(uwbnet("ranging", str(no_ir), "--out", str(out)), "no ir messages")
    assert not out.exists() and not Path(str(out) + ".partial").exists()
    proc = uwbnet("ranging", str(foyer), "--out", str(out), "--method", "music")
    assert proc.returncode == 2 and "invalid choice" in proc.stderr
