"""``uwbnet map``: a robot recording (the robot recorder, with odometry) to map.json and PNG."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from tests.cli import assert_one_line_error, last_json, uwbnet

pytestmark = pytest.mark.integration


@pytest.fixture(scope="module")
def robot_recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("robot") / "cls.mcap"
    proc = uwbnet("sim", "corridor_L_sparse", "--out", str(out), "--workers", "1", "--seed", "2")
    assert proc.returncode == 0, proc.stderr
    return out


def test_map_writes_walls_corners_points_and_trajectory(
    robot_recording: Path, tmp_path: Path
) -> None:
    out, png = tmp_path / "map.json", tmp_path / "map.png"
    proc = uwbnet(
        "map", str(robot_recording), "--out", str(out), "--png", str(png),
        "--particles", "20", "--association", "state", "--eval", "corridor_L_sparse",
        "--seed", "3",
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    stats = last_json(proc)
    doc = json.loads(out.read_text())
    assert set(doc) >= {"walls", "corners", "points", "trajectory"}
    assert doc["seed"] == 3
    assert stats["ir"] == 120 and len(doc["trajectory"]) == 120
    assert all(len(w) == 4 for w in doc["walls"]) and len(doc["walls"]) >= 2
    assert png.stat().st_size > 1000
    # The trajectory starts at the origin of the first-pose frame and stays near the truth.
    assert doc["trajectory"][0][1:] == [0.0, 0.0, 0.0]
    assert stats["eval"]["trajectory"]["rmse_m"] < 1.5
    assert not list(tmp_path.glob("*.partial*"))
    # the path and map are smoothed jointly (graph SLAM); eval_filter scores the filter's own
    assert stats["smoothed"] is True
    raw = stats["eval_filter"]
    # --no-smooth gives exactly the filter's map and path
    proc = uwbnet(
        "map", str(robot_recording), "--out", str(out), "--particles", "20",
        "--association", "state", "--eval", "corridor_L_sparse", "--seed", "3", "--no-smooth",
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    plain = last_json(proc)
    assert plain["smoothed"] is False and plain["eval_filter"] is None
    assert plain["eval"]["trajectory"]["rmse_m"] == raw["trajectory"]["rmse_m"]
    assert plain["eval"]["walls"] == raw["walls"]
    assert len(json.loads(out.read_text())["trajectory"]) == 120


def test_map_errors_are_one_line(robot_recording: Path, tmp_path: Path) -> None:
    out = tmp_path / "m.json"
    proc = uwbnet("map", str(tmp_path / "missing.mcap"), "--out", str(out))
    assert_one_line_error(proc, "no such recording")
    proc = uwbnet("map", str(robot_recording), "--out", str(out), "--particles", "0")
    assert_one_line_error(proc, "--particles")
    proc = uwbnet("map", str(robot_recording), "--out", str(out), "--robot", "nobody")
    assert_one_line_error(proc, "no ir of a mobile node")
    assert not out.exists()
