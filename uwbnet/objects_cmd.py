"""``uwbnet objects FILE.mcap``: contour, material and class of a recorded circular scan.

Reads the scan's ``node_info`` and ``ir`` messages (the layout of
:mod:`sim_nodes.circle_record`), runs :func:`fusion_center.objects.scan.process_scan` and
classifies the contour against the alphabet's reference contours. The references are made by
the simulator's geometric echo model and the same imaging chain (:func:`reference_contours`),
for the scan's own radius and antenna baseline.
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np

from fusion_center.objects.alphabet import alphabet, place
from fusion_center.objects.fuzzy import FuzzyRpmImager, monostatic_distance
from fusion_center.objects.recognition import CssRecognizer
from fusion_center.objects.scan import ScanData, process_scan, track_centre
from protocol import Ir, NodeInfo
from protocol.errors import ProtocolError
from protocol.recording import read_recording
from sim_nodes.channel.prism import PrismTarget
from sim_nodes.circle_scan import CircleTrack, geometric_wavefronts, scan_echoes

#: Channel of each (tx antenna, rx antenna) pair of a circular scan recording.
CHANNEL_OF = {
    ("tx_v", "rx_v"): "vv",
    ("tx_v", "rx_h"): "hv",
    ("tx_h", "rx_h"): "hh",
    ("tx_h", "rx_v"): "vh",
    ("tx_p", "rx_p"): "pp",
    ("tx_p", "rx_m"): "pm",
}


class ObjectsError(ValueError):
    """The recording is not a usable circular scan (one-line message)."""


def scan_contour(
    vertices: np.ndarray,
    track: CircleTrack,
    rng: np.random.Generator,
    *,
    range_noise: float = 0.002,
    beamwidth: float = np.deg2rad(70.0),
) -> np.ndarray:
    """Contour of a metal prism over ``vertices`` from the fast geometric echo model and the
    fuzzy imaging chain (wavefronts with ``range_noise``), shape (Q, 2)."""
    echoes = scan_echoes(PrismTarget(vertices=vertices), track, beamwidth)
    ranges = geometric_wavefronts(echoes, rng, range_noise=range_noise)
    _, _, toward = track.antennas()
    img = FuzzyRpmImager().image(
        track.positions(), monostatic_distance(ranges, track.baseline), toward, closed=track.closed
    )
    return img.contour


def reference_contours(
    radius: float, baseline: float, *, n_rotations: int = 4, seed: int = 12345
) -> dict[str, list[np.ndarray]]:
    """Reference contours of every alphabet shape: full tracks of ``radius``, the shape
    centred and turned through ``n_rotations`` angles of a quarter turn."""
    rng = np.random.default_rng(seed)
    track = CircleTrack(radius=radius, baseline=baseline)
    turns = np.linspace(0.0, np.pi / 2, n_rotations, endpoint=False)
    return {
        name: [scan_contour(place(v, a, (0.0, 0.0)), track, rng) for a in turns]
        for name, v in alphabet().items()
    }


def load_scan(path: str | os.PathLike[str]) -> ScanData:
    """The circular scan of a recording as :class:`ScanData` (the first scanning node)."""
    info: NodeInfo | None = None
    rows: dict[int, dict[str, np.ndarray]] = {}
    poses: dict[int, tuple[float, ...]] = {}
    try:
        for rec in read_recording(path):
            kind = rec.message_kind
            if kind == "node_info" and info is None:
                info = NodeInfo.from_wire(rec.payload)
            elif kind == "ir" and info is not None:
                ir = Ir.from_wire(rec.payload)
                if ir.src != info.src or ir.pose is None:
                    continue
                tx = ir.tx.partition("/")[2]
                for name, row in zip(ir.rx, ir.h, strict=True):
                    ch = CHANNEL_OF.get((tx, name))
                    if ch is not None:
                        rows.setdefault(ir.frame, {})[ch] = row
                poses[ir.frame] = ir.pose
    except ProtocolError as exc:
        raise ObjectsError(f"{path}: bad message: {exc}") from None
    if info is None:
        raise ObjectsError(f"{path}: no node_info in the recording")
    frames = sorted(f for f, r in rows.items() if {"vv", "hh"} <= set(r))
    if len(frames) < 20:
        raise ObjectsError(
            f"{path}: {len(frames)} scan positions with vv and hh channels (need >= 20; "
            "record a [circle_scan] scenario)"
        )
    channels = {ch for f in frames for ch in rows[f]}
    n = len(rows[frames[0]]["vv"])
    h = {
        ch: np.stack([rows[f].get(ch, np.zeros(n, np.float32)) for f in frames]).astype(float)
        for ch in channels
    }
    for ch in ("hv", "vh", "pp", "pm"):
        h.setdefault(ch, np.zeros((len(frames), n)))
    pose = np.array([poses[f] for f in frames], float)
    ant = info.antennas
    if "tx_v" not in ant or "rx_v" not in ant:
        raise ObjectsError(f"{path}: node {info.src} has no tx_v/rx_v antennas")
    c, s = np.cos(pose[:, 3]), np.sin(pose[:, 3])

    def world(name: str) -> np.ndarray:
        px, py, _ = ant[name].pos
        return np.column_stack([pose[:, 0] + c * px - s * py, pose[:, 1] + s * px + c * py])

    r = info.radar
    return ScanData(h=h, poses=pose, tx=world("tx_v"), rx=world("rx_v"), fs=r.fs, t0=r.t0)


def objects_report(path: str | os.PathLike[str]) -> dict[str, Any]:
    """The JSON report of ``uwbnet objects``: contour, material estimate, recognized class."""
    scan = load_scan(path)
    try:
        result = process_scan(scan)
    except ValueError as exc:
        raise ObjectsError(f"{path}: {exc}") from None
    centre = track_centre(scan.poses)
    radius = float(np.median(np.linalg.norm(scan.poses[:, :2] - centre, axis=1)))
    baseline = float(np.median(np.linalg.norm(scan.tx - scan.rx, axis=1)))
    if len(result.contour) < 8:
        raise ObjectsError(f"{path}: only {len(result.contour)} contour points imaged")
    rec = CssRecognizer(reference_contours(radius, baseline))
    scores = rec.scores(result.contour, closed=result.closed)
    best = int(np.argmin(scores))
    eps = result.permittivity
    return {
        "positions": len(scan.poses),
        "closed_track": result.closed,
        "contour": np.round(result.contour, 4).tolist(),
        "corners_45deg": np.round(result.corner_points, 4).tolist(),
        "material": {
            "permittivity": None if not np.isfinite(eps) else round(eps, 3),
            "emissivity": None
            if not np.isfinite(result.emissivity)
            else round(result.emissivity, 3),
            "metal_like": result.metal_like,
            "depolarization_ratio": round(result.depolarization, 5),
            "surface": "rough" if result.depolarization > 0.01 else "smooth",
            "face_positions": result.n_face_positions,
        },
        "class": rec.names[best],
        "scores": {n: round(float(s), 4) for n, s in zip(rec.names, scores, strict=True)},
    }
