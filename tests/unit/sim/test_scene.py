"""Scenario files: the shipped foyer3, and one-line errors that name the bad field."""

from __future__ import annotations

import tomllib
from importlib import resources
from pathlib import Path

import pytest

from sim_nodes.scene import ScenarioError, load_scenario, parse_scenario, scenario_names


def _foyer3() -> dict:
    text = resources.files("sim_nodes.scenarios").joinpath("foyer3.toml").read_text()
    return tomllib.loads(text)


def test_foyer3_loads_by_name() -> None:
    sc = load_scenario("foyer3")
    assert sc.name == "foyer3"
    assert [n.id for n in sc.nodes] == [f"bat{i}" for i in range(1, 7)]
    assert [p.id for p in sc.people] == [1, 2, 3]
    assert all(n.role == "bat" for n in sc.nodes)
    assert sc.duration == 60.0
    assert sc.frame_period == 0.02
    assert sc.radar.fs == 7e9 and sc.radar.n == 4095 and sc.radar.f_high == 3.5e9
    assert "foyer3" in scenario_names()


def test_foyer3_loads_by_path(tmp_path: Path) -> None:
    path = tmp_path / "copy.toml"
    path.write_text(resources.files("sim_nodes.scenarios").joinpath("foyer3.toml").read_text())
    assert load_scenario(str(path)).name == "foyer3"


def _error(data: dict) -> str:
    with pytest.raises(ScenarioError) as info:
        parse_scenario(data, "test.toml")
    msg = str(info.value)
    assert "\n" not in msg
    assert isinstance(info.value, ValueError)
    return msg


def test_misspelt_key_names_the_field() -> None:
    data = _foyer3()
    data["radar"]["snr_bd"] = 20.0
    msg = _error(data)
    assert msg.startswith("test.toml: radar.snr_bd:")
    assert "unknown key" in msg


def test_misspelt_key_in_a_list_item_names_its_index() -> None:
    data = _foyer3()
    data["people"][1]["sped"] = 1.0
    assert "people[1].sped" in _error(data)


def test_wrong_type_names_the_field() -> None:
    data = _foyer3()
    data["people"][2]["speed"] = "fast"
    msg = _error(data)
    assert "people[2].speed" in msg
    assert "'fast'" in msg


def test_wrong_units_are_rejected() -> None:
    data = _foyer3()
    data["radar"]["fs"] = 7.0  # GHz instead of Hz
    assert "radar.fs" in _error(data)
    data = _foyer3()
    data["nodes"][0]["pose"][3] = 90.0  # degrees instead of radians
    msg = _error(data)
    assert "nodes[0].pose" in msg and "radians" in msg


def test_unknown_material_names_the_wall() -> None:
    data = _foyer3()
    data["walls"][3]["material"] = "glass"
    assert "walls[3].material" in _error(data)


def test_missing_required_key_and_bad_pose_length() -> None:
    data = _foyer3()
    del data["people"][0]["waypoints"]
    assert "people[0].waypoints" in _error(data)
    data = _foyer3()
    data["nodes"][4]["pose"] = [1.0, 2.0, 3.0]
    assert "nodes[4].pose" in _error(data)


def test_unknown_name_bad_toml_and_missing_file(tmp_path: Path) -> None:
    with pytest.raises(ScenarioError, match="unknown scenario 'nowhere'"):
        load_scenario("nowhere")
    bad = tmp_path / "bad.toml"
    bad.write_text("name = \n")
    with pytest.raises(ScenarioError, match=r"bad\.toml: not valid TOML"):
        load_scenario(str(bad))
    with pytest.raises(ScenarioError, match="cannot read"):
        load_scenario(str(tmp_path / "missing.toml"))


def test_cross_field_errors_name_the_nested_field() -> None:
    data = _foyer3()
    data["radar"]["f_high"] = 5e9  # above fs/2
    assert _error(data).startswith("test.toml: radar.f_high:")
    data = _foyer3()
    data["frame_period"] = 0.04  # 25 frames/s but 50 IR/s per transmitter
    assert _error(data).startswith("test.toml: radar.rate:")
    data = _foyer3()
    data["nodes"][1]["id"] = "bat1"
    assert "duplicate id 'bat1'" in _error(data)
