"""What the live web view shows, as JSON-ready dicts built from fusion-center snapshots.

:class:`LiveViewModel` turns one :class:`ViewInput` (a snapshot handed over by the fusion
service, never a reference into its working state) into the page's ``state`` document: tracks
with short tails, sensors with their state and health, and the moving-target image of eq. (23)
of the CoLOR chapter accumulated from the sensors' local position estimates. No I/O, no clocks:
the caller passes ``now``.
"""

from __future__ import annotations

import base64
import dataclasses
import itertools
import math
from collections import deque
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import numpy as np

from fusion_center.tracking.base import TrackerOutput
from fusion_center.tracking.fused_image import add_gaussians
from protocol import Image, NodeInfo, Poses, Status


@dataclasses.dataclass(frozen=True, slots=True, kw_only=True)
class NodeView:
    """What the fusion center knows of one node for the view (a copy, not shared state)."""

    alive: bool = False
    detections: int = 0
    latency_ms: float = math.nan
    status: Status | None = None


@dataclasses.dataclass(frozen=True, slots=True, kw_only=True)
class ViewInput:
    """One snapshot of the fusion center for the view.

    Parameters
    ----------
    output : latest tracker output, or None before the first fusion update.
    nodes : node id -> health.
    infos : node id -> description (pose, antennas).
    estimates : local position estimates since the last snapshot, ``(t, positions (k, 2),
        cov (k, 2, 2))`` in world x, y (m, m²).
    image : the latest ``image`` message (migration or other imaging), if any.
    poses : the latest ``poses`` message (NLOS decisions of localized nodes), if any.
    counters : free-form fusion counters shown on the page.
    """

    output: TrackerOutput | None
    nodes: Mapping[str, NodeView]
    infos: Mapping[str, NodeInfo]
    estimates: Sequence[tuple[float, np.ndarray, np.ndarray | None]] = ()
    image: Image | None = None
    poses: Poses | None = None
    counters: Mapping[str, Any] = dataclasses.field(default_factory=dict)


@dataclasses.dataclass(frozen=True, slots=True, kw_only=True)
class LiveViewConfig:
    """Parameters of the view.

    Parameters
    ----------
    tail_seconds : length of a track's tail, s.
    tail_step : spacing of a tail's points, s (the page draws a line through them).
    rate_window : window over which a node's detection rate is averaged, s.
    resolution : pixel size of the moving-target image, m.
    forgetting_per_s : forgetting of the moving-target image per second; eq. (23)'s ``λ`` per
        fusion frame is ``forgetting_per_s ** frame_period``.
    extent_std : person extent added to each estimate's covariance, m (as the fused-image
        tracker does).
    image_max_age : an ``image`` message older than this (s, network time) is no longer shown.
    image_max_pixels : the moving-target image's longest side, pixels: over a large site the
        pixels grow beyond ``resolution`` (the page scales the image anyway).
    """

    tail_seconds: float = 3.0
    tail_step: float = 0.2
    rate_window: float = 2.0
    resolution: float = 0.1
    forgetting_per_s: float = 1e-5
    extent_std: float = 0.2
    image_max_age: float = 10.0
    image_max_pixels: int = 160


def _r(x: float, nd: int = 3) -> float | None:
    """Round for JSON; None for NaN/Inf (JSON has no NaN)."""
    x = float(x)
    return round(x, nd) if math.isfinite(x) else None


class LiveViewModel:
    """Keeps tails, rates and the moving-target image between snapshots; not thread-safe
    (one owner: the web server's thread).

    Parameters
    ----------
    walls : segments ``(x1, y1, x2, y2)`` of the floor plan, m.
    config : LiveViewConfig, optional
    """

    def __init__(
        self,
        walls: Iterable[Sequence[float]] = (),
        config: LiveViewConfig | None = None,
    ) -> None:
        self.config = config or LiveViewConfig()
        self.walls = [[float(v) for v in w] for w in walls]
        self._tails: dict[int, deque[tuple[float, float, float]]] = {}
        self._static: dict[str, tuple[NodeInfo | None, dict[str, Any]]] = {}
        self._det_hist: dict[str, deque[tuple[float, int]]] = {}
        self._img: np.ndarray | None = None
        self._img_x0 = self._img_y0 = 0.0
        self._img_t: float | None = None
        self._img_res = self.config.resolution
        self._pending: list[tuple[float, np.ndarray, np.ndarray | None]] = []
        self._bounds: list[float] | None = None
        self.updates = 0

    # -- scene -----------------------------------------------------------------------------

    def bounds(self, infos: Mapping[str, NodeInfo]) -> list[float]:
        """Extent ``[x_min, x_max, y_min, y_max]`` (m) of walls and nodes, with a 0.5 m margin."""
        xs = [w[0] for w in self.walls] + [w[2] for w in self.walls]
        ys = [w[1] for w in self.walls] + [w[3] for w in self.walls]
        xs += [i.pose[0] for i in infos.values()]
        ys += [i.pose[1] for i in infos.values()]
        if not xs:
            return [-5.0, 5.0, -5.0, 5.0]
        m = 0.5
        return [min(xs) - m, max(xs) + m, min(ys) - m, max(ys) + m]

    def scene(self, infos: Mapping[str, NodeInfo]) -> dict[str, Any]:
        """The static part: walls and the drawing extent."""
        return {"walls": self.walls, "bounds": [_r(b) for b in self.bounds(infos)]}

    # -- per update ------------------------------------------------------------------------

    def update(self, now: float, snap: ViewInput) -> dict[str, Any]:
        """Fold one snapshot in; return the page's ``state`` document.

        ``now`` is network time (s): it ages tails and rates.
        """
        self.updates += 1
        # Estimates wait for the next image() call (the image is refreshed less often).
        self._pending.extend(snap.estimates)
        if len(self._pending) > 20000:
            del self._pending[: len(self._pending) - 20000]
        out = snap.output
        tracks = []
        live_ids = set()
        if out is not None:
            for tr in out.tracks:
                live_ids.add(tr.id)
                tail = self._tails.setdefault(tr.id, deque())
                if not tail or out.t - tail[-1][0] >= self.config.tail_step:
                    tail.append((out.t, round(float(tr.x), 2), round(float(tr.y), 2)))
                while tail and tail[0][0] < out.t - self.config.tail_seconds:
                    tail.popleft()
                tracks.append(
                    {
                        "id": int(tr.id),
                        "x": _r(tr.x),
                        "y": _r(tr.y),
                        "vx": _r(tr.vx),
                        "vy": _r(tr.vy),
                        "w": _r(tr.w),
                        # The sampled tail, then the current position.
                        "tail": [[x, y] for _, x, y in tail]
                        + (
                            [[round(float(tr.x), 2), round(float(tr.y), 2)]]
                            if tail[-1][0] != out.t
                            else []
                        ),
                    }
                )
        for tid in list(self._tails):
            if tid not in live_ids:
                del self._tails[tid]
        nlos = self._nlos(snap)
        nodes = []
        for node in sorted(set(snap.nodes) | set(snap.infos)):
            h = snap.nodes.get(node, NodeView())
            info = snap.infos.get(node)
            st = h.status
            state = "lost" if not h.alive else ("nlos" if nlos.get(node) else "alive")
            if st is not None and bool(st.extra.get("nlos", False)) and h.alive:
                state = "nlos"
            nodes.append(
                {
                    **self._node_static(node, info),
                    "state": state,
                    "rate": _r(self._rate(node, now, h.detections), 1),
                    "drops": st.dropped if st else None,
                    "late": st.late_slots if st else None,
                    "acquired": st.acquired if st else None,
                    # A lost node's last latency and CPU load are history, not health.
                    "latency_ms": _r(h.latency_ms, 1) if h.alive else None,
                    "cpu": _r(st.cpu, 3) if st and h.alive else None,
                }
            )
        return {
            "t": _r(out.t if out is not None else now),
            "now": _r(now),
            "seq": self.updates,
            "n_estimate": _r(out.n_estimate) if out is not None else 0.0,
            "tracks": tracks,
            "nodes": nodes,
            "counters": dict(snap.counters),
        }

    def _node_static(self, node: str, info: NodeInfo | None) -> dict[str, Any]:
        """id, role, pose and boresight of a node, recomputed only when its info changes."""
        cached = self._static.get(node)
        if cached is not None and cached[0] is info:
            return cached[1]
        doc = {
            "id": node,
            "role": info.role if info else None,
            "pose": [_r(v) for v in info.pose] if info else None,
            "boresight": _r(_boresight(info)) if info else None,
        }
        self._static[node] = (info, doc)
        return doc

    def _rate(self, node: str, now: float, count: int) -> float:
        """Detection messages per second over the last ``rate_window`` s."""
        hist = self._det_hist.setdefault(node, deque())
        hist.append((now, count))
        while len(hist) > 2 and hist[1][0] <= now - self.config.rate_window:
            hist.popleft()
        (t0, c0), (t1, c1) = hist[0], hist[-1]
        return (c1 - c0) / (t1 - t0) if t1 > t0 else 0.0

    @staticmethod
    def _nlos(snap: ViewInput) -> dict[str, bool]:
        """Node id -> True where a localized node's pose estimate says its link is NLOS."""
        out: dict[str, bool] = {}
        if snap.poses is None:
            return out
        for mobile, est in snap.poses.poses.items():
            for anchor, los in est.los.items():
                if not los:
                    out[anchor] = True
                    out[mobile] = True
        return out

    # -- image -----------------------------------------------------------------------------

    def image(self, now: float, snap: ViewInput) -> dict[str, Any] | None:
        """The heat map: a recent ``image`` message if there is one, else the moving-target
        image of eq. (23) accumulated from the local estimates in ``snap``.

        Returns the ``image`` document (8-bit, base64, row 0 at ``y0``), or None when there is
        nothing to show yet.
        """
        msg = snap.image
        if msg is not None and now - msg.t <= self.config.image_max_age:
            img = np.asarray(msg.img, dtype=np.float64)
            return _image_doc(img, msg.x0, msg.y0, msg.dx, msg.dy, msg.method, msg.t)
        self._accumulate(now, snap)
        if self._img is None:
            return None
        res = self._img_res
        return _image_doc(self._img, self._img_x0, self._img_y0, res, res, "eq23", now)

    def _accumulate(self, now: float, snap: ViewInput) -> None:
        """Eq. (23) with the forgetting applied per elapsed second, over the view's extent."""
        cfg = self.config
        estimates, self._pending = self._pending, []
        if self._img is None:
            if not snap.infos:
                return
            b = self.bounds(snap.infos)
            side = max(b[1] - b[0], b[3] - b[2])
            res = self._img_res = max(cfg.resolution, side / cfg.image_max_pixels)
            nx = math.ceil((b[1] - b[0]) / res) + 1
            ny = math.ceil((b[3] - b[2]) / res) + 1
            self._img = np.zeros((ny, nx))
            self._img_x0, self._img_y0 = b[0], b[2]
        if self._img_t is not None and now > self._img_t:
            self._img *= cfg.forgetting_per_s ** (now - self._img_t)
        self._img_t = now
        if not estimates:
            return
        pos = [np.asarray(e[1], dtype=np.float64).reshape(-1, 2) for e in estimates]
        p = np.concatenate(pos)
        covs = [
            np.asarray(c, dtype=np.float64).reshape(-1, 2, 2)
            if c is not None
            else np.broadcast_to(np.eye(2) * 0.01, (np.asarray(pos).reshape(-1, 2).shape[0], 2, 2))
            for _, pos, c in estimates
        ]
        cov = np.concatenate(covs) + cfg.extent_std**2 * np.eye(2)
        # Each estimate has already been forgotten for the time since it was made.
        age = np.concatenate(
            [np.full(len(x), now - e[0]) for x, e in zip(pos, estimates, strict=True)]
        )
        w = cfg.forgetting_per_s ** np.clip(age, 0.0, None)
        add_gaussians(self._img, self._img_x0, self._img_y0, self._img_res, p, cov, weights=w)


def _boresight(info: NodeInfo) -> float:
    """World yaw (rad) of the node's first transmitting antenna's boresight."""
    for a in info.antennas.values():
        if a.tx:
            return float(info.pose[3] + a.boresight)
    return float(info.pose[3])


def _image_doc(
    img: np.ndarray, x0: float, y0: float, dx: float, dy: float, method: str, t: float
) -> dict[str, Any]:
    """8-bit quantised heat map (0 = image minimum, 255 = maximum), base64, C order."""
    finite = np.isfinite(img)
    lo = float(img[finite].min()) if finite.any() else 0.0
    hi = float(img[finite].max()) if finite.any() else 0.0
    span = hi - lo if hi > lo else 1.0
    q = np.clip(np.where(finite, (img - lo) / span, 0.0) * 255.0, 0, 255).astype(np.uint8)
    return {
        "t": _r(t),
        "method": method,
        "x0": _r(x0),
        "y0": _r(y0),
        "dx": _r(dx, 4),
        "dy": _r(dy, 4),
        "nx": int(img.shape[1]),
        "ny": int(img.shape[0]),
        "min": _r(lo, 4),
        "max": _r(hi, 4),
        "data": base64.b64encode(q.tobytes()).decode("ascii"),
    }


def floor_plan(scenario: Any) -> list[list[float]]:
    """Wall segments ``[x1, y1, x2, y2]`` (m) of a scenario: its walls, room outline and
    object footprints."""
    segs = [[*w.start, *w.end] for w in scenario.walls]
    if scenario.room is not None:
        o = scenario.room.outline
        segs += [[*a, *b] for a, b in itertools.pairwise(o)]
    for obj in scenario.objects:
        f = obj.footprint
        segs += [[*a, *b] for a, b in itertools.pairwise(f)]
    return [[float(v) for v in s] for s in segs]
