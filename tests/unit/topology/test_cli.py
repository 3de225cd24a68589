"""``uwbnet topology SCENARIO`` and ``uwbnet topology optimize``: real processes, small grids."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.cli import assert_one_line_error, last_json, uwbnet
from uwbnet.cli import main


def test_topology_scenario_prints_resolution_and_ghost(tmp_path: Path):
    png = tmp_path / "maps.png"
    proc = uwbnet(
        "topology", "foyer3", "--json", "--grid", "40", "--refs", "2", "2", "--png", str(png)
    )
    assert proc.returncode == 0, proc.stderr
    out = last_json(proc)
    assert len(proc.stdout.strip().splitlines()) == 1  # --json: only the JSON line
    assert 0.01 < out["resolution_m"] < 0.2  # a 3.35 GHz band: a few centimetres
    assert -60 < out["ghost_db"] < 0
    assert out["links"] == 6 * 12 and out["grid"] == [40, 40]
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert not list(tmp_path.glob("*.partial*"))


def test_topology_optimize_places_receivers_for_the_robot():
    proc = uwbnet(
        "topology",
        "optimize",
        "room_pillar",
        "--sensors",
        "1",
        "--json",
        "--grid",
        "20",
        "--refs",
        "1",
        "1",
        "--spacing",
        "4",
    )
    assert proc.returncode == 0, proc.stderr
    out = last_json(proc)
    assert out["kind"] == "receiver" and len(out["sites"]) == 1
    for key in ("naive", "optimized", "before"):
        assert {"resolution_m", "ghost_db", "cost"} <= set(out[key])
    assert out["optimized"]["cost"] <= out["naive"]["cost"] + 1e-6
    # The naive placement is among the re-ranked ones; when it wins, the output says so.
    finals = [r["final_cost"] for r in out["reranked"]]
    assert finals == sorted(finals) and out["optimized"]["cost"] == pytest.approx(
        finals[0], abs=0.02
    )
    if not out["improved"]:
        assert out["sites"] == out["naive_sites"] and "keeping naive" in out["verdict"]
    else:
        assert out["optimized"]["cost"] < out["naive"]["cost"]


@pytest.mark.parametrize(
    ("args", "fragments"),
    [
        (("topology", "optimize"), ("topology optimize SCENARIO --sensors K",)),
        (("topology", "optimize", "foyer3"), ("--sensors K",)),
        (("topology", "foyer3", "--sensors", "2"), ("belong to 'uwbnet topology optimize'",)),
        (("topology", "foyer3", "extra"), ("unexpected argument 'extra'",)),
        (("topology", "nosuch"), ("unknown scenario 'nosuch'",)),
        (("topology", "foyer3", "--grid", "3"), ("--grid must be",)),
        (("topology", "optimize", "foyer3", "--sensors", "999"), ("--sensors must be 1..",)),
    ],
)
def test_bad_input_gives_one_line(args, fragments, capsys):
    # In-process (the same main() the console script runs): one interpreter start per case
    # would cost ~5 s each on a busy machine. The first case also runs as a real process.
    assert main(list(args)) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "Traceback" not in err[0]
    for f in fragments:
        assert f in err[0], err[0]


def test_bad_input_as_a_process():
    assert_one_line_error(uwbnet("topology", "optimize"), "--sensors K")
