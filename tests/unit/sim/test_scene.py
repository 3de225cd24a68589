"""Scenario files: the shipped foyer3, and one-line errors that name the bad field."""

from __future__ import annotations

import tomllib
from importlib import resources
from pathlib import Path

import numpy as np
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


# --- issue 3: room geometry, objects, robot, channel model ---------------------------------


def _room_pillar() -> dict:
    text = resources.files("sim_nodes.scenarios").joinpath("room_pillar.toml").read_text()
    return tomllib.loads(text)


def test_room_pillar_is_the_chapter_data_set() -> None:
    sc = load_scenario("room_pillar")
    rb = sc.robot
    assert sc.channel.model == "hybrid" and sc.channel.band == [4.5e9, 13.4e9]
    assert sc.room is not None and sc.room.ceiling == 4.0 and sc.room.top == 4.0
    assert sc.objects[0].id == "pillar" and len(sc.objects) == 7
    assert len(rb.stops) * rb.n_headings == 9360
    assert rb.n_headings * rb.heading_step == pytest.approx(2 * 3.141592653589793)
    assert not sc.nodes
    assert {"office", "room_pillar", "foyer3"} <= set(scenario_names())


def test_open_polygon_names_the_element() -> None:
    data = _room_pillar()
    data["room"]["outline"] = data["room"]["outline"][:-1]
    msg = _error(data)
    assert msg.startswith("test.toml: room.outline:") and "polygon is open" in msg
    data = _room_pillar()
    data["objects"][3]["footprint"].pop()
    msg = _error(data)
    assert "objects[3].footprint" in msg and "open" in msg


def test_non_convex_footprint_and_self_intersecting_outline() -> None:
    data = _room_pillar()
    data["objects"][0]["footprint"] = [[0, 0], [2, 0], [1, 0.5], [1, 2], [0, 0]]
    assert "convex" in _error(data)
    data = _room_pillar()
    data["room"]["outline"] = [[0, 0], [9, 8], [9, 0], [0, 8], [0, 0]]
    assert "intersects itself" in _error(data)


def test_zero_thickness_wall_names_the_wall() -> None:
    data = _foyer3()
    data["walls"][2]["thickness"] = 0.0
    msg = _error(data)
    assert msg.startswith("test.toml: walls[2].thickness:") and "zero-thickness" in msg
    data = _room_pillar()
    data["room"]["thickness"] = 0.0
    assert "room.thickness" in _error(data)


def test_antenna_inside_a_wall_or_object_names_both() -> None:
    data = _foyer3()
    data["nodes"][0]["pose"] = [0.01, 4.5, 1.2, 0.0]  # in the west wall's slab
    msg = _error(data)
    assert "nodes[0].antennas.tx (bat1)" in msg and "inside walls[2]" in msg
    data = _foyer3()
    data["nodes"][0]["antennas"] = {"rx1": {"pos": [0.0, 0.0, 5.0]}}  # above the 3 m wall
    parse_scenario(data)  # over the top of the wall is free space
    data = _room_pillar()
    data["robot"]["stops"][5] = [4.5, 4.0]  # in the pillar
    msg = _error(data)
    assert "robot.stops[5]" in msg and "objects[0] (pillar)" in msg
    data = _room_pillar()
    data["robot"]["stops"][7] = [0.3, 6.0]  # receivers reach into the west wall
    msg = _error(data)
    assert "robot.stops[7]" in msg and "room's wall" in msg
    data = _room_pillar()
    data["robot"]["height"] = 4.5
    assert "outside the room's floor..ceiling" in _error(data)


def test_channel_model_options_are_validated() -> None:
    data = _foyer3()
    data["channel"]["model"] = "raytrace"
    assert "channel.model" in _error(data)
    data = _foyer3()
    data["channel"]["model"] = "image2d"
    data["channel"]["reflection_order"] = 3
    assert "channel.reflection_order" in _error(data)
    data["channel"]["model"] = "hybrid"
    assert parse_scenario(data).channel.reflection_order == 3
    data = _room_pillar()
    data["channel"]["band"] = [13.4, 4.5]
    assert "channel.band" in _error(data)
    data = _room_pillar()
    del data["robot"]
    assert "nodes" in _error(data)


def test_materials_derive_fresnel_defaults() -> None:
    data = _room_pillar()
    data["materials"]["glass"] = {"permittivity": 6.25}
    sc = parse_scenario(data)
    assert sc.materials["metal"].gamma() == -1.0 and sc.materials["metal"].transmission() == 0.0
    assert sc.materials["glass"].gamma() == pytest.approx(-1.5 / 3.5)
    assert sc.materials["glass"].transmission() == pytest.approx(1 - (1.5 / 3.5) ** 2)


def test_measured_pattern_table_is_read_relative_to_the_scenario(tmp_path: Path) -> None:
    import numpy as np

    from sim_nodes.channel.antenna import TablePattern
    from sim_nodes.propagation import robot_arrays

    rows = ["azimuth_deg, elevation_deg, gain_db"]
    for el in (-45, 45):
        rows += [f"{az}, {el}, {-abs(az) / 10}" for az in range(-180, 180, 30)]
    (tmp_path / "horn.csv").write_text("\n".join(rows) + "\n")
    text = resources.files("sim_nodes.scenarios").joinpath("office.toml").read_text()
    scen = tmp_path / "office_table.toml"
    scen.write_text(
        text.replace('pattern = "omni"', 'pattern = "table"\npattern_table = "horn.csv"')
    )
    tx, _, _ = robot_arrays(load_scenario(str(scen)), 0)
    assert isinstance(tx.pattern, TablePattern)
    db = 20 * np.log10(tx.pattern.amplitude(np.radians([0.0, 90.0, 165.0]), 0.0, 9e9))
    np.testing.assert_allclose(db, [0.0, -9.0, -16.5], atol=1e-9)
    (tmp_path / "horn.csv").write_text("\n".join(rows[:-1]) + "\n")  # one point missing
    with pytest.raises(ScenarioError, match=r"robot\.pattern_table: horn\.csv: not a full"):
        load_scenario(str(scen))
    scen.write_text(text.replace('pattern = "omni"', 'pattern = "table"'))
    with pytest.raises(ScenarioError, match=r"robot\.pattern_table"):
        load_scenario(str(scen))


# --- issue 8: where each stop's turn starts ---------------------------------------------------


def test_robot_turns_start_at_world_heading_zero_by_default() -> None:
    rb = load_scenario("room_pillar").robot
    heads = rb.stop_headings()
    assert rb.turn_start == "world" and heads.shape == (len(rb.stops), rb.n_headings)
    turn = np.arange(rb.n_headings) * rb.heading_step
    assert np.array_equal(heads, np.tile(turn, (len(rb.stops), 1)))


def test_drive_turns_start_where_the_robot_drove() -> None:
    data = _room_pillar()
    # Three stops: east 1 m, then north-west; the third stop repeats the second.
    data["robot"] |= {
        "stops": [[2.0, 1.0], [3.0, 1.0], [2.0, 2.0], [2.0, 2.0]],
        "turn_start": "drive",
        "first_heading": 0.4,
    }
    heads = parse_scenario(data).robot.stop_headings()
    step = data["robot"]["heading_step"]
    start = heads - np.arange(heads.shape[1]) * step
    assert start == pytest.approx(np.repeat([[0.4], [0.0], [0.75 * np.pi], [0.75 * np.pi]], 120, 1))
    data["robot"].pop("first_heading")
    assert parse_scenario(data).robot.stop_headings()[0, 0] == 0.0


def test_turn_start_options_are_validated() -> None:
    data = _room_pillar()
    data["robot"]["first_heading"] = 0.5  # only with turn_start = "drive"
    assert _error(data).startswith("test.toml: robot.first_heading: applies only with")
    data["robot"] |= {"turn_start": "sideways"}
    assert "robot.turn_start" in _error(data)
    data["robot"] |= {"turn_start": "drive", "first_heading": 7.0}
    assert "robot.first_heading" in _error(data)
