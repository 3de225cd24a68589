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

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from sim_nodes.radar import RadarConfig


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
    """``[channel]``: propagation and body-model settings."""

    reflection_order: int = Field(2, ge=0, le=2)
    shadow_db: float = Field(18.0, ge=0.0, le=60.0)
    fluctuation_time: float = Field(0.1, gt=0.0)
    breathing_amplitude: float = Field(0.005, ge=0.0, le=0.05)
    breathing_rate: float = Field(0.25, gt=0.0, le=1.0)
    gait_amplitude: float = Field(0.05, ge=0.0, le=0.3)


class MaterialModel(_Model):
    """``[materials.NAME]``: specular amplitude reflection and one-way transmission loss.

    ``permittivity`` (relative, eps_r) delays a wave crossing a wall of thickness ``d`` by
    ``d (sqrt(eps_r) - 1) / c``; the default 1 ignores that delay.
    """

    reflection: float = Field(ge=-1.0, le=1.0)
    transmission_loss_db: float = Field(ge=0.0, le=200.0)
    permittivity: float = Field(1.0, ge=1.0, le=100.0)


class WallModel(_Model):
    """``[[walls]]``: a vertical wall on the 2-D segment start-end."""

    start: Point2
    end: Point2
    height: float = Field(3.0, gt=0.0, le=50.0)
    thickness: float = Field(0.2, ge=0.0, le=2.0)
    material: str

    @model_validator(mode="after")
    def _length(self) -> WallModel:
        if math.dist(self.start, self.end) < 1e-6:
            raise ValueError("wall start and end coincide")
        return self


class AntennaOverride(_Model):
    """``[nodes.antennas.NAME]``: override of a default antenna's geometry."""

    pos: Point3 | None = None
    boresight: float | None = Field(None, ge=-2 * math.pi, le=2 * math.pi)
    beamwidth: float | None = Field(None, gt=0.0, le=2 * math.pi)


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
    nodes: Annotated[list[NodeModel], Field(min_length=1)]
    people: list[PersonModel] = Field(default_factory=list)

    @model_validator(mode="after")
    def _consistent(self) -> Scenario:
        for i, wall in enumerate(self.walls):
            if wall.material not in self.materials:
                raise _FieldError(f"walls[{i}].material", f"unknown material {wall.material!r}")
        for what, ids in (
            ("nodes", [n.id for n in self.nodes]),
            ("people", [p.id for p in self.people]),
        ):
            dup = sorted({x for x in ids if ids.count(x) > 1}, key=str)
            if dup:
                raise _FieldError(f"{what}.id", f"duplicate id {dup[0]!r}")
        # Each node transmits once per TDMA frame, so its IR rate is 1 / frame_period.
        if abs(self.radar.rate * self.frame_period - 1.0) > 1e-6:
            raise _FieldError(
                "radar.rate", f"must equal 1/frame_period = {1 / self.frame_period:g} Hz"
            )
        return self


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
    return parse_scenario(data, source)
