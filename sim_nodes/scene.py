"""Scenario files: rooms, walls, materials, sensor nodes and walking people (TOML).

A scenario is a TOML file validated by the pydantic models below (``extra="forbid"``:
a misspelt key is an error; strict types: a string where a number belongs is an error;
SI units, with range checks that catch the usual slips such as GHz for Hz or degrees
for radians). :func:`load_scenario` takes a shipped name (``"foyer3"``) or a path and
raises :class:`ScenarioError` with a one-line message naming the bad field.

Example (abridged; see ``sim_nodes/scenarios/foyer3.toml``)::

    name = "foyer3"
    duration = 60.0
    frame_period = 0.02
    [radar]
    snr_db = 40.0
    [materials.concrete]
    reflection = -0.5
    transmission_loss_db = 15.0
    [[walls]]
    start = [0.0, 0.0]
    end = [12.0, 0.0]
    material = "concrete"
    [[nodes]]
    id = "bat1"
    role = "bat"
    pose = [0.2, 4.5, 1.2, 0.0]
    [[people]]
    id = 1
    waypoints = [[1.0, 1.5], [11.0, 7.5]]
    speed = 1.3
"""

from __future__ import annotations

import itertools
import math
import tomllib
from importlib import resources
from pathlib import Path
from typing import Annotated, Literal

import numpy as np
from pydantic import (
    AfterValidator,
    BaseModel,
    ConfigDict,
    Field,
    ValidationError,
    field_validator,
    model_validator,
)

from sim_nodes.radar import RadarConfig

#: Bat-node antennas: name -> (position in the node frame [m], transmits, receives).
BAT_ANTENNAS: dict[str, tuple[tuple[float, float, float], bool, bool]] = {
    "tx": ((0.0, 0.0, 0.0), True, False),
    "rx1": ((0.0, 0.5, 0.0), False, True),
    "rx2": ((0.0, -0.5, 0.0), False, True),
}


class ScenarioError(ValueError):
    """A scenario file is missing, not TOML, or fails validation (one-line message)."""


class _FieldError(ValueError):
    """A cross-field check failure that names its field itself."""

    def __init__(self, field: str, message: str) -> None:
        super().__init__(f"{field}: {message}")
        self.field = field


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True, frozen=True)


Point2 = Annotated[list[float], Field(min_length=2, max_length=2)]
Point3 = Annotated[list[float], Field(min_length=3, max_length=3)]


class RadarModel(_Model):
    """``[radar]``: the M-sequence radar (see :class:`sim_nodes.radar.RadarConfig`)."""

    fs: float = 7e9
    n: int = 4095
    t0: float = 0.0
    f_low: float = Field(0.0, ge=0.0)
    f_high: float = 3.5e9
    rate: float = Field(50.0, gt=0.0)
    highpass: float = Field(1.5e8, ge=0.0)
    rolloff: float = Field(0.2, gt=0.0, le=1.0)
    snr_db: float = Field(40.0, ge=-30.0, le=120.0)
    snr_reference_distance: float = Field(5.0, gt=0.0)
    snr_reference_rcs: float = Field(1.0, gt=0.0)
    noise: bool = True

    @field_validator("fs")
    @classmethod
    def _fs_in_hz(cls, v: float) -> float:
        if v < 1e6:
            raise ValueError(f"sample rate must be in Hz (e.g. 7e9), got {v}")
        return v

    @field_validator("f_high", "f_low", "highpass")
    @classmethod
    def _band_in_hz(cls, v: float) -> float:
        if 0 < v < 1e3:
            raise ValueError(f"frequency must be in Hz (e.g. 3.5e9), got {v}")
        return v

    @field_validator("n")
    @classmethod
    def _n_mlbs(cls, v: int) -> int:
        if v != 4095:
            raise ValueError(f"only the 12-stage M-sequence (4095 chips) is modelled, got {v}")
        return v

    @model_validator(mode="after")
    def _band(self) -> RadarModel:
        if not self.f_low < self.f_high <= self.fs / 2:
            raise _FieldError("f_high", "band must satisfy f_low < f_high <= fs/2 (baseband)")
        if abs(self.t0) >= self.n / self.fs:
            raise _FieldError("t0", f"must be seconds within one period {self.n / self.fs:.3g}")
        return self

    def config(self) -> RadarConfig:
        """The radar model's parameters."""
        return RadarConfig(**self.model_dump())


class ChannelModel(_Model):
    """``[channel]``: propagation model and body-model settings.

    ``model = "image2d"`` (default) is the issue-2 channel: vertical walls only, specular
    reflections up to order 2 with scalar reflection factors. ``model = "hybrid"`` is the
    Section 3 hybrid channel (:mod:`sim_nodes.channel.hybrid`): 3-D ray tracing up to order 5
    with Fresnel reflection, transmission, wedge diffraction, antenna patterns and the
    stochastic scatterer clusters of eq. (1)-(3) (N, r, a, p below).
    """

    model: Literal["image2d", "hybrid"] = "image2d"
    reflection_order: int = Field(2, ge=0, le=5)
    scatter_order: int = Field(3, ge=0, le=5)
    n_scatterers: int = Field(16, ge=0, le=256)
    scatter_radius: float = Field(1.0, gt=0.0, le=10.0)
    scatter_a: float = Field(0.2, ge=0.0, le=1.0)
    scatter_p: float = Field(0.03, ge=0.0, le=1.0)
    diffraction: bool = True
    diffraction_strength: float = Field(0.5, ge=0.0, le=10.0)
    band: Annotated[list[float], Field(min_length=2, max_length=2)] | None = None
    frequency_step: float | None = Field(None, gt=0.0)
    knots: int = Field(4, ge=1, le=32)
    shadow_db: float = Field(18.0, ge=0.0, le=60.0)
    fluctuation_time: float = Field(0.1, gt=0.0)
    breathing_amplitude: float = Field(0.005, ge=0.0, le=0.05)
    breathing_rate: float = Field(0.25, gt=0.0, le=1.0)
    gait_amplitude: float = Field(0.05, ge=0.0, le=0.3)

    @model_validator(mode="after")
    def _orders(self) -> ChannelModel:
        if self.model == "image2d" and self.reflection_order > 2:
            raise _FieldError("reflection_order", "the image2d model goes to order 2 (use hybrid)")
        if self.band is not None and not 1e6 <= self.band[0] < self.band[1]:
            raise _FieldError("band", f"must be [f_low, f_high] in Hz, increasing, got {self.band}")
        return self


class MaterialModel(_Model):
    """``[materials.NAME]``: a surface material.

    ``permittivity`` (relative, eps_r) delays a wave crossing a wall of thickness ``d`` by
    ``d (sqrt(eps_r) - 1) / c``; the default 1 ignores that delay. The hybrid model reflects
    by the Fresnel equations from ``permittivity`` and ``conductivity`` (S/m); ``metal``
    makes a perfect conductor. ``reflection`` (the image2d model's signed Gamma) and
    ``transmission_loss_db`` (one-way, per wall) default to values derived from those.
    """

    reflection: float | None = Field(None, ge=-1.0, le=1.0)
    transmission_loss_db: float | None = Field(None, ge=0.0, le=200.0)
    permittivity: float = Field(1.0, ge=1.0, le=100.0)
    conductivity: float = Field(0.0, ge=0.0, le=1e8)
    metal: bool = False

    def gamma(self) -> float:
        """Signed normal-incidence reflection factor (given, or -(n-1)/(n+1); metal -1)."""
        if self.reflection is not None:
            return self.reflection
        if self.metal:
            return -1.0
        n = math.sqrt(self.permittivity)
        return -(n - 1) / (n + 1)

    def transmission(self) -> float:
        """One-way amplitude transmission factor (given loss, or 1 - Gamma^2; metal 0)."""
        if self.transmission_loss_db is not None:
            return 10 ** (-self.transmission_loss_db / 20)
        return 0.0 if self.metal else 1.0 - self.gamma() ** 2


def _nonzero_thickness(v: float) -> float:
    if v < 1e-3:
        raise ValueError(f"zero-thickness wall: thickness must be at least 1 mm, got {v}")
    return v


#: Thickness of a wall or of a room's outline walls, m: a wall needs some (ray tracing
#: and the scene checks place antennas against both faces).
WallThickness = Annotated[float, Field(ge=0.0, le=2.0), AfterValidator(_nonzero_thickness)]


class WallModel(_Model):
    """``[[walls]]``: a vertical wall on the 2-D segment start-end."""

    start: Point2
    end: Point2
    height: float = Field(3.0, gt=0.0, le=50.0)
    thickness: WallThickness = 0.2
    material: str

    @model_validator(mode="after")
    def _length(self) -> WallModel:
        if math.dist(self.start, self.end) < 1e-6:
            raise ValueError("wall start and end coincide")
        return self


def _closed_polygon(v: list[list[float]], what: str) -> list[list[float]]:
    """Check a polygon given with its first vertex repeated at the end; no repeated points."""
    if math.dist(v[0], v[-1]) > 1e-9:
        raise ValueError(
            f"{what} polygon is open: first vertex {v[0]} != last vertex {v[-1]} "
            "(repeat the first vertex to close it)"
        )
    if len(v) < 4:
        raise ValueError(f"{what} polygon needs at least 3 distinct vertices")
    for i, (a, b) in enumerate(itertools.pairwise(v)):
        if math.dist(a, b) < 1e-6:
            raise ValueError(f"{what} polygon has a zero-length edge at vertex {i}")
    return v


def _signed_area(v: list[list[float]]) -> float:
    return 0.5 * sum(a[0] * b[1] - b[0] * a[1] for a, b in itertools.pairwise(v))


def _self_intersects(v: list[list[float]]) -> bool:
    def cross(o: list[float], a: list[float], b: list[float]) -> float:
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])

    edges = list(itertools.pairwise(v))
    for i, j in itertools.combinations(range(len(edges)), 2):
        if j == i + 1 or (i == 0 and j == len(edges) - 1):
            continue
        (a, b), (c, d) = edges[i], edges[j]
        if cross(a, b, c) * cross(a, b, d) < 0 and cross(c, d, a) * cross(c, d, b) < 0:
            return True
    return False


class RoomModel(_Model):
    """``[room]``: a room given by its inner outline (closed polygon), floor and ceiling.

    The walls of the outline are ``thickness`` thick outward of the outline. Without
    ``ceiling`` the room is 2-D: walls of ``height`` only, no floor or ceiling reflections.
    """

    outline: Annotated[list[Point2], Field(min_length=4)]
    material: str
    thickness: WallThickness = 0.2
    floor: float = 0.0
    ceiling: float | None = None
    height: float = Field(3.0, gt=0.0, le=50.0)
    floor_material: str | None = None
    ceiling_material: str | None = None

    @field_validator("outline")
    @classmethod
    def _closed(cls, v: list[list[float]]) -> list[list[float]]:
        _closed_polygon(v, "outline")
        if _self_intersects(v):
            raise ValueError("outline polygon intersects itself")
        return v

    @model_validator(mode="after")
    def _heights(self) -> RoomModel:
        if self.ceiling is not None and self.ceiling <= self.floor + 0.1:
            raise _FieldError("ceiling", f"must be above the floor ({self.floor}) by > 0.1 m")
        return self

    @property
    def top(self) -> float:
        """Height of the walls' top edge, m."""
        return self.ceiling if self.ceiling is not None else self.floor + self.height


class ObjectModel(_Model):
    """``[[objects]]``: a solid (pillar, cabinet, table) over a closed convex footprint."""

    id: str = Field(pattern=r"^[A-Za-z0-9_-]+$")
    footprint: Annotated[list[Point2], Field(min_length=4)]
    z: Annotated[list[float], Field(min_length=2, max_length=2)]
    material: str

    @field_validator("footprint")
    @classmethod
    def _convex(cls, v: list[list[float]]) -> list[list[float]]:
        _closed_polygon(v, "footprint")
        pts = v[:-1]
        turns = [
            (b[0] - a[0]) * (c[1] - b[1]) - (b[1] - a[1]) * (c[0] - b[0])
            for a, b, c in zip(pts, pts[1:] + pts[:1], pts[2:] + pts[:2], strict=True)
        ]
        if not (all(t > 1e-12 for t in turns) or all(t < -1e-12 for t in turns)):
            raise ValueError("footprint polygon must be convex (split it into convex objects)")
        return v

    @field_validator("z")
    @classmethod
    def _z(cls, v: list[float]) -> list[float]:
        if not v[1] > v[0] + 1e-3:
            raise ValueError(f"z must be [bottom, top] with top > bottom, got {v}")
        return v


class AntennaOverride(_Model):
    """``[nodes.antennas.NAME]``: override of a default antenna's geometry or pattern.

    ``pattern_table`` (a CSV file, see :func:`read_pattern_table`, relative to the scenario
    file) replaces the horn in the hybrid channel; the image2d model uses ``beamwidth``.
    """

    pos: Point3 | None = None
    boresight: float | None = Field(None, ge=-2 * math.pi, le=2 * math.pi)
    beamwidth: float | None = Field(None, gt=0.0, le=2 * math.pi)
    pattern_table: str | None = None


class NodeModel(_Model):
    """``[[nodes]]``: a static sensor node."""

    id: str = Field(pattern=r"^[A-Za-z0-9_-]+$")
    role: Literal["bat"] = "bat"
    pose: Annotated[list[float], Field(min_length=4, max_length=4)]
    antennas: dict[str, AntennaOverride] = Field(default_factory=dict)

    @field_validator("pose")
    @classmethod
    def _yaw_rad(cls, v: list[float]) -> list[float]:
        if abs(v[3]) > 2 * math.pi:
            raise ValueError(f"yaw must be in radians within [-2pi, 2pi], got {v[3]}")
        return v

    @field_validator("antennas")
    @classmethod
    def _known_antennas(cls, v: dict[str, AntennaOverride]) -> dict[str, AntennaOverride]:
        unknown = sorted(set(v) - {"tx", "rx1", "rx2"})
        if unknown:
            raise ValueError(f"unknown antenna {unknown[0]!r} (a bat node has tx, rx1, rx2)")
        return v


class RobotModel(_Model):
    """``[robot]``: a bat-type robot that stops and turns on the spot (a data-set scenario).

    At each stop (x, y) it turns through ``n_headings`` headings ``start + k heading_step``
    (rad) and records one acquisition per heading with its ``tx`` and the two receivers at
    (0, +-``baseline``/2) in its frame, all at ``height``. ``turn_start`` sets ``start``:
    ``"world"`` (the default) 0 at every stop; ``"drive"`` the heading of the straight drive
    that reached the stop (``atan2`` of the step from the previous stop), as a robot that turns
    from the direction it arrived in; the first stop starts at ``first_heading`` (rad, default
    0), a stop at the previous stop's position keeps the previous start.
    """

    id: str = Field("robot", pattern=r"^[A-Za-z0-9_-]+$")
    stops: Annotated[list[Point2], Field(min_length=1)]
    height: float = Field(1.0, gt=0.0, le=10.0)
    heading_step: float = Field(math.radians(3.0), gt=0.0, le=2 * math.pi)
    n_headings: int = Field(120, ge=1, le=3600)
    baseline: float = Field(1.0, gt=0.0, le=5.0)
    pattern: Literal["omni", "horn", "table"] = "horn"
    beamwidth: float = Field(math.radians(60.0), gt=0.0, le=2 * math.pi)
    beamwidth_frequency: float = Field(9e9, ge=0.0)
    pattern_table: str | None = None
    turn_start: Literal["world", "drive"] = "world"
    first_heading: float | None = Field(None, ge=-2 * math.pi, le=2 * math.pi)

    @model_validator(mode="after")
    def _table(self) -> RobotModel:
        if (self.pattern == "table") != (self.pattern_table is not None):
            raise _FieldError("pattern_table", 'give a table file exactly when pattern = "table"')
        if self.first_heading is not None and self.turn_start != "drive":
            raise _FieldError("first_heading", 'applies only with turn_start = "drive"')
        return self

    def stop_headings(self) -> np.ndarray:
        """World headings (rad) of every stop's acquisitions, shape (stops, n_headings).

        Row ``s`` is ``start_s + k heading_step`` with ``start_s`` from ``turn_start`` (class
        docstring): 0, or the drive direction ``atan2(dy, dx)`` from stop ``s - 1`` to ``s``.
        """
        stops = np.asarray(self.stops, float)
        start = np.zeros(len(stops))
        if self.turn_start == "drive":
            start[0] = self.first_heading or 0.0
            d = np.diff(stops, axis=0)
            moved = np.hypot(d[:, 0], d[:, 1]) > 1e-9
            drive = np.arctan2(d[:, 1], d[:, 0])
            for s in range(1, len(stops)):  # a stop that did not move keeps the last start
                start[s] = drive[s - 1] if moved[s - 1] else start[s - 1]
        return start[:, None] + np.arange(self.n_headings) * self.heading_step


class AnchorModel(_Model):
    """``[[anchors]]``: a fixed ranging node (one omnidirectional antenna) at a known position."""

    id: str = Field(pattern=r"^[A-Za-z0-9_-]+$")
    position: Point3


class MobileModel(_Model):
    """``[[mobiles]]``: a mobile ranging node moving along a closed ``track`` of corners at
    ``speed``, pausing ``pause`` s at each corner (static intervals for the eq. (6) test),
    its antenna at ``height``."""

    id: str = Field(pattern=r"^[A-Za-z0-9_-]+$")
    track: Annotated[list[Point2], Field(min_length=1)]
    speed: float = Field(0.5, ge=0.0, le=5.0)
    pause: float = Field(0.0, ge=0.0)
    height: float = Field(1.0, gt=0.0, le=10.0)


class RangingModel(_Model):
    """``[ranging]``: the node-to-node RTToA link (docs/localization.md).

    The radar samples ``n`` points at ``fs`` over [f_low, f_high] (``fc`` > 0: complex baseband);
    ``snr_db`` is the unobstructed direct path's peak over the noise sigma at
    ``reference_distance``; ``rate`` ranging rounds per second per mobile node; ``scheme``
    ``ds`` (double-sided, drift-tolerant) or ``ss`` (single-sided) two-way ranging with
    ``reply_delay`` and node clocks off by up to ``clock_ppm``; the multipath of each link is
    an 802.15.4a ``environment`` realization, redrawn every round while the node moves and
    every ``coherence_time`` s while it stands still. The floor (z = 0, or ``[room]``'s
    ``floor``) reflects with ``floor_material`` (or the room's; default a concrete floor,
    eps_r 6), the ceiling only when ``[room]`` gives one (sim_nodes/ranging.py).
    """

    fs: float = Field(7.0e9, gt=0.0)
    n: int = Field(512, ge=64, le=16384)
    f_low: float = Field(0.0, ge=0.0)
    f_high: float = Field(3.5e9, gt=0.0)
    fc: float = Field(0.0, ge=0.0)
    snr_db: float = Field(40.0, ge=-20.0, le=120.0)
    reference_distance: float = Field(1.0, gt=0.0)
    rate: float = Field(10.0, gt=0.0, le=1000.0)
    scheme: Literal["ds", "ss"] = "ds"
    reply_delay: float = Field(1e-3, gt=0.0, le=1.0)
    clock_ppm: float = Field(20.0, ge=0.0, le=1000.0)
    environment: Literal["office", "residential"] = "residential"
    coherence_time: float = Field(1.0, gt=0.0)
    method: Literal["mpd", "threshold", "adaptive", "peak", "ml"] = "adaptive"
    floor_material: str | None = None


class CircleScanModel(_Model):
    """``[circle_scan]``: a bat-type sensor circling one object (Section 7; a data-set kind).

    The object is a vertical prism over ``target`` (a closed polygon, convex or not, m) of
    ``material`` with surface ``roughness`` (0 smooth). The sensor stops every ``step`` rad on
    a circle (``span`` < 2 pi: a partial circle from ``start``) of ``radius`` around
    ``centre``, boresight to the centre, with V, H and 45-degree polarized transmit and
    receive antennas ``baseline`` apart (see :mod:`sim_nodes.circle_scan`).
    """

    id: str = Field("scan", pattern=r"^[A-Za-z0-9_-]+$")
    target: Annotated[list[Point2], Field(min_length=4)]
    material: str
    roughness: float = Field(0.0, ge=0.0, le=1.0)
    centre: Point2 = Field(default_factory=lambda: [0.0, 0.0])
    radius: float = Field(1.0, gt=0.05, le=20.0)
    start: float = Field(0.0, ge=-2 * math.pi, le=2 * math.pi)
    span: float = Field(2 * math.pi, gt=0.0, le=2 * math.pi)
    step: float = Field(math.pi / 180, gt=0.0, le=math.pi / 4)
    baseline: float = Field(0.1, gt=0.0, le=2.0)
    height: float = Field(1.0, gt=0.0, le=10.0)
    beamwidth: float = Field(math.radians(70.0), gt=0.0, le=2 * math.pi)

    @field_validator("target")
    @classmethod
    def _simple(cls, v: list[list[float]]) -> list[list[float]]:
        _closed_polygon(v, "target")
        if _self_intersects(v):
            raise ValueError("target polygon intersects itself")
        return v

    @model_validator(mode="after")
    def _outside(self) -> CircleScanModel:
        far = max(math.dist(self.centre, p) for p in self.target)
        if far >= self.radius - 0.05:
            raise _FieldError(
                "radius", f"the track must clear the target by 5 cm (reach {far:.3g} m)"
            )
        return self


class PersonModel(_Model):
    """``[[people]]``: a person walking waypoints."""

    id: int = Field(ge=0)
    waypoints: Annotated[list[Point2], Field(min_length=2)]
    speed: float = Field(1.2, gt=0.0, le=5.0)
    mode: Literal["bounce", "once"] = "bounce"
    enter: float = Field(0.0, ge=0.0)
    leave: float | None = None
    radius: float = Field(0.25, gt=0.0, le=1.0)
    rcs: float = Field(1.0, gt=0.0, le=10.0)
    height: float = Field(1.2, gt=0.0, le=2.5)
    n_scatterers: int = Field(6, ge=5, le=8)

    @model_validator(mode="after")
    def _times(self) -> PersonModel:
        if self.leave is not None and self.leave <= self.enter:
            raise ValueError("leave must be after enter")
        if any(math.dist(a, b) < 1e-6 for a, b in itertools.pairwise(self.waypoints)):
            raise ValueError("consecutive waypoints coincide")
        return self


class Scenario(_Model):
    """A simulation scenario (the top level of a scenario TOML file)."""

    name: str
    description: str = ""
    net: str = Field("demo", pattern=r"^[A-Za-z0-9_-]+$")
    duration: float = Field(60.0, gt=0.0)
    frame_period: float = Field(0.02, gt=0.0, le=10.0)
    radar: RadarModel = Field(default_factory=RadarModel)
    channel: ChannelModel = Field(default_factory=ChannelModel)
    materials: dict[str, MaterialModel] = Field(default_factory=dict)
    walls: list[WallModel] = Field(default_factory=list)
    room: RoomModel | None = None
    objects: list[ObjectModel] = Field(default_factory=list)
    nodes: list[NodeModel] = Field(default_factory=list)
    robot: RobotModel | None = None
    circle_scan: CircleScanModel | None = None
    people: list[PersonModel] = Field(default_factory=list)
    anchors: list[AnchorModel] = Field(default_factory=list)
    mobiles: list[MobileModel] = Field(default_factory=list)
    ranging: RangingModel | None = None

    @model_validator(mode="after")
    def _consistent(self) -> Scenario:
        if not self.nodes and self.robot is None and not self.mobiles and self.circle_scan is None:
            raise _FieldError(
                "nodes",
                "a scenario needs static [[nodes]], a [robot], [[mobiles]] or a [circle_scan]",
            )
        if self.mobiles and (len(self.anchors) == 0 or self.ranging is None):
            raise _FieldError("anchors", "[[mobiles]] need [[anchors]] and a [ranging] table")
        if self.ranging is not None and self.objects:
            # the ranging link models walls, the room outline, floor and ceiling only: an
            # object would neither block nor reflect it, a silently wrong channel
            raise _FieldError("objects", "the [ranging] link does not model [[objects]] yet")
        refs = [(f"walls[{i}].material", w.material) for i, w in enumerate(self.walls)]
        if self.circle_scan is not None:
            refs.append(("circle_scan.material", self.circle_scan.material))
        refs += [(f"objects[{i}].material", o.material) for i, o in enumerate(self.objects)]
        if self.ranging is not None and self.ranging.floor_material is not None:
            refs.append(("ranging.floor_material", self.ranging.floor_material))
        if self.room is not None:
            refs += [
                (f"room.{k}", m)
                for k, m in (
                    ("material", self.room.material),
                    ("floor_material", self.room.floor_material),
                    ("ceiling_material", self.room.ceiling_material),
                )
                if m is not None
            ]
        for field, material in refs:
            if material not in self.materials:
                raise _FieldError(field, f"unknown material {material!r}")
        for what, ids in (
            ("nodes", [n.id for n in self.nodes]),
            ("people", [p.id for p in self.people]),
            ("objects", [o.id for o in self.objects]),
            ("anchors", [a.id for a in self.anchors] + [m.id for m in self.mobiles]),
        ):
            dup = sorted({x for x in ids if ids.count(x) > 1}, key=str)
            if dup:
                raise _FieldError(f"{what}.id", f"duplicate id {dup[0]!r}")
        # Each node transmits once per TDMA frame, so its IR rate is 1 / frame_period.
        if abs(self.radar.rate * self.frame_period - 1.0) > 1e-6:
            raise _FieldError(
                "radar.rate", f"must equal 1/frame_period = {1 / self.frame_period:g} Hz"
            )
        self._antennas_in_free_space()
        return self

    def antenna_positions(self) -> tuple[list[str], np.ndarray]:
        """World positions of every antenna and the scenario element each belongs to.

        Static nodes give their tx, rx1, rx2; the robot gives its antennas at every stop and
        heading (element ``robot.stops[i]``).

        Returns
        -------
        labels : list of str, one per row
        positions : ndarray, float64, shape (M, 3), m
        """
        labels, rows = [], []
        for i, node in enumerate(self.nodes):
            x, y, z, yaw = node.pose
            c, s = math.cos(yaw), math.sin(yaw)
            for name, (pos, _, _) in BAT_ANTENNAS.items():
                ov = node.antennas.get(name)
                px, py, pz = ov.pos if ov and ov.pos else pos
                labels.append(f"nodes[{i}].antennas.{name} ({node.id})")
                rows.append([x + c * px - s * py, y + s * px + c * py, z + pz])
        pos = np.array(rows, float).reshape(-1, 3)
        if self.robot is not None:
            rb = self.robot
            stops = np.array(rb.stops, float)
            heads = rb.stop_headings()
            side = np.array([0.5, -0.5]) * rb.baseline
            # Per stop: the Tx, then rx1 and rx2 at every heading.
            rx_x = stops[:, None, None, 0] - np.sin(heads)[:, :, None] * side
            rx_y = stops[:, None, None, 1] + np.cos(heads)[:, :, None] * side
            rx = np.stack([rx_x, rx_y], axis=-1).reshape(len(stops), -1, 2)
            xy = np.concatenate([stops[:, None, :], rx], axis=1).reshape(-1, 2)
            pos = np.concatenate([pos, np.column_stack([xy, np.full(len(xy), rb.height)])])
            per_stop = 1 + 2 * rb.n_headings
            labels += [f"robot.stops[{i}]" for i in range(len(stops)) for _ in range(per_stop)]
        return labels, pos

    def _antennas_in_free_space(self) -> None:
        """Raise a _FieldError naming the first antenna inside a wall, object or slab."""
        labels, pos = self.antenna_positions()
        if pos.shape[0] == 0:
            return
        x, y, z = pos[:, 0], pos[:, 1], pos[:, 2]
        found: list[tuple[int, str]] = []  # (first offending row, message) of each check

        def first(mask: np.ndarray, what: str) -> None:
            # mask (M, E): the first antenna row inside any element, and that element.
            if mask.size and mask.any():
                row = int(np.argmax(mask.any(axis=1)))
                elem = int(np.argmax(mask[row]))
                found.append((row, what.format(elem=elem)))

        if self.walls:
            a = np.array([w.start for w in self.walls], float)
            b = np.array([w.end for w in self.walls], float)
            half = np.array([w.thickness / 2 for w in self.walls])
            top = np.array([w.height for w in self.walls])
            first(
                (_segment_distances(pos[:, :2], a, b) < half) & (z[:, None] <= top),
                "is inside walls[{elem}]",
            )
        for j, o in enumerate(self.objects):
            poly = np.array(o.footprint, float)
            inside = _inside_convex(pos[:, :2], poly) & (z >= o.z[0]) & (z <= o.z[1])
            first(inside[:, None], f"is inside objects[{j}] ({o.id})")
        room = self.room
        if room is not None:
            first(
                ((z <= room.floor) | (z >= room.top))[:, None],
                "is outside the room's floor..ceiling",
            )
            poly = np.array(room.outline, float)
            ccw = _signed_area(room.outline) > 0
            a, b = poly[:-1], poly[1:]
            e = b - a
            length = np.linalg.norm(e, axis=1)
            # Signed distance into the room from each outline edge, and the foot parameter.
            inward = ((x[:, None] - a[:, 0]) * -e[:, 1] + (y[:, None] - a[:, 1]) * e[:, 0]) / length
            inward *= 1 if ccw else -1
            along = (
                (x[:, None] - a[:, 0]) * e[:, 0] + (y[:, None] - a[:, 1]) * e[:, 1]
            ) / length**2
            first(
                (inward > -room.thickness) & (inward < 1e-9) & (along >= 0) & (along <= 1),
                "is inside the room's wall room.outline[{elem}]",
            )
        if found:
            row, what = min(found, key=lambda f: f[0])
            px, py, pz = pos[row]
            raise _FieldError(labels[row], f"antenna at ({px:.3g}, {py:.3g}, {pz:.3g}) {what}")


def _segment_distances(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distances in x, y from points (M, 2) to segments a-b (E, 2), shape (M, E)."""
    e = b - a
    t = np.einsum("mek,ek->me", p[:, None, :] - a, e) / np.sum(e * e, axis=1)
    foot = a + np.clip(t, 0.0, 1.0)[..., None] * e
    return np.linalg.norm(p[:, None, :] - foot, axis=-1)


def _inside_convex(p: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """Whether points (M, 2) are strictly inside a closed convex polygon (V + 1, 2)."""
    a, b = poly[:-1], poly[1:]
    cross = (b[:, 0] - a[:, 0]) * (p[:, None, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (
        p[:, None, 0] - a[:, 0]
    )
    sign = 1.0 if _signed_area(poly.tolist()) > 0 else -1.0
    return np.all(sign * cross > 0, axis=1)


def _loc(loc: tuple[int | str, ...]) -> str:
    out = ""
    for part in loc:
        out += f"[{part}]" if isinstance(part, int) else (f".{part}" if out else str(part))
    return out


def _one_line(exc: ValidationError) -> str:
    """The first validation error as ``field: message`` (+ how many more)."""
    errors = exc.errors(include_url=False)
    err = errors[0]
    ctx_err = err.get("ctx", {}).get("error")
    if isinstance(ctx_err, _FieldError):
        # Raised by a model validator: its field is relative to the model's location.
        text = ".".join(filter(None, [_loc(err["loc"]), str(ctx_err)]))
    else:
        field = _loc(err["loc"]) or "(top level)"
        if err["type"] == "extra_forbidden":
            msg = "unknown key (misspelt?)"
        elif err["type"] == "missing":
            msg = "required key missing"
        else:
            msg = err["msg"].removeprefix("Value error, ")
            if err["type"].endswith("_type") or err["type"] == "literal_error":
                msg += f", got {err['input']!r}"[:80]
        text = f"{field}: {msg}"
    more = f" (+{len(errors) - 1} more)" if len(errors) > 1 else ""
    return " ".join(f"{text}{more}".split())


def parse_scenario(data: dict, source: str = "<scenario>") -> Scenario:
    """Validate a scenario mapping (the parsed TOML).

    Raises
    ------
    ScenarioError
        One line: ``source: field: message``.
    """
    try:
        return Scenario.model_validate(data)
    except ValidationError as exc:
        raise ScenarioError(f"{source}: {_one_line(exc)}") from None


def scenario_names() -> list[str]:
    """Names of the shipped scenarios."""
    files = resources.files("sim_nodes.scenarios").iterdir()
    return sorted(f.name.removesuffix(".toml") for f in files if f.name.endswith(".toml"))


def load_scenario(name_or_path: str) -> Scenario:
    """Load a shipped scenario by name (``"foyer3"``) or a scenario TOML file by path.

    Raises
    ------
    ScenarioError
        One line naming the file and the bad field.
    """
    text_source = str(name_or_path)
    path = Path(text_source)
    if path.suffix == ".toml" or path.exists() or "/" in text_source:
        source = path.name
        try:
            text = path.read_text(encoding="utf-8")
        except OSError as exc:
            raise ScenarioError(f"{text_source}: cannot read: {exc.strerror}") from None
    else:
        source = f"{text_source}.toml"
        res = resources.files("sim_nodes.scenarios").joinpath(source)
        if not res.is_file():
            known = ", ".join(scenario_names())
            raise ScenarioError(f"unknown scenario {text_source!r} (shipped: {known})")
        text = res.read_text(encoding="utf-8")
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(f"{source}: not valid TOML: {' '.join(str(exc).split())}") from None
    base = path.parent if path.suffix == ".toml" or path.exists() or "/" in text_source else None
    _resolve_tables(data, base or Path(str(resources.files("sim_nodes.scenarios"))))
    scenario = parse_scenario(data, source)
    for field, table in _pattern_tables(scenario):
        try:
            read_pattern_table(table)
        except (OSError, ValueError) as exc:
            raise ScenarioError(f"{source}: {field}: {exc}") from None
    return scenario


def _resolve_tables(data: dict, base: Path) -> None:
    """Make relative ``pattern_table`` paths relative to the scenario file's directory."""
    holders = [data.get("robot")] if isinstance(data.get("robot"), dict) else []
    for node in data.get("nodes", []) if isinstance(data.get("nodes"), list) else []:
        if isinstance(node, dict) and isinstance(node.get("antennas"), dict):
            holders += [a for a in node["antennas"].values() if isinstance(a, dict)]
    for h in holders:
        t = h.get("pattern_table")
        if isinstance(t, str) and not Path(t).is_absolute():
            h["pattern_table"] = str(base / t)


def _pattern_tables(scenario: Scenario) -> list[tuple[str, str]]:
    out = []
    if scenario.robot is not None and scenario.robot.pattern_table:
        out.append(("robot.pattern_table", scenario.robot.pattern_table))
    for i, node in enumerate(scenario.nodes):
        for name, ov in node.antennas.items():
            if ov.pattern_table:
                out.append((f"nodes[{i}].antennas.{name}.pattern_table", ov.pattern_table))
    return out


def read_pattern_table(path: str) -> tuple[list[float], list[float], list[list[float]]]:
    """A measured antenna pattern: CSV rows ``azimuth_deg, elevation_deg, gain_db``.

    ``#`` starts a comment; a header line of names is skipped. The rows must cover a full
    azimuth x elevation grid (any order). Returns the increasing azimuths and elevations
    (rad; azimuths wrapped to [-pi, pi)) and gains (dB) as ``gain[elevation][azimuth]``.

    Raises
    ------
    OSError
        The file cannot be read.
    ValueError
        A one-line description of the first bad line or of the incomplete grid.
    """
    rows: dict[tuple[float, float], float] = {}
    with open(path, encoding="utf-8") as fh:
        for n, line in enumerate(fh, 1):
            text = line.split("#", 1)[0].strip()
            if not text:
                continue
            parts = [p.strip() for p in text.split(",")]
            try:
                az, el, g = (float(p) for p in parts)
            except ValueError:
                if n == 1 and not any(c.isdigit() for c in text):
                    continue  # a header
                raise ValueError(
                    f"{Path(path).name}:{n}: need 'azimuth_deg, elevation_deg, gain_db'"
                ) from None
            az = (az + 180.0) % 360.0 - 180.0
            rows[(round(math.radians(az), 12), round(math.radians(el), 12))] = g
    azs = sorted({a for a, _ in rows})
    els = sorted({e for _, e in rows})
    if len(azs) < 2 or len(rows) != len(azs) * len(els):
        raise ValueError(
            f"{Path(path).name}: not a full azimuth x elevation grid "
            f"({len(rows)} points for {len(azs)} azimuths x {len(els)} elevations)"
        )
    return azs, els, [[rows[(a, e)] for a in azs] for e in els]
