"""From a scenario to the hybrid channel: room faces, materials, configuration, robot data set.

The bridge between :mod:`sim_nodes.scene` (validated TOML) and the pure channel code in
:mod:`sim_nodes.channel` (numpy arrays only). See ``docs/channel.md``.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from sim_nodes.channel.antenna import AntennaPattern, HornPattern, OmniPattern, TablePattern
from sim_nodes.channel.hybrid import HybridChannel, HybridConfig
from sim_nodes.channel.materials import Material
from sim_nodes.channel.raytrace import AntennaArray
from sim_nodes.channel.room import CEILING, FLOOR, SOLID, WALL, FaceSpec, Room, vertical_face
from sim_nodes.channel.synth import frequency_response
from sim_nodes.scene import MaterialModel, Scenario, read_pattern_table


def _material(m: MaterialModel, thickness: float = 0.0) -> Material:
    return Material(
        permittivity=m.permittivity,
        conductivity=m.conductivity,
        metal=m.metal,
        transmission=m.transmission(),
        excess=thickness * (math.sqrt(m.permittivity) - 1),
    )


def room_from_scenario(scenario: Scenario) -> Room:
    """The faces and wedges of a scenario's walls, room outline, floor, ceiling and objects.

    Layout rules (sim_nodes.channel.room): ``[[walls]]`` are two-sided mid-plane faces from
    the floor to their height with wedges at free ends; ``[room]`` outline faces are the
    inner surfaces (normals into the room), floor and ceiling only if ``ceiling`` is set;
    ``[[objects]]`` are convex prisms with outward faces and a wedge at each vertical edge.
    """
    mats = scenario.materials
    faces: list[FaceSpec] = []
    materials: list[Material] = []
    wedges: list[tuple[float, float, float, float]] = []
    floor = scenario.room.floor if scenario.room else 0.0

    def add(vert: np.ndarray, normal: np.ndarray, mat: Material, two: bool, kind: int, name: str):
        materials.append(mat)
        faces.append(
            FaceSpec(
                vertices=vert,
                normal=normal,
                material=len(materials) - 1,
                two_sided=two,
                kind=kind,
                name=name,
            )
        )

    ends = [tuple(p) for w in scenario.walls for p in (w.start, w.end)]
    for i, w in enumerate(scenario.walls):
        d = np.subtract(w.end, w.start)
        vert, n = vertical_face(w.start, w.end, floor, w.height, [-d[1], d[0]])
        add(vert, n, _material(mats[w.material], w.thickness), True, WALL, f"walls[{i}]")
        for p in (w.start, w.end):
            # A wall end shared with another wall is a corner, not a free (diffracting) edge.
            if sum(math.dist(p, q) < 1e-2 for q in ends) == 1:
                wedges.append((p[0], p[1], floor, w.height))
    room = scenario.room
    if room is not None:
        outline = room.outline
        ccw = sum(a[0] * b[1] - b[0] * a[1] for a, b in itertools.pairwise(outline)) > 0
        mat = _material(mats[room.material], room.thickness)
        for j, (a, b) in enumerate(itertools.pairwise(outline)):
            e = np.subtract(b, a)
            inward = np.array([-e[1], e[0]]) * (1 if ccw else -1)
            vert, n = vertical_face(a, b, room.floor, room.top, inward)
            add(vert, n, mat, False, WALL, f"room.outline[{j}]")
        if room.ceiling is not None:
            xy = np.array(outline[:-1], float)
            for z, kind, key, sign in (
                (room.floor, FLOOR, room.floor_material, 1.0),
                (room.ceiling, CEILING, room.ceiling_material, -1.0),
            ):
                vert = np.concatenate([xy, np.full((len(xy), 1), z)], axis=1)
                name = "room.floor" if kind == FLOOR else "room.ceiling"
                m = _material(mats[key or room.material], room.thickness)
                add(vert, np.array([0.0, 0.0, sign]), m, False, kind, name)
    for i, o in enumerate(scenario.objects):
        xy = np.array(o.footprint[:-1], float)
        ccw = np.sum(xy[:, 0] * np.roll(xy[:, 1], -1) - np.roll(xy[:, 0], -1) * xy[:, 1]) > 0
        mat = _material(mats[o.material])
        z0, z1 = o.z
        for a, b in zip(xy, np.roll(xy, -1, axis=0), strict=True):
            e = b - a
            outward = np.array([e[1], -e[0]]) * (1 if ccw else -1)
            vert, n = vertical_face(a, b, z0, z1, outward)
            add(vert, n, mat, False, SOLID, f"objects[{i}] ({o.id})")
            wedges.append((a[0], a[1], z0, z1))
        for z, sign in ((z1, 1.0), (z0, -1.0)):
            if sign < 0 and z0 <= floor + 1e-6:
                continue  # standing on the floor: no bottom face
            vert = np.concatenate([xy, np.full((len(xy), 1), z)], axis=1)
            add(vert, np.array([0.0, 0.0, sign]), mat, False, SOLID, f"objects[{i}] ({o.id})")
    return Room.build(faces, tuple(materials), wedges)


def table_pattern(path: str) -> TablePattern:
    """A measured pattern table file (:func:`sim_nodes.scene.read_pattern_table`)."""
    az, el, gain = read_pattern_table(path)
    return TablePattern(np.array(az), np.array(el), np.array(gain, float))


def channel_band(scenario: Scenario) -> tuple[float, float]:
    """Band of the hybrid channel, Hz: ``[channel] band`` or the radar's (without DC)."""
    ch = scenario.channel
    if ch.band is not None:
        return float(ch.band[0]), float(ch.band[1])
    r = scenario.radar
    return max(r.f_low, r.highpass, 0.05 * r.f_high), float(r.f_high)


def hybrid_config(scenario: Scenario) -> HybridConfig:
    """The :class:`HybridConfig` of a scenario's ``[channel]`` section."""
    ch = scenario.channel
    f_lo, f_hi = channel_band(scenario)
    knots = (0.5 * (f_lo + f_hi),) if ch.knots == 1 else tuple(np.linspace(f_lo, f_hi, ch.knots))
    return HybridConfig(
        max_order=ch.reflection_order,
        scatter_order=ch.scatter_order,
        n_scatterers=ch.n_scatterers,
        radius=ch.scatter_radius,
        a=ch.scatter_a,
        p=ch.scatter_p,
        center_frequency=0.5 * (f_lo + f_hi),
        diffraction=ch.diffraction,
        diffraction_strength=ch.diffraction_strength,
        knots=tuple(float(k) for k in knots),
    )


def hybrid_channel(scenario: Scenario, rng: np.random.Generator) -> HybridChannel:
    """One realization of the scenario's hybrid channel (clusters drawn from ``rng``)."""
    return HybridChannel(room_from_scenario(scenario), hybrid_config(scenario), rng)


@dataclass(frozen=True, slots=True, kw_only=True)
class RobotDataset:
    """Frequency responses of a robot scenario (e.g. room_pillar).

    Attributes
    ----------
    frequencies : ndarray, float64, shape (K,), Hz
    stops : ndarray, float64, shape (S, 2), m
    headings : ndarray, float64, shape (S, H), rad
        World heading of every stop's acquisitions (``RobotModel.stop_headings``).
    response : ndarray, complex64, shape (S, H, 2, K)
        ``1/d``-scaled transfer functions of rx1 and rx2 (multiply by ``c / (4 pi f)``
        for the Friis scale).
    n_paths : ndarray, int, shape (S, H, 2)
    """

    frequencies: npt.NDArray[np.float64]
    stops: npt.NDArray[np.float64]
    headings: npt.NDArray[np.float64]
    response: npt.NDArray[np.complex64]
    n_paths: npt.NDArray[np.int64]


def robot_arrays(
    scenario: Scenario, stop: int
) -> tuple[AntennaArray, AntennaArray, npt.NDArray[np.float64]]:
    """Tx and the 2 H receivers (rx1 and rx2 for every heading) of the robot at a stop."""
    rb = scenario.robot
    if rb is None:
        raise ValueError(f"scenario {scenario.name!r} has no [robot]")
    if rb.pattern == "table":
        pattern: AntennaPattern = table_pattern(rb.pattern_table)
    elif rb.pattern == "horn":
        pattern = HornPattern(beamwidth=rb.beamwidth, f0=rb.beamwidth_frequency)
    else:
        pattern = OmniPattern()
    x, y = rb.stops[stop]
    heads = rb.stop_headings()[stop]
    side = np.array([0.5, -0.5]) * rb.baseline
    # Receiver index 2 h + j: heading h, rx(j+1) at (0, side_j) in the robot frame.
    rx_pos = np.stack(
        [
            x - np.sin(heads)[:, None] * side,
            y + np.cos(heads)[:, None] * side,
            np.full((heads.size, 2), rb.height),
        ],
        axis=-1,
    ).reshape(-1, 3)
    tx = AntennaArray(position=np.array([[x, y, rb.height]]), yaw=np.zeros(1), pattern=pattern)
    rx = AntennaArray(position=rx_pos, yaw=np.repeat(heads, 2), pattern=pattern)
    return tx, rx, heads


def robot_dataset(
    scenario: Scenario,
    channel: HybridChannel,
    *,
    stops: list[int] | None = None,
    scatterers: bool = True,
) -> RobotDataset:
    """Transfer functions of every stop and heading of a robot scenario.

    The transmitter sits at the robot's origin, so turning on the spot moves only the
    receivers: the image tree is built once per stop and all ``2 n_headings`` receivers are
    traced and synthesised together, each with the Tx boresight of its heading.
    """
    f_lo, f_hi = channel_band(scenario)
    step = scenario.channel.frequency_step or 6.25e6
    n_freq = math.floor((f_hi - f_lo) / step + 1e-9) + 1
    freqs = f_lo + step * np.arange(n_freq)
    idx = list(range(len(scenario.robot.stops))) if stops is None else stops
    n_h = scenario.robot.n_headings
    resp = np.zeros((len(idx), n_h, 2, n_freq), np.complex64)
    n_paths = np.zeros((len(idx), n_h, 2), np.int64)
    for i, s in enumerate(idx):
        tx, rx, heads = robot_arrays(scenario, s)
        paths = channel.paths(tx, rx, scatterers=scatterers, tx_yaw=np.repeat(heads, 2))
        h = frequency_response(paths, rx.position.shape[0], f_lo, step, n_freq)
        resp[i] = h.reshape(n_h, 2, n_freq)
        n_paths[i] = np.bincount(paths.rx, minlength=rx.position.shape[0]).reshape(n_h, 2)
    return RobotDataset(
        frequencies=freqs,
        stops=np.array([scenario.robot.stops[s] for s in idx], float),
        headings=scenario.robot.stop_headings()[idx],
        response=resp,
        n_paths=n_paths,
    )
