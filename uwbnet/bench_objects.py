"""``uwbnet bench objects``: the Section 7 experiments, JSON on the last line.

* **Recognition** (7.7): every alphabet shape at ``trials`` random orientations and centre
  offsets (up to ``max_offset`` m) is scanned on a full, a 270-degree and a 180-degree track
  (random start); contours come from the simulator's fast geometric echo model
  (:func:`sim_nodes.circle_scan.geometric_wavefronts`: echo ranges with 2 mm noise, echoes
  closer than 2 cm merged) through fuzzy imaging, not from a waveform per trial. Accuracies
  and confusion matrices per track length; contour point error against the true polygon.
* **Pulse separation**: DCM, CLEAN and the matched-filter peak picker on two overlapping
  radar pulses (amplitudes 1 and 0.8, 40 dB SNR) at spacings from 0.25 to 2 range
  resolutions (``c / B``): resolved fraction and spacing error.
* **Ellipsometry** (eq. (16), Fig. 37): simulated impulse responses (the M-sequence radar,
  thermal noise) of a partial circular scan with a 0.8 m bistatic baseline over a 1 m slab
  of eps_r 2.9 (MDF) and 4.5 (brick); the corner correction table is calibrated on an
  eps_r 3.7 slab. Amplitudes are read from the impulse responses at the face echo's delay;
  the face plane and the corner distance are taken from the scene (evaluation geometry).
* **Waveform scan**: the ``circle_L`` scenario simulated to impulse responses and processed
  by the ``uwbnet objects`` chain (Wiener deconvolution, DCM, fuzzy imaging): contour error.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

C = 299792458.0


def _edge_distance(points: np.ndarray, vertices: np.ndarray) -> np.ndarray:
    """Distance of points (Q, 2) to the boundary of a polygon (V, 2), m."""
    from sim_nodes.channel.geometry import segment_point_distance

    dist, _ = segment_point_distance(vertices, np.roll(vertices, -1, axis=0), points)
    return dist.min(axis=0)


def recognition_experiment(trials: int, seed: int, max_offset: float = 0.2) -> dict[str, Any]:
    """Accuracies, confusion matrices and contour errors of the recognition experiment."""
    from fusion_center.objects.alphabet import alphabet, place
    from fusion_center.objects.fuzzy import FuzzyRpmImager, monostatic_distance
    from fusion_center.objects.recognition import CssRecognizer
    from sim_nodes.channel.prism import PrismTarget
    from sim_nodes.circle_scan import CircleTrack, geometric_wavefronts, scan_echoes
    from uwbnet.objects_cmd import reference_contours

    rng = np.random.default_rng(seed)
    shapes = alphabet()
    names = list(shapes)
    rec = CssRecognizer(reference_contours(1.0, 0.1))
    imager = FuzzyRpmImager()
    spans = {"full": 360, "270": 270, "180": 180}
    conf = {k: np.zeros((len(names), len(names)), int) for k in spans}
    errors = []
    for ci, name in enumerate(names):
        for _ in range(trials):
            rot = rng.uniform(0, 2 * np.pi)
            r, ph = max_offset * np.sqrt(rng.uniform()), rng.uniform(0, 2 * np.pi)
            verts = place(shapes[name], rot, (r * np.cos(ph), r * np.sin(ph)))
            full = CircleTrack()
            echoes = scan_echoes(PrismTarget(vertices=verts), full, np.deg2rad(70.0))
            rho = monostatic_distance(geometric_wavefronts(echoes, rng), full.baseline)
            pos, (_, _, toward) = full.positions(), full.antennas()
            start = int(rng.integers(0, 360))
            for key, span in spans.items():
                sel = np.mod(start + np.arange(span if span < 360 else 360), 360)
                closed = span == 360
                img = imager.image(pos[sel], rho[sel], toward[sel], closed=closed)
                if len(img.contour) < 8:
                    conf[key][ci, ci - 1] += 1  # nothing imaged: counted as wrong
                    continue
                if closed:
                    errors.append(_edge_distance(img.contour, verts))
                conf[key][ci, int(np.argmin(rec.scores(img.contour, closed=closed)))] += 1
    err = np.concatenate(errors)
    out: dict[str, Any] = {f"acc_{k}": float(np.trace(m) / m.sum()) for k, m in conf.items()}
    out["per_class_full"] = {n: float(conf["full"][i, i] / trials) for i, n in enumerate(names)}
    out["per_class_270"] = {n: float(conf["270"][i, i] / trials) for i, n in enumerate(names)}
    out["confusion"] = {k: m.tolist() for k, m in conf.items()}
    out["classes"] = names
    out["contour_error_m"] = {
        "median": float(np.median(err)),
        "mean": float(err.mean()),
        "p95": float(np.percentile(err, 95)),
    }
    return out


def separation_table(seed: int, trials: int = 40) -> list[dict[str, Any]]:
    """Resolved fraction and spacing error of DCM, CLEAN and matched filter vs spacing."""
    from fusion_center.objects.pulses import (
        CleanSeparator,
        DynamicCorrelationSeparator,
        MatchedFilterPeakPicker,
    )
    from sim_nodes.radar import MSequenceRadar, RadarConfig

    radar = MSequenceRadar(RadarConfig(noise=False))
    fs, n = radar.config.fs, 256
    resolution = fs / radar.config.f_high  # samples per 1/B (c/B of path), baseband B = f_high

    def pulses(delays: list[float], amps: list[float]) -> np.ndarray:
        spec = radar.path_spectrum(np.asarray(delays) / fs, amps)
        return radar.impulse_response(spec[None])[0].astype(float)[:n]

    ref = np.roll(_pulse(radar), 32)[:65]
    rng = np.random.default_rng(seed)
    noise = 0.01  # 40 dB below the unit pulse peak
    methods = {
        "dcm": DynamicCorrelationSeparator(ref, n, centre=32),
        "clean": CleanSeparator(ref, n, centre=32),
        "matched_filter": MatchedFilterPeakPicker(ref, n, centre=32),
    }
    rows = []
    for frac in (0.25, 0.5, 0.75, 1.0, 1.5, 2.0):
        spacing = frac * resolution
        row: dict[str, Any] = {
            "spacing_resolutions": frac,
            "spacing_m_path": round(spacing / fs * C, 4),
        }
        for name, m in methods.items():
            ok, err = 0, []
            for _ in range(trials):
                d0 = 100 + rng.uniform()
                y = pulses([d0, d0 + spacing], [1.0, 0.8]) + rng.normal(0, noise, n)
                p = m.separate(y, noise)
                if len(p.delays) < 2:
                    continue
                top = np.sort(p.delays[np.argsort(-np.abs(p.amplitudes))[:2]])
                if abs(top[0] - d0) < spacing / 2 and abs(top[1] - d0 - spacing) < spacing / 2:
                    ok += 1
                    err.append(abs(top[1] - top[0] - spacing) / fs * C)
            row[f"{name}_resolved"] = ok / trials
            row[f"{name}_spacing_error_mm"] = round(1e3 * float(np.mean(err)), 2) if err else None
        rows.append(row)
    return rows


def _pulse(radar: Any) -> np.ndarray:
    spec = radar.path_spectrum(np.zeros(1), np.ones(1))
    return radar.impulse_response(spec[None])[0].astype(float)


def ellipsometry_experiment(seed: int) -> dict[str, Any]:
    """Permittivity errors of eq. (16) with and without the corner correction table."""
    from fusion_center.objects.material import (
        CornerCorrectionTable,
        ellipsometry_permittivity,
        incidence_angle,
    )
    from fusion_center.objects.scan import sample_at
    from sim_nodes.channel.materials import fresnel
    from sim_nodes.channel.prism import FACE, PrismTarget
    from sim_nodes.circle_scan import CircleTrack, scan_echoes, scan_impulse_responses
    from sim_nodes.radar import MSequenceRadar, RadarConfig

    radar = MSequenceRadar(RadarConfig())
    rng = np.random.default_rng(seed)
    half_len, half_thick = 0.5, 0.08
    slab = np.array(
        [[-half_len, -half_thick], [half_len, -half_thick], [half_len, half_thick],
         [-half_len, half_thick]]
    )  # fmt: skip
    track = CircleTrack(
        radius=0.7, start=np.deg2rad(40), span=np.deg2rad(100), step=np.deg2rad(0.5), baseline=0.8
    )
    tx, rx, _ = track.antennas()
    normal = np.array([0.0, 1.0])

    def measure(eps: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        target = PrismTarget(vertices=slab, permittivity=eps, metal=False)
        echoes = scan_echoes(target, track, np.deg2rad(70.0))
        top = int(np.flatnonzero(echoes.kind == FACE)[2])  # the face at y = +half_thick
        length = echoes.length[:, top]
        ok = np.isfinite(length)
        h = scan_impulse_responses(echoes, radar, ("vv", "hh"), rng).astype(float)
        d = (np.nan_to_num(length) / C - radar.config.t0) * radar.config.fs
        a_vv, a_hh = sample_at(h[:, 0], d), sample_at(h[:, 1], d)
        point = echoes.point[:, top]
        theta = incidence_angle(tx, rx, point, normal)
        corner = half_len - np.abs(point[:, 0])
        rho = -a_hh / a_vv
        return rho[ok], theta[ok], corner[ok], point[ok]

    rho_r, th_r, cd_r, _ = measure(3.7)
    te, tm = fresnel(3.7, np.cos(th_r))
    table = CornerCorrectionTable.calibrate(
        cd_r, rho_r, np.real(tm / te), np.arange(0.0, 0.55, 0.025)
    )
    out: dict[str, Any] = {
        "theta_deg_range": [round(float(np.rad2deg(th_r.min())), 1),
                            round(float(np.rad2deg(th_r.max())), 1)],
        "correction_table": {
            "distance_m": np.round(table.distance, 4).tolist(),
            "factor": np.round(table.factor, 4).tolist(),
        },
    }  # fmt: skip
    for label, eps in (("mdf_2.9", 2.9), ("brick_4.5", 4.5)):
        rho, th, cd, _ = measure(eps)
        far = cd > 0.25
        raw = ellipsometry_permittivity(rho, th)
        cor = ellipsometry_permittivity(table.correct(rho, cd), th)
        near = (cd < 0.1) & (cd > 0.0)
        out[label] = {
            "eps_raw_far": round(float(np.median(raw[far])), 4),
            "eps_corrected_far": round(float(np.median(cor[far])), 4),
            "rel_error_corrected_far": round(float(abs(np.median(cor[far]) / eps - 1)), 4),
            "rel_error_raw_far": round(float(abs(np.median(raw[far]) / eps - 1)), 4),
            "rel_error_raw_near_10cm": round(float(abs(np.median(raw[near]) / eps - 1)), 4),
            "rel_error_corrected_near_10cm": round(float(abs(np.median(cor[near]) / eps - 1)), 4),
            "positions_far": int(far.sum()),
        }
    return out


def waveform_scan(seed: int) -> dict[str, Any]:
    """The ``circle_L`` scenario to impulse responses, processed like ``uwbnet objects``."""
    from fusion_center.objects.scan import ScanData, process_scan
    from sim_nodes.circle_record import scan_target, scan_track
    from sim_nodes.circle_scan import scan_echoes, scan_impulse_responses
    from sim_nodes.radar import MSequenceRadar
    from sim_nodes.scene import load_scenario

    sc = load_scenario("circle_L")
    target, track = scan_target(sc, seed), scan_track(sc)
    radar = MSequenceRadar(sc.radar.config())
    echoes = scan_echoes(target, track, sc.circle_scan.beamwidth)
    chans = ("vv", "hh", "vh", "hv", "pp", "pm")
    h = scan_impulse_responses(echoes, radar, chans, np.random.default_rng(seed))
    tx, rx, _ = track.antennas()
    scan = ScanData(
        h={c: h[:, i].astype(float) for i, c in enumerate(chans)},
        poses=track.poses(),
        tx=tx,
        rx=rx,
        fs=radar.config.fs,
        t0=radar.config.t0,
    )
    res = process_scan(scan)
    err = _edge_distance(res.contour, target.vertices)
    return {
        "contour_points": len(res.contour),
        "contour_error_m": {"median": float(np.median(err)), "p95": float(np.percentile(err, 95))},
        "corner_points_45deg": len(res.corner_points),
    }


def bench_objects(seed: int = 0, trials: int = 400) -> dict[str, Any]:
    """All Section 7 experiments (see the module docstring)."""
    t0 = time.perf_counter()
    out: dict[str, Any] = {"bench": "objects", "trials_per_class": trials}
    out.update(recognition_experiment(trials, seed))
    out["separation"] = separation_table(seed)
    out["ellipsometry"] = ellipsometry_experiment(seed)
    out["waveform_scan"] = waveform_scan(seed)
    out["wall_s"] = round(time.perf_counter() - t0, 1)
    return out
