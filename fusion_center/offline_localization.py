"""Offline localization of mobile nodes over a recording: ``uwbnet localize``.

The same :class:`~fusion_center.pose_core.PoseCore` as the live fusion center, driven by the
``node_info`` and ranging ``detections`` of an MCAP file; one JSON line per pose update. The
evaluation compares the poses with the recording's ``truth``: position RMSE of the tracked
pose and of the snapshot fixes, the Cramér-Rao bound of the geometry at the links' true SNR,
and the NLOS identification and false-alarm rates of the eq. (6) test and of the per-impulse-
response classifier.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from fusion_center.localization.crlb import position_error_bound, range_crlb
from fusion_center.localization.mobile import LocalizerConfig
from fusion_center.pose_core import PoseCore, pose_json
from protocol import Detections, NodeInfo, ProtocolError, Truth
from protocol.recording import decoded_messages, read_recording

log = logging.getLogger(__name__)

#: Double-sided RTToA: the time of flight is (e0 + 2 e1 + e2) / 4 of three receive errors.
DS_RANGE_FACTOR = math.sqrt(6.0) / 4.0


class LocalizationError(ValueError):
    """A recording or poses file cannot be processed (one-line message)."""


@dataclasses.dataclass(slots=True)
class LocalizeStats:
    """Counts of an offline localization run."""

    messages: int = 0
    rounds: int = 0
    poses: int = 0
    rejected: int = 0
    anchors: int = 0

    def as_dict(self) -> dict[str, int]:
        return dataclasses.asdict(self)


def localize_recording(
    path: str | os.PathLike[str],
    out: str | os.PathLike[str],
    *,
    method: str = "taylor",
    mitigate: bool = True,
    config: LocalizerConfig | None = None,
    progress: Callable[[int], None] | None = None,
) -> LocalizeStats:
    """Localize every mobile node of a recording, writing one JSON line per pose update
    (:func:`~fusion_center.pose_core.pose_json`); ``out`` appears only when complete."""
    cfg = config or LocalizerConfig()
    cfg = dataclasses.replace(cfg, method=method, mitigate=mitigate)
    core = PoseCore(cfg)
    out = Path(out)
    partial = out.with_name(out.name + ".partial")
    stats = LocalizeStats()
    try:
        with open(partial, "w", encoding="utf-8") as f:
            for msg in decoded_messages(path, ("node_info", "detections"), stats, progress):
                if isinstance(msg, NodeInfo):
                    core.add_node(msg)
                elif isinstance(msg, Detections) and msg.links is not None:
                    stats.rounds += 1
                    res = core.add_ranging(msg)
                    if res is not None:
                        f.write(json.dumps(pose_json(*res), separators=(",", ":")) + "\n")
                        stats.poses += 1
        stats.anchors = len(core.anchors)
        os.replace(partial, out)
    except BaseException:
        partial.unlink(missing_ok=True)
        raise
    return stats


@dataclasses.dataclass(frozen=True, slots=True)
class _TruthRound:
    xy: np.ndarray
    z: float
    links: dict[str, dict[str, Any]]


def read_node_truth(path: str | os.PathLike[str]) -> dict[str, dict[float, _TruthRound]]:
    """``node -> t -> truth`` of the mobile nodes in a recording's ``truth`` messages."""
    out: dict[str, dict[float, _TruthRound]] = {}
    for rec in read_recording(path):
        if rec.message_kind != "truth":
            continue
        try:
            msg = Truth.from_wire(rec.payload)
        except ProtocolError as exc:
            log.warning("truth rejected: %s", exc)
            continue
        links = msg.extra.get("links", {}) if isinstance(msg.extra, dict) else {}
        for node, pose in msg.nodes.items():
            node_links = links.get(node, {}) if isinstance(links, dict) else {}
            out.setdefault(node, {})[round(msg.t, 6)] = _TruthRound(
                xy=np.array(pose[:2]), z=float(pose[2]), links=node_links
            )
    return out


def _read_poses(path: str | os.PathLike[str]) -> list[dict[str, Any]]:
    try:
        f = open(path, encoding="utf-8")
    except OSError as exc:
        raise LocalizationError(f"cannot read {path}: {exc.strerror}") from None
    rows = []
    with f:
        for lineno, line in enumerate(f, 1):
            if not line.strip():
                continue
            try:
                rec = json.loads(line)
                rec["t"] = float(rec["t"])
                rec["pose"] = [float(v) for v in rec["pose"][:2]]
                str(rec["node"])
                dict(rec["los"])
            except (ValueError, KeyError, TypeError) as exc:
                raise LocalizationError(f"{path}:{lineno}: not a poses line ({exc})") from None
            rows.append(rec)
    return rows


def evaluate_localization(
    recording: str | os.PathLike[str],
    poses: str | os.PathLike[str],
    *,
    skip: float = 2.0,
) -> dict[str, Any]:
    """Score a poses file against a recording's truth (after ``skip`` s of track start).

    Returns
    -------
    dict
        ``rmse`` (tracked pose), ``fix_rmse`` (snapshot fixes), ``fix_rate`` (share of rounds
        with a fix), ``crlb`` (RMS of the position error bound over the rounds, every link at
        its double-sided RTToA range bound), ``nlos_detection`` and ``nlos_false_alarm`` (the
        NLOS test's decisions vs the true link states), m and fractions.
    """
    truth = read_node_truth(recording)
    if not truth:
        raise LocalizationError(f"{recording}: no truth of mobile nodes")
    anchors: dict[str, np.ndarray] = {}
    for rec in read_recording(recording):
        if rec.message_kind == "node_info":
            try:
                info = NodeInfo.from_wire(rec.payload)
            except ProtocolError:
                continue
            if not info.mobile:
                anchors[info.src] = np.array(info.pose[:3])
    rows = _read_poses(poses)
    if not rows:
        raise LocalizationError(f"{poses}: no pose lines")
    t_first = min(r["t"] for r in rows)
    err, fix_err, bounds = [], [], []
    n_rounds = n_fix = 0
    tp = fn = fp = tn = 0
    for r in rows:
        tr = truth.get(r["node"], {}).get(round(r["t"], 6))
        if tr is None or r["t"] < t_first + skip:
            continue
        n_rounds += 1
        err.append(np.subtract(r["pose"], tr.xy))
        if r.get("fix") is not None:
            n_fix += 1
            fix_err.append(np.subtract(r["fix"][:2], tr.xy))
        ids = [a for a in tr.links if a in anchors]
        if ids:
            pos = np.array([anchors[a] for a in ids])
            std = np.array(
                [
                    DS_RANGE_FACTOR * range_crlb(tr.links[a]["ebn0_db"], tr.links[a]["beta"])
                    for a in ids
                ]
            )
            bounds.append(position_error_bound(tr.xy, pos[:, :2], std, pos[:, 2] - tr.z))
        for a, link in tr.links.items():
            if a not in r["los"]:
                continue
            flagged = not r["los"][a]
            if link["los"]:
                fp += flagged
                tn += not flagged
            else:
                tp += flagged
                fn += not flagged

    def rms(e: list[np.ndarray]) -> float | None:
        return round(float(np.sqrt(np.mean(np.sum(np.square(e), axis=1)))), 5) if e else None

    return {
        "evaluated_rounds": n_rounds,
        "rmse": rms(err),
        "fix_rmse": rms(fix_err),
        "fix_rate": round(n_fix / n_rounds, 4) if n_rounds else None,
        "crlb": round(float(np.sqrt(np.mean(np.square(bounds)))), 5) if bounds else None,
        "nlos_links": tp + fn,
        "los_links": fp + tn,
        "nlos_detection": round(tp / (tp + fn), 4) if tp + fn else None,
        "nlos_false_alarm": round(fp / (fp + tn), 4) if fp + tn else None,
    }
