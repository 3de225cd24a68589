"""``uwbnet plot tracks|image|channel|topology``: figures like the CoLOR chapter's (matplotlib).

- ``tracks``: estimated tracks against the recording's truth, on the floor plan (x-y), and the
  per-axis positions over time.
- ``image``: an imaging result from an ``.npz`` with ``img`` (ny, nx), ``x0``, ``y0``, ``dx``,
  ``dy`` (PROTOCOL.md ``image`` fields; optional ``method``) as a heat map with colour bar.
- ``channel``: radargram of one node's impulse responses in a recording: magnitude (dB) over
  bistatic range (m) and time (s).
- ``topology``: the deployment layout of a scenario: walls, objects, sensors with their beams,
  people's paths.

The format follows the output's suffix (``.png``, ``.svg``, ``.pdf``). The figure appears
under its name only once complete (written to a temp name, then renamed).
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any

import numpy as np

from protocol import C, Ir, NodeInfo, ProtocolError
from protocol.recording import read_recording


class PlotError(ValueError):
    """Bad input for a plot (one-line message)."""


FORMATS = (".png", ".svg", ".pdf")


def _pyplot() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig: Any, out: Path) -> dict[str, Any]:
    if out.suffix.lower() not in FORMATS:
        raise PlotError(f"output must end in one of {', '.join(FORMATS)}: {out}")
    part = out.with_name(out.stem + ".partial" + out.suffix)
    try:
        fig.savefig(part, dpi=120)
        os.replace(part, out)
    finally:
        part.unlink(missing_ok=True)
        fig.clf()
    return {"out": str(out)}


def _draw_walls(ax: Any, walls: list[list[float]]) -> None:
    for x1, y1, x2, y2 in walls:
        ax.plot([x1, x2], [y1, y2], color="0.25", lw=2.5, solid_capstyle="butt", zorder=1)


def _draw_nodes(ax: Any, infos: dict[str, NodeInfo]) -> None:
    for node, info in sorted(infos.items()):
        x, y, _, yaw = info.pose
        bore = yaw + next((a.boresight for a in info.antennas.values() if a.tx), 0.0)
        ax.plot(x, y, "s", color="tab:green", ms=7, zorder=4)
        ax.annotate(
            "",
            (x + 0.6 * math.cos(bore), y + 0.6 * math.sin(bore)),
            (x, y),
            arrowprops={"arrowstyle": "->", "color": "tab:green"},
        )
        ax.annotate(node, (x, y), xytext=(4, -11), textcoords="offset points", fontsize=8)


def plot_tracks(
    recording: Path, tracks: Path, out: Path, scenario: Any | None = None
) -> dict[str, Any]:
    """Tracks of a JSONL file against the truth of ``recording`` (x-y plane and x, y over t)."""
    from fusion_center.offline import read_tracks, read_truth
    from fusion_center.viewer.state import floor_plan

    truth = read_truth(recording)
    if not truth:
        raise PlotError(f"no truth messages in {recording}")
    est = list(read_tracks(tracks))
    if not est:
        raise PlotError(f"no tracks in {tracks}")
    plt = _pyplot()
    fig = plt.figure(figsize=(12, 6), layout="constrained")
    gs = fig.add_gridspec(2, 2, width_ratios=(1.4, 1))
    ax = fig.add_subplot(gs[:, 0])
    axx, axy = fig.add_subplot(gs[0, 1]), fig.add_subplot(gs[1, 1], sharex=None)
    if scenario is not None:
        _draw_walls(ax, floor_plan(scenario))
    t0 = truth[0][0]
    true_paths: dict[int, list[tuple[float, float, float]]] = {}
    for t, ids, xy in truth:
        for i, p in zip(ids.tolist(), xy, strict=True):
            true_paths.setdefault(i, []).append((t - t0, p[0], p[1]))
    for i, pts in sorted(true_paths.items()):
        a = np.array(pts)
        kw = {"color": "k", "ls": "--", "lw": 1.0}
        ax.plot(a[:, 1], a[:, 2], **kw, label="truth" if i == min(true_paths) else None)
        axx.plot(a[:, 0], a[:, 1], **kw)
        axy.plot(a[:, 0], a[:, 2], **kw)
    by_id: dict[int, list[tuple[float, float, float]]] = {}
    for t, ids, xy in est:
        for i, p in zip(ids.tolist(), xy, strict=True):
            by_id.setdefault(i, []).append((t - t0, p[0], p[1]))
    cmap = plt.get_cmap("tab10")
    for k, (i, pts) in enumerate(sorted(by_id.items())):
        a = np.array(pts)
        col = cmap(k % 10)
        ax.plot(a[:, 1], a[:, 2], ".", ms=2, color=col, label=f"track {i}" if k < 12 else None)
        axx.plot(a[:, 0], a[:, 1], ".", ms=1.5, color=col)
        axy.plot(a[:, 0], a[:, 2], ".", ms=1.5, color=col)
    ax.set(xlabel="x (m)", ylabel="y (m)", title="tracks vs truth", aspect="equal")
    ax.legend(fontsize=7, loc="upper right", markerscale=4)
    axx.set(ylabel="x (m)")
    axy.set(xlabel="time (s)", ylabel="y (m)")
    for a in (ax, axx, axy):
        a.grid(alpha=0.3)
    return {**_save(fig, out), "tracks": len(by_id), "targets": len(true_paths)}


def plot_image(npz: Path, out: Path) -> dict[str, Any]:
    """An imaging result (``img``, ``x0``, ``y0``, ``dx``, ``dy``) as a heat map, in metres."""
    try:
        with np.load(npz, allow_pickle=False) as data:
            missing = [k for k in ("img", "x0", "y0", "dx", "dy") if k not in data]
            if missing:
                raise PlotError(f"{npz}: missing array {missing[0]!r} (needs img, x0, y0, dx, dy)")
            img = np.asarray(data["img"], dtype=np.float64)
            x0, y0, dx, dy = (float(data[k]) for k in ("x0", "y0", "dx", "dy"))
            method = str(data["method"]) if "method" in data else "image"
    except (OSError, ValueError) as exc:
        if isinstance(exc, PlotError):
            raise
        raise PlotError(f"{npz}: not an image .npz ({exc})") from None
    if img.ndim != 2 or img.size == 0:
        raise PlotError(f"{npz}: img must be a non-empty 2-D array, got shape {img.shape}")
    if not (dx > 0 and dy > 0):
        raise PlotError(f"{npz}: dx and dy must be positive, got {dx}, {dy}")
    ny, nx = img.shape
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(8, 6), layout="constrained")
    extent = (x0 - dx / 2, x0 + (nx - 0.5) * dx, y0 - dy / 2, y0 + (ny - 0.5) * dy)
    im = ax.imshow(img, origin="lower", extent=extent, cmap="viridis", interpolation="nearest")
    fig.colorbar(im, ax=ax, label="image value (arb. units)")
    ax.set(xlabel="x (m)", ylabel="y (m)", title=method, aspect="equal")
    return {**_save(fig, out), "shape": [ny, nx]}


def plot_channel(
    recording: Path, node: str, out: Path, rx: str | None = None, max_range: float = 30.0
) -> dict[str, Any]:
    """Radargram: |h| in dB (re its maximum) over bistatic range and time, one receiver."""
    info: NodeInfo | None = None
    times, rows = [], []
    for rec in read_recording(recording):
        kind = rec.message_kind
        if kind not in ("node_info", "ir") or f"/node/{node}/" not in rec.topic:
            continue
        try:
            if kind == "node_info":
                info = NodeInfo.from_wire(rec.payload)
                continue
            msg = Ir.from_wire(rec.payload)
        except ProtocolError:
            continue
        if rx is None:
            rx = msg.rx[0]
        if rx not in msg.rx:
            continue
        times.append(msg.t)
        rows.append(np.abs(msg.h[msg.rx.index(rx)]))
    if info is None or not rows:
        raise PlotError(f"no node_info and ir of node {node!r} in {recording}")
    r = info.radar
    rng = C * (r.t0 + np.arange(len(rows[0])) / r.fs)
    keep = rng <= max_range
    mag = np.array(rows)[:, keep]
    db = 20 * np.log10(mag / max(float(mag.max()), 1e-30) + 1e-12)
    t = np.array(times) - times[0]
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(9, 5), layout="constrained")
    im = ax.imshow(
        db.T,
        origin="lower",
        aspect="auto",
        extent=(t[0], t[-1] if t[-1] > t[0] else t[0] + 1, rng[keep][0], rng[keep][-1]),
        vmin=-60,
        vmax=0,
        cmap="magma",
    )
    fig.colorbar(im, ax=ax, label="|h| (dB re max)")
    ax.set(xlabel="time (s)", ylabel="bistatic range (m)", title=f"radargram {node}/{rx}")
    return {**_save(fig, out), "impulse_responses": len(rows)}


def plot_topology(scenario: Any, out: Path) -> dict[str, Any]:
    """Deployment layout of a scenario: walls, objects, sensors and beams, people's paths."""
    from matplotlib.patches import Wedge

    from fusion_center.viewer.state import floor_plan
    from sim_nodes.network import BAT_BEAMWIDTH
    from sim_nodes.scene import BAT_ANTENNAS

    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(9, 7), layout="constrained")
    _draw_walls(ax, floor_plan(scenario))
    for n in scenario.nodes:
        x, y, _, yaw = n.pose
        tx = n.antennas.get("tx")
        width = tx.beamwidth if tx is not None and tx.beamwidth else BAT_BEAMWIDTH
        bore = yaw + (tx.boresight if tx is not None and tx.boresight is not None else 0.0)
        ax.plot(x, y, "s", color="tab:green", ms=8, zorder=4)
        half = math.degrees(width) / 2
        deg = math.degrees(bore)
        # The 3 dB beam drawn to 3 m.
        ax.add_patch(Wedge((x, y), 3.0, deg - half, deg + half, alpha=0.12, color="tab:green"))
        for pos, _, _ in BAT_ANTENNAS.values():
            c, s_ = math.cos(yaw), math.sin(yaw)
            ax.plot(x + c * pos[0] - s_ * pos[1], y + s_ * pos[0] + c * pos[1], ".k", ms=3)
        ax.annotate(n.id, (x, y), xytext=(5, 5), textcoords="offset points", fontsize=9)
    cmap = plt.get_cmap("tab10")
    for k, p in enumerate(scenario.people):
        w = np.array(p.waypoints, dtype=float)
        ax.plot(w[:, 0], w[:, 1], "-o", ms=3, color=cmap(k % 10), label=f"person {p.id}")
    ax.set(xlabel="x (m)", ylabel="y (m)", title=f"{scenario.name}: deployment", aspect="equal")
    ax.grid(alpha=0.3)
    if scenario.people:
        ax.legend(fontsize=8, loc="upper right")
    return {**_save(fig, out), "nodes": len(scenario.nodes), "people": len(scenario.people)}
