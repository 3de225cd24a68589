"""Offline processing of recordings: ``uwbnet track`` and ``uwbnet eval``.

The same node DSP (:class:`node_agent.core.NodeCore`) and fusion (:class:`FusionCore`) as the
live runtime, driven by the messages of an MCAP file as fast as the machine allows.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import os
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

from fusion_center.core import FusionCore, FusionCoreConfig, tracks_json
from fusion_center.tracking.base import Tracker
from node_agent.core import NodeConfigError, NodeCore, detections_message
from node_agent.dsp.pipeline import NodeDspConfig
from protocol import Detections, Ir, NodeInfo, ProtocolError, Truth
from protocol.recording import decoded_messages, read_recording

log = logging.getLogger(__name__)


class TrackingError(ValueError):
    """A recording or tracks file cannot be processed (one-line message)."""


def make_tracker(method: str) -> Tracker:
    """The tracker of ``method``: ``gmphd`` (Section 9.2, labelled GM-PHD) or ``image``
    (Section 9.1, closest target per sensor and fused image of eq. (23))."""
    if method == "gmphd":
        from fusion_center.tracking.gmphd import GmPhdTracker

        return GmPhdTracker()
    if method == "image":
        from fusion_center.tracking.fused_image import FusedImageTracker

        return FusedImageTracker()
    raise TrackingError(f"unknown tracking method {method!r} (gmphd, image)")


@dataclasses.dataclass(slots=True)
class TrackStats:
    """Counts of an offline tracking run."""

    messages: int = 0
    ir: int = 0
    detections_in: int = 0
    updates: int = 0
    rejected: int = 0
    nodes: int = 0

    def as_dict(self) -> dict[str, int]:
        return dataclasses.asdict(self)


def track_recording(
    path: str | os.PathLike[str],
    out: str | os.PathLike[str],
    *,
    method: str = "gmphd",
    dsp_config: NodeDspConfig | None = None,
    fusion_config: FusionCoreConfig | None = None,
    progress: Callable[[int], None] | None = None,
) -> TrackStats:
    """Run node DSP and fusion over a recording, writing one JSON line per fusion update.

    ``ir`` messages are processed by the DSP of the receiving node, built from its
    ``node_info``; a recording without ``ir`` but with ``detections`` is fused directly. The
    output appears under ``out`` only when complete. Bad messages are counted in
    ``rejected`` and logged; a corrupt recording raises :class:`RecordingError`.
    """
    out = Path(out)
    partial = out.with_name(out.name + ".partial")
    stats = TrackStats()
    fusion = FusionCore(make_tracker(method), fusion_config)
    cores: dict[str, NodeCore] = {}
    infos: dict[str, NodeInfo] = {}
    have_ir: set[str] = set()
    try:
        with open(partial, "w", encoding="utf-8") as f:

            def emit(outputs: list[Any]) -> None:
                for o in outputs:
                    f.write(json.dumps(tracks_json(o), separators=(",", ":")) + "\n")
                    stats.updates += 1

            for msg in decoded_messages(path, ("node_info", "ir", "detections"), stats, progress):
                if isinstance(msg, NodeInfo):
                    infos[msg.src] = msg
                    fusion.add_node(msg)
                    core = cores.get(msg.src)
                    try:
                        if core is None:
                            cores[msg.src] = NodeCore(msg, dsp_config, infos)
                        else:
                            core.update_info(msg)
                    except NodeConfigError as exc:
                        stats.rejected += 1
                        log.warning("node_info rejected: %s", exc)
                    for c in cores.values():
                        c.peers = infos
                elif isinstance(msg, Ir):
                    stats.ir += 1
                    core = cores.get(msg.src)
                    if core is None:
                        stats.rejected += 1
                        log.warning("ir of %s before its node_info: rejected", msg.src)
                        continue
                    if msg.src not in have_ir:
                        have_ir.add(msg.src)
                        fusion.expected = frozenset(have_ir)
                    try:
                        result = core.process(msg)
                    except (NodeConfigError, ValueError) as exc:
                        stats.rejected += 1
                        log.warning("ir of %s rejected: %s", msg.src, exc)
                        continue
                    det = detections_message(msg, result, src=msg.src, seq=msg.seq)
                    emit(fusion.add_detections(det))
                elif isinstance(msg, Detections) and msg.src not in have_ir:
                    stats.detections_in += 1
                    emit(fusion.add_detections(msg))
            emit(fusion.flush())
        stats.nodes = len(infos)
        os.replace(partial, out)
    except BaseException:
        partial.unlink(missing_ok=True)
        raise
    return stats


# --- evaluation ------------------------------------------------------------------------------

TruthSeries = list[tuple[float, np.ndarray, np.ndarray]]


def read_truth(path: str | os.PathLike[str]) -> TruthSeries:
    """The ``truth`` messages of a recording as ``(t, ids (m,), xy (m, 2))``, in time order."""
    series: TruthSeries = []
    for rec in read_recording(path):
        if rec.message_kind != "truth":
            continue
        try:
            msg = Truth.from_wire(rec.payload)
        except ProtocolError as exc:
            log.warning("truth rejected: %s", exc)
            continue
        ids = np.array([tg.id for tg in msg.targets], dtype=np.int64)
        xy = np.array([(tg.x, tg.y) for tg in msg.targets], dtype=np.float64).reshape(-1, 2)
        series.append((msg.t, ids, xy))
    series.sort(key=lambda s: s[0])
    return series


def read_tracks(path: str | os.PathLike[str]) -> Iterator[tuple[float, np.ndarray, np.ndarray]]:
    """The lines of a tracks JSONL file as ``(t, ids (n,), xy (n, 2))``."""
    try:
        f = open(path, encoding="utf-8")
    except OSError as exc:
        raise TrackingError(f"cannot read {path}: {exc.strerror}") from None
    with f:
        for lineno, line in enumerate(f, 1):
            if not line.strip():
                continue
            try:
                rec = json.loads(line)
                t = float(rec["t"])
                tracks = rec["tracks"]
                ids = np.array([int(tr["id"]) for tr in tracks], dtype=np.int64)
                xy = np.array(
                    [(float(tr["x"]), float(tr["y"])) for tr in tracks], dtype=np.float64
                ).reshape(-1, 2)
            except (ValueError, KeyError, TypeError) as exc:
                raise TrackingError(f"{path}:{lineno}: not a tracks line ({exc})") from None
            yield t, ids, xy


def evaluate_files(
    truth_path: str | os.PathLike[str],
    tracks_path: str | os.PathLike[str],
    *,
    skip: float = 2.0,
    cutoff: float = 1.0,
) -> dict[str, Any]:
    """OSPA/GOSPA, cardinality, ID switches and RMSE of a tracks file against a recording's
    truth (see :func:`fusion_center.tracking.metrics.evaluate`)."""
    from fusion_center.tracking.metrics import evaluate

    truth = read_truth(truth_path)
    if not truth:
        raise TrackingError(f"{truth_path}: no truth messages")
    tracks = list(read_tracks(tracks_path))
    if not tracks:
        raise TrackingError(f"{tracks_path}: no tracks lines")
    return evaluate(truth, tracks, c=cutoff, skip=skip)
