"""Robot recordings (sim_nodes.robot_record, ``uwbnet sim`` of a [robot] scenario)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from protocol import Ir, NodeInfo, Truth
from protocol.messages import decode
from protocol.recording import read_recording
from protocol.units import C
from sim_nodes.propagation import RobotDataset
from sim_nodes.robot_record import frequency_to_ir, ir_sampling, write_robot_recording
from sim_nodes.scene import load_scenario
from tests.cli import assert_one_line_error, last_json, uwbnet

# A small metal room with one pole: cheap to trace (order 1, no scatterers), 2 stops x 3 headings.
SMALL = """
name = "robot_small"
duration = 1.0
[channel]
model = "hybrid"
reflection_order = 1
scatter_order = 0
n_scatterers = 0
diffraction = false
band = [4.5e9, 13.4e9]
frequency_step = 25e6
knots = 1
[materials.metal]
metal = true
[room]
outline = [[0.0, 0.0], [4.0, 0.0], [4.0, 3.0], [0.0, 3.0], [0.0, 0.0]]
material = "metal"
floor = 0.0
ceiling = 3.0
[[objects]]
id = "pole"
footprint = [[2.9, 1.4], [3.1, 1.4], [3.1, 1.6], [2.9, 1.6], [2.9, 1.4]]
z = [0.0, 2.0]
material = "metal"
[robot]
id = "bot"
height = 1.0
baseline = 0.6
n_headings = 3
heading_step = 0.5
pattern = "omni"
stops = [[1.0, 1.5], [1.5, 1.0]]
"""


@pytest.fixture(scope="module")
def small_toml(tmp_path_factory: pytest.TempPathFactory) -> Path:
    p = tmp_path_factory.mktemp("robot") / "robot_small.toml"
    p.write_text(SMALL)
    return p


def _messages(path: Path) -> list[tuple[str, object]]:
    return [(m.topic, decode(m.payload)) for m in read_recording(path)]


def test_single_path_becomes_a_peak_at_its_delay_with_its_friis_amplitude() -> None:
    f = 4.5e9 + 6.25e6 * np.arange(1425)
    fs, n_fft, n = ir_sampling(f)
    assert fs >= 2.4 * f[-1] and n == math.ceil(100e-9 * fs)
    d = 7.3  # m of path; 1/d-scaled transfer function of one path
    resp = (np.exp(-2j * np.pi * f * d / C) / d).astype(np.complex64)
    h = frequency_to_ir(resp, f, n_fft, n)
    assert h.dtype == np.float32 and h.shape == (n,)
    k = int(np.argmax(np.abs(h)))
    assert abs(k / fs * C - d) < C / fs  # within one sample
    friis = C / (4 * np.pi * 9e9) / d  # amplitude at mid band
    assert 0.5 * friis < np.abs(h).max() < 2 * friis


def test_noise_has_the_documented_snr(tmp_path: Path) -> None:
    sc = load_scenario("room_pillar")
    f = 4.5e9 + 6.25e6 * np.arange(1425)
    d = 3.0
    one = (np.exp(-2j * np.pi * f * d / C) / d).astype(np.complex64)
    ds = RobotDataset(
        frequencies=f,
        stops=np.array([[2.0, 2.0]]),
        headings=np.array([[0.0]]),
        response=np.broadcast_to(one, (1, 1, 2, f.size)).copy(),
        n_paths=np.ones((1, 1, 2), np.int64),
    )

    def first_ir(snr: float, seed: int) -> np.ndarray:
        out = tmp_path / f"n{snr}_{seed}.mcap"
        write_robot_recording(sc, ds, out, seed=seed, snr_db=snr)
        return next(m for _, m in _messages(out) if isinstance(m, Ir)).h

    clean = first_ir(math.inf, 0)
    noisy = first_ir(20.0, 0)
    assert np.array_equal(noisy, first_ir(20.0, 0))  # seeded
    assert not np.array_equal(noisy, first_ir(20.0, 1))
    _, n_fft, n = ir_sampling(f)
    # White noise spreads over all n_fft samples; the recording keeps n of them.
    snr = np.sum(clean**2) / (np.sum((noisy - clean) ** 2) * n_fft / n)
    assert abs(10 * np.log10(snr) - 20.0) < 1.0


def test_sim_of_a_robot_scenario_writes_the_protocol_recording(
    small_toml: Path, tmp_path: Path
) -> None:
    out = tmp_path / "small.mcap"
    proc = uwbnet("sim", str(small_toml), "--out", str(out), "--seed", "3", "--workers", "2")
    assert proc.returncode == 0, proc.stderr
    assert last_json(proc)["acquisitions"] == 6
    msgs = _messages(out)
    topic, info = msgs[0]
    assert isinstance(info, NodeInfo) and topic == "uwbnet/demo/node/bot/info"
    assert info.role == "robot" and info.mobile
    assert info.antennas["tx"].pos == (0.0, 0.0, 1.0) and info.antennas["tx"].tx
    assert info.antennas["rx1"].pos == (0.0, 0.3, 1.0) and info.antennas["rx1"].rx
    assert info.antennas["rx2"].pos == (0.0, -0.3, 1.0) and info.antennas["rx2"].rx
    r = info.radar
    assert r.f_low == 4.5e9 and r.f_high == 13.4e9 and r.fs >= 2 * r.f_high and r.t0 == 0.0
    irs = [(t, m) for t, m in msgs if isinstance(m, Ir)]
    truths = [m for _, m in msgs if isinstance(m, Truth)]
    assert len(irs) == len(truths) == 6 and len(msgs) == 13
    expected = [(x, y, 0.0, 0.5 * k) for x, y in ((1.0, 1.5), (1.5, 1.0)) for k in range(3)]
    for (topic, ir), truth, pose in zip(irs, truths, expected, strict=True):
        assert topic == "uwbnet/demo/node/bot/ir"
        assert ir.tx == "bot/tx" and ir.rx == ("rx1", "rx2")
        assert ir.h.dtype == np.dtype("<f4") and ir.h.shape == (2, r.n)
        assert np.all(np.isfinite(ir.h)) and np.abs(ir.h).max() > 0
        assert ir.pose == pytest.approx(pose)
        assert truth.nodes["bot"] == pytest.approx(pose) and truth.t == ir.t
    # The direct Tx -> rx1 coupling (0.3 m) is the first strong echo of the first IR.
    h = irs[0][1].h[0]
    k = int(np.argmax(np.abs(h[: int(1.0 / C * r.fs)])))
    assert abs(k / r.fs * C - 0.3) < 0.05


def test_room_pillar_robot_matches_its_scenario(tmp_path: Path) -> None:
    out = tmp_path / "rp.mcap"
    proc = uwbnet("sim", "room_pillar", "--out", str(out), "--stops", "1", "--workers", "1")
    assert proc.returncode == 0, proc.stderr
    msgs = _messages(out)
    info = msgs[0][1]
    assert isinstance(info, NodeInfo) and info.antennas["rx1"].pos == (0.0, 0.5, 1.0)
    irs = [m for _, m in msgs if isinstance(m, Ir)]
    assert len(irs) == 120
    assert irs[-1].pose == pytest.approx((2.25, 0.75, 0.0, math.radians(357.0)))
    assert len({m.seq for m in irs}) == 120


def test_sim_rejects_a_bad_stop_count(small_toml: Path, tmp_path: Path) -> None:
    out = tmp_path / "x.mcap"
    proc = uwbnet("sim", str(small_toml), "--out", str(out), "--stops", "0")
    assert_one_line_error(proc, "--stops")
    proc = uwbnet("sim", str(small_toml), "--out", str(out), "--duration", "3")
    assert_one_line_error(proc, "--duration does not apply")
    assert not out.exists()


def test_drive_turns_record_their_poses_and_the_drives_odometry(
    small_toml: Path, tmp_path: Path
) -> None:
    """Three stops with turn_start = "drive": each turn starts at the drive's heading, the
    receivers really turn with it, and the odometry between stops carries the drive's yaw."""
    from sim_nodes.propagation import hybrid_channel, robot_dataset
    from sim_nodes.robot_record import OdometrySlip

    text = small_toml.read_text().replace("n_headings = 3", "n_headings = 4")
    text = text.replace("heading_step = 0.5", f"heading_step = {math.pi / 2}")
    text = text.replace(
        "stops = [[1.0, 1.5], [1.5, 1.0]]", "stops = [[1.0, 1.5], [2.0, 1.5], [2.0, 2.0]]"
    )
    world = tmp_path / "world.toml"
    world.write_text(text)
    drive = tmp_path / "drive.toml"
    drive.write_text(text + 'turn_start = "drive"\nfirst_heading = 0.3\n')
    sc = load_scenario(str(drive))
    ds = robot_dataset(sc, hybrid_channel(sc, np.random.default_rng(0)))
    q = math.pi / 2
    starts = np.array([0.3, 0.0, q])  # first_heading, east, north
    assert ds.headings == pytest.approx(starts[:, None] + q * np.arange(4))
    # Stop 2 starts at world heading pi/2: its heading k is the default turn's heading k + 1.
    sw = load_scenario(str(world))
    dw = robot_dataset(sw, hybrid_channel(sw, np.random.default_rng(0)))
    assert np.allclose(ds.response[2, :3], dw.response[2, 1:], rtol=1e-3, atol=1e-6)
    assert not np.allclose(ds.response[2], dw.response[2], rtol=1e-3, atol=1e-6)

    out = tmp_path / "drive.mcap"
    still = OdometrySlip(translation=0.0, rotation=0.0, heading_per_metre=0.0, floor=(0.0, 0.0))
    write_robot_recording(sc, ds, out, seed=0, slip=still)
    irs = [m for _, m in _messages(out) if isinstance(m, Ir)]
    stops = [(1.0, 1.5), (2.0, 1.5), (2.0, 2.0)]
    expected = [
        (x, y, 0.0, a + q * k) for (x, y), a in zip(stops, starts, strict=True) for k in range(4)
    ]
    assert np.array([ir.pose for ir in irs]) == pytest.approx(np.array(expected))
    odom = np.array([ir.odom for ir in irs])
    assert odom[[1, 2, 3, 5, 6, 7, 9, 10, 11]] == pytest.approx(np.tile([0.0, 0.0, q], (9, 1)))
    # Stop 0's last heading 0.3 + 3 pi/2, then 1 m east: yaw change to 0 is -(0.3 + 3 pi/2),
    # wrapped to pi/2 - 0.3; the drive seen from the last heading is 1 m at -(0.3 + 3 pi/2).
    last = 0.3 + 3 * q
    assert odom[4] == pytest.approx([math.cos(last), -math.sin(last), q - 0.3])
    # Stop 1 ends at 3 pi/2 (south), drives 0.5 m north (backwards), turns to north: +-pi.
    assert odom[8, :2] == pytest.approx([-0.5, 0.0], abs=1e-9)
    assert abs(odom[8, 2]) == pytest.approx(math.pi)
