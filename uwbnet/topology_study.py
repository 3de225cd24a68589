"""The Fig. 18 findings of the CoLOR chapter's Section 5, measured on a Fig. 17 network.

``python -m uwbnet.topology_study [--png FILE] [--json]``: a 10 m x 10 m area, a transmitter
moving along a track (the virtual array) and three stationary receivers (the real array), band
3.5-10.5 GHz (the chapter's passband radar). Three findings, each as numbers:

1. Resolution: the 3 dB main-lobe width is smaller along the direction in which the look
   direction rotates (a broadside track: large rotation) than for a radial track (small
   rotation), at one frequency and across the band.
2. Ghost: a linear track gives a full-height ghost at the mirror image of the reference point
   across the track's line; an irregular track of the same length suppresses it.
3. Topology: receivers off the track's line partially suppress that ghost (the topology
   factor), more the farther they are from the line.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any

import numpy as np

from fusion_center.topology import (
    SPEED_OF_LIGHT as C,
)
from fusion_center.topology import (
    Area,
    Band,
    NetworkGeometry,
    ambiguity,
    assess_point,
    factor_maps,
    grid_points,
    mainlobe_widths,
)

BAND = Band(f_low=3.5e9, f_high=10.5e9)
AREA = Area(x_min=0.0, y_min=0.0, x_max=10.0, y_max=10.0, nx=200, ny=200)
REFERENCE = np.array([5.0, 7.0])
TRACK_Y = 5.0  # the linear track runs along y = 5 (line L1); its mirror of REFERENCE is (5, 3)


def _narrow(band: Band) -> Band:
    """A 1 % band at the centre: the single-frequency AF."""
    return Band(f_low=band.center * 0.995, f_high=band.center * 1.005)


def _db(value: complex) -> float:
    return 20.0 * math.log10(max(abs(value), 1e-9))


def linear_track(n: int = 41) -> np.ndarray:
    """Transmit positions along y = 5 from x = 1 to 9, m."""
    return np.column_stack([np.linspace(1.0, 9.0, n), np.full(n, TRACK_Y)])


def irregular_track(n: int = 41, seed: int = 0, wiggle: float = 0.6) -> np.ndarray:
    """The linear track with seeded lateral offsets up to ``wiggle`` m (a meandering walk)."""
    rng = np.random.default_rng(seed)
    t = linear_track(n)
    t[:, 1] += rng.uniform(-wiggle, wiggle, n)
    return t


def receivers(offset: float) -> np.ndarray:
    """Three stationary receivers ``offset`` m below the track's line, m."""
    return np.array([[0.5, TRACK_Y - offset], [3.0, TRACK_Y - offset], [9.5, TRACK_Y - offset]])


def resolution_study() -> dict[str, Any]:
    """Widths along x and y for a broadside and a radial track of equal length."""
    rx = np.array([[1.0, 1.0], [5.0, 0.5], [9.0, 1.0]])
    p0 = np.array([5.0, 8.0])
    tracks = {
        "broadside": np.column_stack([np.linspace(2.0, 8.0, 31), np.full(31, 5.0)]),
        "radial": np.column_stack([np.full(31, 5.5), np.linspace(0.5, 6.5, 31)]),
    }
    out: dict[str, Any] = {"reference": p0.tolist()}
    xy = np.eye(2)
    for name, tx in tracks.items():
        net = NetworkGeometry(transmitters=tx, receivers=rx)
        look = np.degrees(np.arctan2(p0[1] - tx[:, 1], p0[0] - tx[:, 0]))
        row: dict[str, Any] = {"rotation_deg": round(float(look.max() - look.min()), 1)}
        for label, band in (("single_frequency", _narrow(BAND)), ("band", BAND)):
            w, _ = mainlobe_widths(net, band, p0, xy)
            row[label] = {"width_x_m": round(float(w[0]), 4), "width_y_m": round(float(w[1]), 4)}
        out[name] = row
    return out


def ghost_study(seed: int = 0) -> dict[str, Any]:
    """Ghost at the mirror point for linear/irregular tracks and receiver offsets."""
    mirror = np.array([REFERENCE[0], 2 * TRACK_Y - REFERENCE[1]])
    out: dict[str, Any] = {"reference": REFERENCE.tolist(), "mirror": mirror.tolist()}
    f = BAND.frequencies(256)
    rows = []
    for offset in (0.0, 0.02, 0.05, 0.1, 0.2, 0.5, 1.0, 2.0):
        net = NetworkGeometry(transmitters=linear_track(), receivers=receivers(offset))
        at = float(np.abs(ambiguity(net, BAND, REFERENCE, mirror[None]))[0])
        fm = factor_maps(net, REFERENCE, mirror[None], f, far_field=False)
        rows.append(
            {
                "rx_offset_m": offset,
                "ghost_at_mirror_db": round(20 * math.log10(max(at, 1e-9)), 2),
                "motion_factor_abs": round(float(np.abs(fm.motion).mean()), 4),
                "topology_factor_band_db": round(_db(np.sum(fm.signal * fm.topology[:, 0])), 2),
                "factorized_af_db": round(_db(fm.across_band()[0]), 2),
            }
        )
    out["linear_track_vs_rx_offset"] = rows
    for name, tx, off in (
        ("linear_collinear_rx", linear_track(), 0.0),
        ("linear_offset_rx", linear_track(), 0.1),
        ("irregular_collinear_rx", irregular_track(seed=seed), 0.0),
        ("irregular_offset_rx", irregular_track(seed=seed), 0.1),
    ):
        net = NetworkGeometry(transmitters=tx, receivers=receivers(off))
        at = float(np.abs(ambiguity(net, BAND, REFERENCE, mirror[None]))[0])
        q = assess_point(net, BAND, REFERENCE, AREA)
        near = mirror + grid_points(np.linspace(-0.5, 0.5, 101), np.linspace(-0.5, 0.5, 101))
        out[name] = {
            "ghost_at_mirror_db": round(20 * math.log10(max(at, 1e-9)), 2),
            "max_within_0.5m_of_mirror_db": round(
                _db(np.abs(ambiguity(net, BAND, REFERENCE, near)).max()), 2
            ),
            "worst_ghost_db": round(q.ghost_db, 2),
            "worst_ghost_at": [round(float(v), 2) for v in q.ghost_position],
            "widths_m": [round(float(v), 4) for v in q.widths],
        }
    return out


def _line_widths(img: np.ndarray, x: np.ndarray, y: np.ndarray, p0, axes) -> np.ndarray:
    """3 dB widths of an image's peak at ``p0`` along ``axes`` (bilinear samples), m."""
    from scipy.ndimage import map_coordinates

    step = x[1] - x[0]
    r = np.arange(1, int(0.45 * len(x))) * step / 4
    peak = float(
        map_coordinates(img, [[(p0[1] - y[0]) / step], [(p0[0] - x[0]) / step]], order=1)[0]
    )
    widths = np.empty(2)
    for i, ax in enumerate(axes):
        total = 0.0
        for sign in (1.0, -1.0):
            q = p0 + sign * r[:, None] * ax
            v = map_coordinates(img, [(q[:, 1] - y[0]) / step, (q[:, 0] - x[0]) / step], order=1)
            below = np.nonzero(v < peak * 10 ** (-3 / 20))[0]
            if below.size == 0:
                return np.full(2, np.nan)  # no crossing inside the image
            n = int(below[0])
            prev_v, prev_r = (peak, 0.0) if n == 0 else (v[n - 1], r[n - 1])
            total += prev_r + (prev_v - peak * 10 ** (-3 / 20)) / max(prev_v - v[n], 1e-12) * (
                r[n] - prev_r
            )
        widths[i] = total
    return widths


def psf_check(net: NetworkGeometry, band: Band, p0: np.ndarray) -> dict[str, Any]:
    """Predicted 3 dB widths (the AF) against the point-spread function of the Kirchhoff
    migration of :mod:`fusion_center.imaging` for a point target at ``p0``.

    The impulse responses are the band-limited echo of a point target on every link, as
    complex baseband rows (carrier ``f_c``, flat band ``B``, sampled at ``8 B``) so that the
    coherent migration (``envelope=False``) is the matched filter whose image is ``|AF|``.
    (The imager's default envelope migration is incoherent: its point-spread function is not
    the AF's main lobe and is not what this predicts.)
    """
    from fusion_center.imaging import Grid, Observations, kirchhoff_image

    widths, axes = mainlobe_widths(net, band, p0)
    ti, ri = net.link_indices()
    z = 1.0
    tx = np.column_stack([net.transmitters[ti], np.full(len(ti), z)])
    rx = np.column_stack([net.receivers[ri], np.full(len(ri), z)])
    tau0 = (np.linalg.norm(tx[:, :2] - p0, axis=1) + np.linalg.norm(rx[:, :2] - p0, axis=1)) / C
    fs = 8.0 * band.bandwidth
    n = int(np.ceil((tau0.max() + 30.0 / band.bandwidth) * fs))
    t = np.arange(n) / fs
    h = (
        np.sinc(band.bandwidth * (t[None, :] - tau0[:, None]))
        * np.exp(-2j * np.pi * band.center * tau0)[:, None]
    )
    obs = Observations(h=h.astype(np.complex64), tx=tx, rx=rx, fs=fs, fc=band.center)
    step = float(widths.min()) / 12.0
    half = 2.5 * float(widths.max())
    npx = int(2 * half / step) + 1
    grid = Grid.covering(p0[0] - half, p0[0] + half, p0[1] - half, p0[1] + half, npx, npx, z)
    gx, gy = grid.xy()
    out: dict[str, Any] = {
        "reference": [float(v) for v in p0],
        "predicted_widths_m": [round(float(w), 4) for w in widths],
    }
    img = kirchhoff_image(obs, grid, envelope=False, gate=-1.0)
    meas = _line_widths(img.astype(np.float64), gx, gy, p0, axes)
    out["migration_widths_m"] = [round(float(w), 4) for w in meas]
    out["relative_error"] = [
        round(float(m / w - 1.0), 4) for m, w in zip(meas, widths, strict=True)
    ]
    return out


def psf_study() -> list[dict[str, Any]]:
    """:func:`psf_check` on the Fig. 17 network and at two points of foyer3 and room_pillar."""
    from sim_nodes.scene import load_scenario
    from uwbnet.topology_cmd import scenario_band, scenario_geometry

    fig17 = NetworkGeometry(transmitters=linear_track(), receivers=receivers(1.0))
    rows = [{"geometry": "fig17_linear_track_rx_1m_off", **psf_check(fig17, BAND, REFERENCE)}]
    for name, points in (
        ("foyer3", [(6.0, 4.5), (3.0, 7.0)]),
        ("room_pillar", [(2.0, 2.0), (7.0, 6.0)]),
    ):
        sc = load_scenario(name)
        net, band = scenario_geometry(sc), scenario_band(sc)
        rows += [{"geometry": name, **psf_check(net, band, np.array(p))} for p in points]
    return rows


def plot_study(png: Path, seed: int = 0) -> None:
    """AF maps (dB) of the ghost cases and the factors at the centre frequency."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from uwbnet.topology_cmd import _save

    # A strip over the reference and its mirror at 6 mm: the lobes are 1-3 cm wide.
    strip = Area(x_min=3.5, y_min=2.5, x_max=6.5, y_max=7.5, nx=501, ny=834)
    pts = strip.points()
    ext = (strip.x_min, strip.x_max, strip.y_min, strip.y_max)
    cases = [
        ("linear track, Rx on its line", linear_track(), receivers(0.0)),
        ("linear track, Rx 0.1 m off the line", linear_track(), receivers(0.1)),
        ("irregular track, Rx on the line", irregular_track(seed=seed), receivers(0.0)),
    ]
    fig, axes = plt.subplots(2, 3, figsize=(13, 14))
    for ax, (title, tx, rx) in zip(axes[0], cases, strict=True):
        net = NetworkGeometry(transmitters=tx, receivers=rx)
        mag = np.abs(ambiguity(net, BAND, REFERENCE, pts)).reshape(strip.ny, strip.nx)
        im = ax.imshow(
            20 * np.log10(np.maximum(mag, 1e-3)), origin="lower", extent=ext, vmin=-30, vmax=0
        )
        ax.plot(*tx.T, "r.", ms=3)
        ax.plot(*rx.T, "wv", mec="k")
        ax.plot(*REFERENCE, "c+", ms=12, mew=2)
        ax.set_title(f"AF across the band:\n{title}", fontsize=9)
    fig.colorbar(im, ax=axes[0].tolist(), label="|AF| (dB)")
    net = NetworkGeometry(transmitters=linear_track(), receivers=receivers(0.1))
    fm = factor_maps(net, REFERENCE, pts, [BAND.center], far_field=False)
    for ax, (title, val) in zip(
        axes[1],
        (
            ("motion factor |M| at f_c\n(virtual array)", fm.motion[0]),
            ("topology factor |T| at f_c\n(real array)", fm.topology[0]),
            ("AF at f_c = M x T", fm.per_frequency()[0]),
        ),
        strict=True,
    ):
        im = ax.imshow(
            20 * np.log10(np.maximum(np.abs(val), 1e-3)).reshape(strip.ny, strip.nx),
            origin="lower",
            extent=ext,
            vmin=-30,
            vmax=0,
        )
        ax.plot(*REFERENCE, "c+", ms=12, mew=2)
        ax.set_title(title + ", linear track, Rx 0.1 m off", fontsize=9)
        ax.plot(*net.receivers.T, "wv", mec="k")
    fig.colorbar(im, ax=axes[1].tolist(), label="dB")
    for ax in axes.ravel():
        ax.set(xlabel="x (m)", ylabel="y (m)", aspect="equal", xlim=ext[:2], ylim=ext[2:])
    _save(fig, png)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m uwbnet.topology_study", description=__doc__)
    p.add_argument("--png", help="save the AF and factor maps to this PNG file")
    p.add_argument("--json", action="store_true", help="print only the JSON line")
    p.add_argument("--seed", type=int, default=0, help="seed of the irregular track")
    p.add_argument(
        "--psf", action="store_true", help="also compare with Kirchhoff migration images"
    )
    args = p.parse_args(argv)
    result: dict[str, Any] = {"resolution": resolution_study(), "ghost": ghost_study(args.seed)}
    if args.psf:
        result["psf"] = psf_study()
    if args.png:
        plot_study(Path(args.png), args.seed)
        result["png"] = args.png
    if not args.json:
        print(json.dumps(result, indent=1))  # noqa: T201
    print(json.dumps(result))  # noqa: T201
    return 0


if __name__ == "__main__":
    sys.exit(main())
