"""``uwbnet image FILE.mcap``: Kirchhoff or cross-correlated image of a recording (I/O shell).

Reads ``node_info``, ``poses`` and ``ir`` (:mod:`fusion_center.image_input`), images with
:mod:`fusion_center.imaging` on a thread pool (numpy releases the GIL in the kernels), writes
the ``.npz`` (``img``, ``x0``, ``y0``, ``dx``, ``dy``, PROTOCOL.md ``image``) and an optional
PNG, and, given the scenario, the quality figures.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from fusion_center.image_input import ImagingError, ObservationAssembler, Rows, stack_rows
from fusion_center.imaging import Grid, Observations, cross_correlated_image, kirchhoff_image
from protocol import Ir, NodeInfo, Poses, ProtocolError, decode
from protocol.recording import read_recording

METHODS = ("kirchhoff", "xcorr")


@dataclass(frozen=True, slots=True, kw_only=True)
class ImageOptions:
    """How ``uwbnet image`` images (see ``docs/imaging.md``)."""

    method: str = "kirchhoff"
    nx: int = 400
    ny: int = 400
    bounds: tuple[float, float, float, float] | None = None
    margin: float = 1.0
    z: float | None = None
    envelope: bool = True
    pattern: bool = False
    gate: float = 0.3
    workers: int = 2


def read_observations(
    path: str | os.PathLike[str], progress: Callable[[int], None] | None = None
) -> tuple[Observations, int]:
    """All ``ir`` of a recording as observations; also the number of rejected messages.

    Raises :class:`ImagingError` for an empty recording, mismatched sampling between nodes, or
    a mobile node without poses.
    """
    asm = ObservationAssembler()
    rows: list[Rows] = []
    rejected = 0
    for m in read_recording(path):
        if progress is not None:
            progress(len(m.payload))
        kind = m.message_kind
        if kind not in ("node_info", "ir", "poses"):
            continue
        try:
            msg = decode(m.payload)
        except ProtocolError:
            rejected += 1
            continue
        if isinstance(msg, NodeInfo):
            asm.add_info(msg)
        elif isinstance(msg, Poses):
            asm.add_poses(msg)
        elif isinstance(msg, Ir):
            rows.append(asm.rows(msg))
    if not rows or asm.sampling is None:
        raise ImagingError(f"{path}: no ir messages to image (empty recording?)")
    return stack_rows(rows, asm.sampling), rejected


def default_grid(obs: Observations, opts: ImageOptions) -> Grid:
    """The image plane: ``opts.bounds`` or the antennas' extent plus ``margin``; at the mean
    antenna height unless ``opts.z``."""
    if opts.bounds is not None:
        x0, x1, y0, y1 = opts.bounds
    else:
        p = np.concatenate([obs.tx, obs.rx])
        x0, y0 = p[:, :2].min(axis=0) - opts.margin
        x1, y1 = p[:, :2].max(axis=0) + opts.margin
    z = opts.z if opts.z is not None else float(np.mean(np.concatenate([obs.tx, obs.rx])[:, 2]))
    return Grid.covering(float(x0), float(x1), float(y0), float(y1), opts.nx, opts.ny, z)


def make_image(
    obs: Observations,
    grid: Grid,
    opts: ImageOptions,
    progress: Callable[[int], None] | None = None,
) -> np.ndarray:
    """The image of ``opts.method`` on ``grid`` over ``opts.workers`` threads."""
    kw: dict[str, Any] = {
        "envelope": opts.envelope,
        "gate": opts.gate,
        "pattern": opts.pattern,
        "progress": progress,
    }
    with ThreadPoolExecutor(max_workers=opts.workers) as pool:
        kw["map_fn"] = pool.map
        try:
            if opts.method == "kirchhoff":
                return kirchhoff_image(obs, grid, **kw)
            if opts.method == "xcorr":
                return cross_correlated_image(obs, grid, **kw)
        except ValueError as exc:
            raise ImagingError(str(exc)) from None
    raise ImagingError(f"unknown imaging method {opts.method!r} ({', '.join(METHODS)})")


def write_npz(out: Path, img: np.ndarray, grid: Grid, method: str) -> None:
    """The image as ``.npz`` (written to ``.partial``, then renamed)."""
    part = out.with_name(out.name + ".partial")
    with open(part, "wb") as fh:
        np.savez(
            fh,
            img=img.astype(np.float32),
            x0=grid.x0,
            y0=grid.y0,
            dx=grid.dx,
            dy=grid.dy,
            method=method,
        )
    os.replace(part, out)


def write_png(
    out: Path,
    img: np.ndarray,
    grid: Grid,
    title: str,
    *,
    db_range: float = 30.0,
    outlines: list[Any] | None = None,
    positions: np.ndarray | None = None,
) -> None:
    """The image in dB re its maximum (``-db_range`` .. 0: the same colour scale for every
    image), with optional scene outlines and antenna positions."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    a = np.abs(img)
    db = 20 * np.log10(np.maximum(a / max(float(a.max()), 1e-30), 10 ** (-db_range / 20)))
    ext = (
        grid.x0 - grid.dx / 2,
        grid.x0 + (grid.nx - 0.5) * grid.dx,
        grid.y0 - grid.dy / 2,
        grid.y0 + (grid.ny - 0.5) * grid.dy,
    )
    fig, ax = plt.subplots(figsize=(7, 6.2))
    im = ax.imshow(db, origin="lower", extent=ext, vmin=-db_range, vmax=0, cmap="inferno")
    for poly in outlines or []:
        p = np.asarray(poly, float)
        ax.plot(p[:, 0], p[:, 1], color="cyan", lw=0.6, alpha=0.7)
    if positions is not None and len(positions):
        ax.plot(positions[:, 0], positions[:, 1], ".", color="lime", ms=2)
    ax.set(xlabel="x (m)", ylabel="y (m)", title=title, aspect="equal")
    fig.colorbar(im, ax=ax, label="dB re maximum")
    fig.tight_layout()
    part = out.with_name(out.stem + ".partial" + out.suffix)
    fig.savefig(part, dpi=110)
    plt.close(fig)
    os.replace(part, out)


def scenario_figures(img: np.ndarray, grid: Grid, scenario: Any) -> dict[str, Any]:
    """Quality figures against a scenario's objects and room outline (``quality`` module)."""
    from fusion_center.imaging.quality import artefact_ratio, surface_errors

    objects = [(o.id, o.footprint) for o in scenario.objects]
    polys = [p for _, p in objects]
    if scenario.room is not None:
        polys.append(scenario.room.outline)
    polys += [[w.start, w.end] for w in scenario.walls]
    errs = surface_errors(img, grid, [p for _, p in objects]) if objects else np.array([])
    return {
        "object_errors_m": {
            oid: (None if not np.isfinite(e) else round(float(e), 4))
            for (oid, _), e in zip(objects, errs, strict=True)
        },
        "max_object_error_m": round(float(np.nanmax(errs)), 4) if errs.size else None,
        "artefact_ratio": round(artefact_ratio(img, grid, polys), 4),
    }
