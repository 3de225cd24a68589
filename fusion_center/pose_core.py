"""The fusion center's localization of mobile nodes, I/O-free: ``node_info`` and ranging
``detections`` (with ``links``, docs/localization.md) in, one pose per ranging round out.

Shared by the live service (which publishes ``poses``) and offline ``uwbnet localize``.
Anchors are the static nodes (``mobile`` false) whose ``node_info`` gives their position; a
mobile node is localized from its ``links`` by a
:class:`~fusion_center.localization.mobile.RangingLocalizer` of its own. Links to unknown
anchors are counted and ignored; a ranging round before any anchor is known is counted.
"""

from __future__ import annotations

import dataclasses
import logging
import math

from fusion_center.localization.mobile import LocalizerConfig, PoseResult, RangingLocalizer
from protocol import Detections, NodeInfo, PoseEstimate, Poses

log = logging.getLogger(__name__)


@dataclasses.dataclass(slots=True)
class PoseCounters:
    """What the pose core accepted and rejected."""

    rounds: int = 0
    poses: int = 0
    unknown_anchor: int = 0
    no_fix: int = 0
    duplicates: int = 0


class PoseCore:
    """Per-mobile-node localization from ranging rounds.

    Parameters
    ----------
    config : LocalizerConfig
        The localizer of every mobile node.
    """

    def __init__(self, config: LocalizerConfig | None = None) -> None:
        self.config = config or LocalizerConfig()
        self.anchors: dict[str, tuple[float, float, float]] = {}
        self.heights: dict[str, float] = {}
        self.localizers: dict[str, RangingLocalizer] = {}
        self.counters = PoseCounters()
        #: Anchors named in links whose ``node_info`` has not arrived (the service asks them).
        self.unknown_anchors: set[str] = set()
        self._last_t: dict[str, float] = {}

    def add_node(self, info: NodeInfo) -> None:
        """Take a node's description: an anchor's position or a mobile node's height."""
        if info.mobile:
            self.heights[info.src] = float(info.pose[2])
            return
        self.unknown_anchors.discard(info.src)
        pos = (float(info.pose[0]), float(info.pose[1]), float(info.pose[2]))
        if self.anchors.get(info.src) != pos:
            self.anchors[info.src] = pos
            # anchors changed: localizers rebuild with the new set (their tracks restart)
            self.localizers.clear()

    def add_ranging(self, det: Detections) -> tuple[str, PoseResult] | None:
        """One ranging round of mobile node ``det.src``; its pose update, or None."""
        links = det.links or {}
        self.counters.rounds += 1
        if det.t <= self._last_t.get(det.src, -float("inf")):
            self.counters.duplicates += 1
            return None
        self._last_t[det.src] = det.t
        known = {
            a: (lk.range, lk.std, lk.los, lk.snr_db) for a, lk in links.items() if a in self.anchors
        }
        self.counters.unknown_anchor += len(links) - len(known)
        self.unknown_anchors |= set(links) - set(self.anchors)
        if not known:
            self.counters.no_fix += 1
            return None
        loc = self.localizers.get(det.src)
        if loc is None:
            loc = RangingLocalizer(self.anchors, self.heights.get(det.src, 0.0), self.config)
            self.localizers[det.src] = loc
        res = loc.step(det.t, known)
        if not math.isfinite(res.pose[0]):
            self.counters.no_fix += 1
            return None
        self.counters.poses += 1
        return det.src, res


def poses_message(results: dict[str, PoseResult], *, src: str, seq: int, t: float) -> Poses:
    """The ``poses`` message (PROTOCOL.md) of the latest pose of each mobile node."""
    return Poses(
        src=src,
        seq=seq,
        t=t,
        poses={
            node: PoseEstimate(pose=r.pose, cov=tuple(map(tuple, r.cov.tolist())), los=r.los)
            for node, r in results.items()
        },
    )


def _sig(v: float) -> float:
    """``v`` to 6 significant digits (JSON-safe; inf and nan as they are)."""
    return float(f"{v:.6g}")


def pose_json(node: str, res: PoseResult) -> dict[str, object]:
    """One JSONL record of ``uwbnet localize``: the tracked pose and the snapshot fix."""
    fix = res.fix
    return {
        "t": round(res.t, 6),
        "node": node,
        "pose": [round(v, 5) for v in res.pose],
        # significant digits: sub-millimetre poses have variances of 1e-8 m² and less
        "cov": [[_sig(v) for v in row] for row in res.cov.tolist()],
        "los": res.los,
        "fix": [round(float(v), 5) for v in fix.position] if fix.ok else None,
        "fix_cov": [[_sig(float(v)) for v in row] for row in fix.cov] if fix.ok else None,
        "fix_reason": fix.reason,
    }
