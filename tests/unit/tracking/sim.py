"""Scenario generation for the tracking tests (simulate, then recover)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from fusion_center.tracking.base import SensorScan, in_field_of_view

FRAME = 0.02  # s, one TDMA frame


@dataclass(frozen=True, slots=True, kw_only=True)
class Sensor:
    name: str
    origin: np.ndarray
    boresight: float
    beamwidth: float
    max_range: float


def sensors_around(width: float, height: float, n: int = 6) -> list[Sensor]:
    """``n`` bat-type sensors on the border of a ``width x height`` room, looking at its centre."""
    centre = np.array([width / 2, height / 2])
    out = []
    for i in range(n):
        a = 2 * math.pi * i / n
        p = centre + np.array([math.cos(a) * width / 2, math.sin(a) * height / 2])
        p = np.clip(p, [0, 0], [width, height])
        look = math.atan2(*(centre - p)[::-1])
        out.append(
            Sensor(
                name=f"s{i}",
                origin=p,
                boresight=look,
                beamwidth=math.radians(100),
                max_range=12.0,
            )
        )
    return out


def crossing_truth(duration: float) -> tuple[np.ndarray, np.ndarray]:
    """Three walkers in a 10 m x 8 m room: 1 and 2 cross at (5, 4) at t = 5 s, 3 walks apart.

    Returns times (T,) and positions (T, 3, 2).
    """
    t = np.arange(0.0, duration, FRAME)
    p1 = np.stack([1.5 + 0.7 * t, 1.2 + 0.56 * t], axis=1)
    p2 = np.stack([1.5 + 0.7 * t, 6.8 - 0.56 * t], axis=1)
    p3 = np.stack([8.5 - 0.25 * t, 6.5 * np.ones_like(t)], axis=1)
    return t, np.stack([p1, p2, p3], axis=1)


def detect(
    rng: np.random.Generator,
    sensor: Sensor,
    t: float,
    xy: np.ndarray,
    *,
    pd: float = 0.9,
    sigma: float = 0.1,
    clutter: float = 1.0,
    bounds: tuple[float, float] = (10.0, 8.0),
) -> SensorScan:
    """One scan: each visible target detected with ``pd``, plus Poisson clutter in the room."""
    probe = SensorScan(
        sensor=sensor.name,
        t=t,
        positions=np.zeros((0, 2)),
        cov=np.zeros((0, 2, 2)),
        origin=sensor.origin,
        boresight=sensor.boresight,
        beamwidth=sensor.beamwidth,
        max_range=sensor.max_range,
    )
    seen = xy[in_field_of_view(probe, xy) & (rng.random(len(xy)) < pd)]
    meas = seen + rng.normal(0.0, sigma, seen.shape)
    n_c = rng.poisson(clutter)
    cl = rng.uniform([0, 0], bounds, (n_c, 2))
    z = np.concatenate([meas, cl])
    cov = np.broadcast_to(np.eye(2) * sigma**2, (len(z), 2, 2)).copy()
    return SensorScan(
        sensor=sensor.name,
        t=t,
        positions=z,
        cov=cov,
        origin=sensor.origin,
        boresight=sensor.boresight,
        beamwidth=sensor.beamwidth,
        max_range=sensor.max_range,
    )
