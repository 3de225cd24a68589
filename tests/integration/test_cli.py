"""The command line as a user runs it: real processes, real files, one-line errors."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

import sim_nodes
from tests.cli import assert_one_line_error, uwbnet

pytestmark = pytest.mark.integration


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("rec") / "r.mcap"
    proc = uwbnet("sim", "foyer3", "--duration", "4", "--seed", "3", "--out", str(out))
    assert proc.returncode == 0, proc.stderr
    summary = json.loads(proc.stdout.strip().splitlines()[-1])
    assert summary["messages"] == 4 * 50 * 7 + 7  # 6 ir + truth per frame, infos + schedule
    return out


def test_sim_track_eval_chain(recording: Path, tmp_path: Path) -> None:
    tracks = tmp_path / "t.jsonl"
    proc = uwbnet("track", str(recording), "--out", str(tracks))
    assert proc.returncode == 0, proc.stderr
    stats = json.loads(proc.stdout.strip().splitlines()[-1])
    assert stats["ir"] == 4 * 50 * 6
    assert stats["rejected"] == 0
    lines = [json.loads(x) for x in tracks.read_text().splitlines()]
    assert len(lines) == stats["updates"] >= 190
    assert all(set(line) >= {"t", "tracks"} for line in lines)
    assert all(set(tr) >= {"id", "x", "y", "vx", "vy"} for line in lines for tr in line["tracks"])
    proc = uwbnet("eval", "--truth", str(recording), "--tracks", str(tracks), "--skip", "1")
    assert proc.returncode == 0, proc.stderr
    result = json.loads(proc.stdout.strip().splitlines()[-1])
    for key in (
        "ospa_p1_mean",
        "ospa_p2_mean",
        "gospa_p2_mean",
        "card_correct_fraction",
        "id_switches",
        "rmse",
    ):
        assert key in result
    assert 0.0 <= result["ospa_p2_mean"] <= 1.0


def test_track_rejects_truncated_and_corrupt_recordings(recording: Path, tmp_path: Path) -> None:
    data = recording.read_bytes()
    truncated = tmp_path / "trunc.mcap"
    truncated.write_bytes(data[: len(data) // 2])
    out = tmp_path / "t.jsonl"
    proc = uwbnet("track", str(truncated), "--out", str(out))
    assert_one_line_error(proc, "uwbnet: error:", "trunc.mcap")
    assert not out.exists() and not Path(str(out) + ".partial").exists()

    corrupt = tmp_path / "corrupt.mcap"
    corrupt.write_bytes(b"\x89MCAP0\r\n" + bytes(range(256)) * 64)
    proc = uwbnet("track", str(corrupt), "--out", str(out))
    assert_one_line_error(proc, "uwbnet: error:")
    assert not out.exists()

    proc = uwbnet("track", str(tmp_path / "missing.mcap"), "--out", str(out))
    assert_one_line_error(proc, "no such recording")


def test_bad_scenario_file_gives_one_line_naming_the_field(tmp_path: Path) -> None:
    src = Path(sim_nodes.__file__).parent / "scenarios" / "foyer3.toml"
    bad = tmp_path / "bad.toml"
    text = src.read_text()
    bad.write_text(text + "\nfoo_unknown_key = 3\n")
    proc = uwbnet("sim", str(bad), "--duration", "1", "--out", str(tmp_path / "x.mcap"))
    assert_one_line_error(proc, "foo_unknown_key")
    assert not (tmp_path / "x.mcap").exists()

    proc = uwbnet("sim", "no_such_scenario", "--out", str(tmp_path / "x.mcap"))
    assert_one_line_error(proc, "no_such_scenario")


def test_usage_errors_are_one_line(tmp_path: Path) -> None:
    assert_one_line_error(uwbnet("sim"), "uwbnet: error:")
    assert_one_line_error(uwbnet("demo", "--duration", "-3"), "positive")
    assert_one_line_error(uwbnet("bench", "nope"), "invalid choice")
    proc = uwbnet("eval", "--truth", str(tmp_path / "no.mcap"), "--tracks", "x.jsonl")
    assert_one_line_error(proc, "no.mcap")


def test_eval_rejects_a_bad_tracks_file(recording: Path, tmp_path: Path) -> None:
    bad = tmp_path / "bad.jsonl"
    bad.write_text('{"t": 1.0, "tracks": []}\nnot json\n')
    proc = uwbnet("eval", "--truth", str(recording), "--tracks", str(bad))
    assert_one_line_error(proc, "bad.jsonl:2")


def test_help_of_every_command() -> None:
    for cmd in ("demo", "sim", "track", "eval", "bench", "channel"):
        proc = uwbnet(cmd, "--help")
        assert proc.returncode == 0
        assert "usage: uwbnet" in proc.stdout


@pytest.mark.slow
def test_demo_runs_records_and_the_recording_tracks(tmp_path: Path) -> None:
    rec = tmp_path / "demo.mcap"
    proc = uwbnet("demo", "--duration", "6", "--record", str(rec), timeout=120)
    assert proc.returncode == 0, proc.stderr
    summary = json.loads(proc.stdout.strip().splitlines()[-1])
    assert summary["nodes"] == 6
    assert summary["fusion_updates"] > 150
    assert summary["decode_errors"] == 0
    assert summary["handler_errors"] == 0
    assert rec.is_file()
    out = tmp_path / "t.jsonl"
    proc = uwbnet("track", str(rec), "--out", str(out))
    assert proc.returncode == 0, proc.stderr
    stats = json.loads(proc.stdout.strip().splitlines()[-1])
    assert stats["nodes"] == 6 and stats["ir"] > 1000 and stats["rejected"] == 0


def test_bad_scenario_geometry_is_one_line_naming_the_element(tmp_path: Path) -> None:
    src = Path(sim_nodes.__file__).parent / "scenarios" / "foyer3.toml"
    bad = tmp_path / "bad.toml"
    bad.write_text(
        src.read_text().replace("pose = [0.25, 4.5, 1.2, 0.0]", "pose = [0.01, 4.5, 1.2, 0.0]")
    )
    proc = uwbnet("sim", str(bad), "--duration", "1", "--out", str(tmp_path / "x.mcap"))
    assert_one_line_error(proc, "nodes[0].antennas.tx (bat1)", "inside walls[2]")
    assert not (tmp_path / "x.mcap").exists()
    # A [robot] scenario is simulated by sim_nodes.robot_record; its own options are checked.
    proc = uwbnet("sim", "room_pillar", "--stops", "0", "--out", str(tmp_path / "x.mcap"))
    assert_one_line_error(proc, "--stops must be at least 1")
    assert not (tmp_path / "x.mcap").exists()


def test_channel_dataset_params_and_plot(tmp_path: Path) -> None:
    import numpy as np

    out = tmp_path / "rp.npz"
    proc = uwbnet(
        "channel", "dataset", "room_pillar", "--stops", "2", "--workers", "1", "--out", str(out)
    )
    assert proc.returncode == 0, proc.stderr
    summary = json.loads(proc.stdout.strip().splitlines()[-1])
    assert summary["acquisitions"] == 240 and summary["frequencies"] == 1425
    with np.load(out) as z:
        assert z["response"].shape == (2, 120, 2, 1425)
        assert np.all(np.isfinite(z["response"])) and np.all(z["n_paths"] > 100)
    png = tmp_path / "office.png"
    csv = tmp_path / "paths.csv"
    proc = uwbnet(
        "channel", "params", "office", "--stop", "0", "--plot", str(png), "--paths", str(csv)
    )
    assert proc.returncode == 0, proc.stderr
    rows = csv.read_text().splitlines()
    assert rows[0].startswith("kind,order,delay_ns") and len(rows) > 500
    assert {r.split(",")[0] for r in rows[1:]} >= {"los", "reflected", "scattered"}
    fig = json.loads(proc.stdout.strip().splitlines()[-1])
    assert fig["hybrid"]["rms_delay_spread_ns"] > fig["ray_tracing"]["rms_delay_spread_ns"]
    assert png.stat().st_size > 10_000
    assert_one_line_error(uwbnet("channel", "params", "office", "--stop", "99"), "--stop")
    assert_one_line_error(
        uwbnet("channel", "dataset", "foyer3", "--out", str(tmp_path / "f.npz")), "no [robot]"
    )


def test_bench_names_of_the_parser_are_the_registered_benchmarks() -> None:
    from uwbnet.bench import BENCHES
    from uwbnet.cli import BENCH_NAMES, build_parser

    assert sorted(BENCH_NAMES) == sorted(BENCHES)
    for name in BENCH_NAMES:
        assert build_parser().parse_args(["bench", name]).name == name
