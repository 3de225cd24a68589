"""Fusion benchmark: GM-PHD step time, and ours against Stone Soup's GM-PHD.

``run(seed) -> dict`` returns JSON-serialisable figures:

* ``update_ms_mean_6x3``, ``update_ms_p99_6x3``: :class:`GmPhdTracker` step time with 6
  bat-type sensors around a 10 m x 8 m room and 3 walkers;
* ``update_ms_mean_100x30``, ``update_ms_p99_100x30``: 100 sensors on a 10 x 10 grid over a
  50 m x 50 m hall, 30 walkers;
* on one seeded scenario (3 walkers, two crossing, 10 m x 10 m, 50 Hz, p_D 0.9, 0.1 m
  noise, Poisson clutter 5 per scan, one omni position sensor): ``ms_per_scan``, ``ospa``,
  ``id_switches`` (ours) and ``stonesoup_ms_per_scan``, ``stonesoup_ospa`` (Stone Soup's
  GM-PHD built as in its GM-PHD tutorial; ``null`` with ``stonesoup_error`` when the
  ``bench`` extra is not installed). OSPA: c = 1 m, p = 1, positions, mean over the scans
  after a 1 s warm-up.

Times are wall-clock; each has a CPU-time twin (``update_cpu_ms_mean_6x3``,
``update_cpu_ms_mean_100x30``, ``cpu_ms_per_scan``, ``stonesoup_cpu_ms_per_scan``: CPU time
of this process, which a busy machine disturbs less). Run with one BLAS thread.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from fusion_center.tracking.base import SensorScan, in_field_of_view
from fusion_center.tracking.gmphd import GmPhdConfig, GmPhdTracker
from fusion_center.tracking.metrics import evaluate, ospa

__all__ = ["run"]

FRAME = 0.02  # s: 50 Hz
WARMUP = 1.0  # s


@dataclass(frozen=True, slots=True, kw_only=True)
class _Sensor:
    name: str
    origin: np.ndarray
    boresight: float = 0.0
    beamwidth: float = 2.0 * math.pi
    max_range: float = math.inf


def _scan(
    rng: np.random.Generator,
    sensor: _Sensor,
    t: float,
    xy: np.ndarray,
    *,
    pd: float,
    sigma: float,
    clutter_rate: float,
    clutter_box: tuple[np.ndarray, np.ndarray],
) -> SensorScan:
    """Detections of the visible people (p_D, Gaussian noise) plus uniform clutter in view."""
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
    seen = xy[in_field_of_view(probe, xy) & (rng.random(xy.shape[0]) < pd)]
    lo, hi = clutter_box
    clutter = rng.uniform(lo, hi, (rng.poisson(clutter_rate), 2))
    if sensor.beamwidth < 2.0 * math.pi or math.isfinite(sensor.max_range):
        clutter = clutter[in_field_of_view(probe, clutter)]
    z = np.concatenate([seen + rng.normal(0.0, sigma, seen.shape), clutter])
    cov = np.broadcast_to(np.eye(2) * sigma**2, (z.shape[0], 2, 2)).copy()
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


def _walkers(
    rng: np.random.Generator, n: int, lo: np.ndarray, hi: np.ndarray, n_steps: int
) -> np.ndarray:
    """Random walkers (about 1 m/s, slowly turning, reflected at the walls), (T, n, 2)."""
    pos = rng.uniform(lo + 1.0, hi - 1.0, (n, 2))
    heading = rng.uniform(-math.pi, math.pi, n)
    speed = rng.uniform(0.6, 1.4, n)
    out = np.empty((n_steps, n, 2))
    for k in range(n_steps):  # time steps of the simulation, not mixture components
        heading += rng.normal(0.0, 0.05, n)
        pos = pos + FRAME * speed[:, None] * np.stack([np.cos(heading), np.sin(heading)], 1)
        low, high = pos < lo + 0.5, pos > hi - 0.5
        heading = np.where((low | high)[:, 0], math.pi - heading, heading)
        heading = np.where((low | high)[:, 1], -heading, heading)
        pos = np.clip(pos, lo + 0.5, hi - 0.5)
        out[k] = pos
    return out


def _timing(
    seed: int, n_side: int, spacing: float, n_people: int, n_steps: int
) -> tuple[list[float], list[float]]:
    """GmPhdTracker step times, ms, wall and CPU, with ``n_side**2`` sensors (or 6 for
    ``n_side == 0``)."""
    rng = np.random.default_rng(seed)
    if n_side == 0:
        lo, hi = np.array([0.0, 0.0]), np.array([10.0, 8.0])
        centre = (lo + hi) / 2
        sensors = []
        for i in range(6):
            a = 2 * math.pi * i / 6
            p = np.clip(centre + np.array([5 * math.cos(a), 4 * math.sin(a)]), lo, hi)
            look = math.atan2(centre[1] - p[1], centre[0] - p[0])
            sensors.append(
                _Sensor(
                    name=f"s{i}",
                    origin=p,
                    boresight=look,
                    beamwidth=math.radians(100),
                    max_range=12.0,
                )
            )
    else:
        lo, hi = np.array([0.0, 0.0]), np.array([n_side * spacing, n_side * spacing])
        g = (np.arange(n_side) + 0.5) * spacing
        gx, gy = np.meshgrid(g, g)
        sensors = [
            _Sensor(
                name=f"s{i}",
                origin=np.array([x, y]),
                boresight=rng.uniform(-math.pi, math.pi),
                beamwidth=math.radians(100),
                max_range=8.0,
            )
            for i, (x, y) in enumerate(zip(gx.ravel(), gy.ravel(), strict=True))
        ]
    truth = _walkers(rng, n_people, lo, hi, n_steps)
    tracker = GmPhdTracker(GmPhdConfig(clutter_rate=1.0))
    times, cpu = [], []
    for k in range(n_steps):
        t = k * FRAME
        n = len(sensors)
        scans = [
            _scan(
                rng,
                s,
                t + FRAME * j / n,
                truth[k],
                pd=0.9,
                sigma=0.1,
                clutter_rate=1.0,
                clutter_box=(s.origin - s.max_range, s.origin + s.max_range),
            )
            for j, s in enumerate(sensors)
        ]
        c0, t0 = time.process_time(), time.perf_counter()
        tracker.step(t + FRAME, scans)
        times.append(1e3 * (time.perf_counter() - t0))
        cpu.append(1e3 * (time.process_time() - c0))
    return times, cpu


def _crossing_truth(duration: float) -> tuple[np.ndarray, np.ndarray]:
    """3 walkers in 10 m x 10 m: A and B cross at (5, 5) at t = 5 s; C walks along x = 0.8."""
    t = np.arange(0.0, duration, FRAME)
    a = np.stack([1.0 + 0.8 * t, 1.5 + 0.7 * t], 1)
    b = np.stack([1.0 + 0.8 * t, 8.5 - 0.7 * t], 1)
    c = np.stack([np.full_like(t, 0.8), 3.5 + 0.3 * t], 1)
    return t, np.stack([a, b, c], 1)


def _crossing_scans(seed: int, duration: float) -> tuple[np.ndarray, np.ndarray, list[SensorScan]]:
    rng = np.random.default_rng(seed)
    t, truth = _crossing_truth(duration)
    sensor = _Sensor(name="omni", origin=np.array([5.0, 5.0]))
    box = (np.array([0.0, 0.0]), np.array([10.0, 10.0]))
    scans = [
        _scan(rng, sensor, tk, truth[k], pd=0.9, sigma=0.1, clutter_rate=5.0, clutter_box=box)
        for k, tk in enumerate(t)
    ]
    return t, truth, scans


def _ours(t: np.ndarray, truth: np.ndarray, scans: list[SensorScan]) -> dict[str, float | int]:
    # The scenario's own parameters, as Stone Soup gets them: known p_D, clutter, point
    # targets (no body extent).
    tracker = GmPhdTracker(
        GmPhdConfig(
            clutter_rate=5.0,
            surveillance_area=100.0,
            detection_probability=0.9,
            adapt_detection=False,
            extent_std=0.0,
            maneuver_weight=0.0,  # the walkers move at constant velocity, as Stone Soup's model
        )
    )
    outputs = []
    c0, t0 = time.process_time(), time.perf_counter()
    for tk, scan in zip(t.tolist(), scans, strict=True):
        outputs.append(tracker.step(tk, [scan]))
    elapsed, cpu = time.perf_counter() - t0, time.process_time() - c0
    ids = np.arange(truth.shape[1])
    res = evaluate(
        [(tk, ids, truth[k]) for k, tk in enumerate(t.tolist())],
        [(o.t, o.ids(), o.positions()) for o in outputs],
        c=1.0,
        skip=WARMUP,
    )
    return {
        "ms_per_scan": 1e3 * elapsed / len(scans),
        "cpu_ms_per_scan": 1e3 * cpu / len(scans),
        "ospa": float(res["ospa_p1_mean"]),  # type: ignore[arg-type]
        "id_switches": int(res["id_switches"]),  # type: ignore[call-overload]
    }


def _stonesoup(t: np.ndarray, truth: np.ndarray, scans: list[SensorScan]) -> dict[str, float]:
    """Stone Soup's GM-PHD as its GM-PHD tutorial builds it (import here: bench extra)."""
    from datetime import datetime, timedelta

    from stonesoup.hypothesiser.distance import DistanceHypothesiser
    from stonesoup.hypothesiser.gaussianmixture import GaussianMixtureHypothesiser
    from stonesoup.measures import Mahalanobis
    from stonesoup.mixturereducer.gaussianmixture import GaussianMixtureReducer
    from stonesoup.models.measurement.linear import LinearGaussian
    from stonesoup.models.transition.linear import (
        CombinedLinearGaussianTransitionModel,
        ConstantVelocity,
    )
    from stonesoup.predictor.kalman import KalmanPredictor
    from stonesoup.types.array import CovarianceMatrix, StateVector
    from stonesoup.types.detection import Detection
    from stonesoup.types.state import TaggedWeightedGaussianState
    from stonesoup.updater.kalman import KalmanUpdater
    from stonesoup.updater.pointprocess import PHDUpdater

    cfg = GmPhdConfig()
    transition = CombinedLinearGaussianTransitionModel(
        [ConstantVelocity(cfg.accel_psd), ConstantVelocity(cfg.accel_psd)]
    )
    measurement = LinearGaussian(ndim_state=4, mapping=(0, 2), noise_covar=np.eye(2) * 0.01)
    kalman_updater = KalmanUpdater(measurement)
    updater = PHDUpdater(
        kalman_updater,
        clutter_spatial_density=5.0 / 100.0,
        prob_detection=0.9,
        prob_survival=0.999,
    )
    hypothesiser = GaussianMixtureHypothesiser(
        DistanceHypothesiser(
            KalmanPredictor(transition),
            kalman_updater,
            Mahalanobis(),
            missed_distance=math.sqrt(cfg.gate),
        ),
        order_by_detection=True,
    )
    reducer = GaussianMixtureReducer(
        prune_threshold=1e-5, pruning=True, merge_threshold=cfg.merge_threshold, merging=True
    )
    start = datetime(2024, 1, 1)
    birth = TaggedWeightedGaussianState(
        StateVector([5.0, 0.0, 5.0, 0.0]),
        CovarianceMatrix(np.diag([9.0, 1.0, 9.0, 1.0])),
        weight=0.1,
        tag=TaggedWeightedGaussianState.BIRTH,
        timestamp=start,
    )
    mixture: list = []
    ospas = []
    elapsed = cpu = 0.0
    for k, (tk, scan) in enumerate(zip(t.tolist(), scans, strict=True)):
        stamp = start + timedelta(seconds=tk)
        detections = {
            Detection(StateVector(z), timestamp=stamp, measurement_model=measurement)
            for z in scan.positions
        }
        c0, t0 = time.process_time(), time.perf_counter()
        b = TaggedWeightedGaussianState(
            birth.state_vector,
            birth.covar,
            weight=birth.weight,
            tag=birth.tag,
            timestamp=stamp - timedelta(seconds=FRAME),
        )
        hypotheses = hypothesiser.hypothesise(
            [*mixture, b], detections, stamp, order_by_detection=True
        )
        updated = updater.update(hypotheses)
        mixture = list(reducer.reduce(updated))
        est = np.array(
            [
                [float(c.state_vector[0]), float(c.state_vector[2])]
                for c in mixture
                if c.weight > 0.5
            ]
        ).reshape(-1, 2)
        elapsed += time.perf_counter() - t0
        cpu += time.process_time() - c0
        if tk >= WARMUP:
            ospas.append(ospa(truth[k], est, 1.0, 1.0))
    return {
        "stonesoup_ms_per_scan": 1e3 * elapsed / len(scans),
        "stonesoup_cpu_ms_per_scan": 1e3 * cpu / len(scans),
        "stonesoup_ospa": float(np.mean(ospas)),
    }


def run(seed: int = 0) -> dict[str, float | int | str | None]:
    """Run the fusion benchmark.

    Parameters
    ----------
    seed : int
        Seed of every random draw.

    Returns
    -------
    dict
        The figures listed in the module docstring; times in milliseconds.
    """
    out: dict[str, float | int | str | None] = {"seed": seed}
    wall, cpu = (np.array(x[20:]) for x in _timing(seed, 0, 0.0, 3, 250))
    out["update_ms_mean_6x3"] = float(wall.mean())
    out["update_ms_p99_6x3"] = float(np.percentile(wall, 99))
    out["update_cpu_ms_mean_6x3"] = float(cpu.mean())
    wall, cpu = (np.array(x[10:]) for x in _timing(seed, 10, 5.0, 30, 60))
    out["update_ms_mean_100x30"] = float(wall.mean())
    out["update_ms_p99_100x30"] = float(np.percentile(wall, 99))
    out["update_cpu_ms_mean_100x30"] = float(cpu.mean())

    t, truth, scans = _crossing_scans(seed, 10.0)
    out.update(_ours(t, truth, scans))
    try:
        out.update(_stonesoup(t, truth, scans))
    except ImportError as exc:
        out["stonesoup_ms_per_scan"] = None
        out["stonesoup_cpu_ms_per_scan"] = None
        out["stonesoup_ospa"] = None
        out["stonesoup_error"] = f"stonesoup not available: {exc}"
    return out
