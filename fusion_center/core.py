"""The fusion center's processing, I/O-free: ``node_info`` and ``detections`` in, tracks out.

Shared by the live service and offline ``uwbnet track``. Detections are grouped by TDMA frame;
a frame is handed to the tracker as soon as every expected sensor has reported for it, once a
detection ``frame_lag`` frames later shows it is over, or on :meth:`FusionCore.flush`.
Duplicates and reordered messages (a ``seq`` not above the source's last, with a ``t`` not
after it) and detections of frames already processed are counted and dropped: the tracker never
goes back in time. A node that restarts (``seq`` from 0 again, later ``t``) is accepted.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from collections import defaultdict

import numpy as np

from fusion_center.tracking.base import SensorScan, Tracker, TrackerOutput
from node_agent.core import NodeConfigError, radar_params, sensor_geometry
from node_agent.dsp.geometry import WINDOW_GUARD
from protocol import C, Detections, NodeInfo

log = logging.getLogger(__name__)


@dataclasses.dataclass(frozen=True, slots=True, kw_only=True)
class FusionCoreConfig:
    """Parameters of frame assembly.

    Parameters
    ----------
    frame_lag : a frame is processed when a detection of frame ``f + frame_lag`` arrives.
    frame_wait : up to this many frames more, an incomplete frame waits for an expected sensor
        whose detection of it may still be in flight: one that reported one of the
        ``frame_lag + frame_wait`` frames before it and no frame after it (a node's messages
        arrive in order, so one that reported a later frame skipped this one). Later frames
        wait with it (the tracker never goes back in time). 0: off, as before. For a node
        process that got its core late and publishes its batch after the frame's deadline
        (issue 11, stop 20 notes).
    max_range : the distance (m) from a sensor up to which it is expected to detect a person;
        capped by the radar's window (half its longest bistatic range). 20 m (was 15): in a
        20 m hall a person near one end is seen only by the sensors at the other, 15-18 m
        away, whose estimates the range gate dropped; the learned detection profile of the
        farthest distance bin sets how much a miss out there costs a track
        (docs/integration.md).
    view_margin : angle (rad) added on each side of a sensor's 3 dB beam for the tracker's
        field of view: antennas still see people somewhat outside it (the node DSP keeps
        intersections up to its ``fov_margin`` beyond the beam).
    window_guard : pulse widths at the window's ends in which the nodes search no echo
        (``NodeDspConfig.window_guard``): a sensor is blind to people nearer than half the
        window's first measurable bistatic range.
    blind_zone : give the tracker each sensor's blind zone (``SensorScan.min_range``, no
        detection expected nearer than half the first measurable bistatic range). Off by
        default: measured worse on the outside proxy recordings (docs/blind_zone.md).
    range_gate : drop position estimates farther than ``max_range`` from their sensor. The
        tracker expects no detection there (``p_D = 0``), so a track born of such estimates
        (an echo that reached the sensor by a wall, placed behind the wall or far outside the
        hall) could never lose weight. Needed with the nodes' multi-frame integration, which
        brings such weak echoes above the threshold (docs/integration.md).
    """

    frame_lag: int = 2
    frame_wait: int = 0
    max_range: float = 20.0
    view_margin: float = 0.35
    window_guard: float = WINDOW_GUARD
    blind_zone: bool = False
    range_gate: bool = True


@dataclasses.dataclass(slots=True)
class FusionCounters:
    """What the fusion core accepted and rejected."""

    detections: int = 0
    duplicates: int = 0
    late: int = 0
    unknown_node: int = 0
    updates: int = 0
    beyond_range: int = 0  # position estimates dropped by ``range_gate``


class FusionCore:
    """Groups detections into TDMA frames and steps a :class:`Tracker` once per frame."""

    def __init__(self, tracker: Tracker, config: FusionCoreConfig | None = None) -> None:
        self.tracker = tracker
        self.config = config or FusionCoreConfig()
        self.nodes: dict[str, NodeInfo] = {}
        self.counters = FusionCounters()
        self._pending: dict[int, list[SensorScan]] = defaultdict(list)
        #: The sensors of each pending frame (checked against ``expected`` per detection).
        self._reported: dict[int, set[str]] = defaultdict(set)
        self._ranges: dict[str, float] = {}  # each node's max_range, m
        self._last_frame: dict[str, int] = {}  # the latest frame each sensor reported
        self._done_frame = -(2**62)
        self._last_t = -math.inf
        self._seen: dict[str, tuple[int, float]] = {}
        #: Per (node, tx, rx): array centre, boresight, view width, max_range and min_range.
        self._views: dict[
            tuple[str, str, tuple[str, ...]], tuple[np.ndarray, float, float, float, float]
        ] = {}
        self._blind: dict[str, float] = {}  # each node's blind distance, m
        #: Sensors expected to report in every frame (the TDMA schedule's); empty: unknown.
        self.expected: frozenset[str] = frozenset()

    def add_node(self, info: NodeInfo) -> None:
        """Take (or refresh) a node's description."""
        self.nodes[info.src] = info
        self._views = {k: v for k, v in self._views.items() if k[0] != info.src}
        self._blind.pop(info.src, None)
        self._ranges.pop(info.src, None)

    def _view(self, det: Detections) -> tuple[np.ndarray, float, float, float, float]:
        """Array centre (world x, y), boresight, beamwidth, largest and smallest distance
        (m) of the sensor behind ``det`` (kept per sensor: one look-up per message)."""
        rx = tuple(sorted(det.ranges))
        key = (det.src, det.tx, rx)
        view = self._views.get(key)
        if view is None:
            info = self.nodes[det.src]
            geom = sensor_geometry(info, det.tx, rx, self.nodes)
            # The node keeps estimates up to its DSP's margin beyond the 3 dB beam.
            width = min(2.0 * math.pi, geom.beamwidth + 2.0 * self.config.view_margin)
            view = (
                geom.centre,
                geom.boresight,
                width,
                self._max_range(info),
                self._min_range(info),
            )
            self._views[key] = view
        return view

    def _max_range(self, info: NodeInfo) -> float:
        max_range = self._ranges.get(info.src)
        if max_range is None:
            r = info.radar
            window = C * (r.t0 + r.n / r.fs) / 2.0
            max_range = self._ranges[info.src] = min(self.config.max_range, window)
        return max_range

    def _min_range(self, info: NodeInfo) -> float:
        if not self.config.blind_zone:
            return 0.0
        blind = self._blind.get(info.src)
        if blind is None:
            # half the shortest bistatic range the node measures (RadarParams.measurable):
            # a bat sensor's antennas are close together, a person at d is at about 2 d
            try:
                lo, _ = radar_params(info).measurable(self.config.window_guard)
            except NodeConfigError:
                lo = 0.0
            blind = self._blind[info.src] = max(lo / 2.0, 0.0)
        return blind

    def add_detections(self, det: Detections) -> list[TrackerOutput]:
        """Queue one node's detections; return the tracker outputs of frames now complete.

        Ranging rounds of mobile nodes (``links``) are not target detections: they go to
        :class:`~fusion_center.pose_core.PoseCore`, never to the tracker."""
        if det.links is not None:
            return []
        last = self._seen.get(det.src)
        if last is not None and det.seq <= last[0] and det.t <= last[1]:
            # Same or older sequence number and not newer: a duplicate or a reordered
            # message. A smaller seq with a newer t is a restarted node (its seq began at 0).
            self.counters.duplicates += 1
            return []
        if last is None or det.seq > last[0] or det.t > last[1]:
            self._seen[det.src] = (det.seq, det.t)
        if det.src not in self.nodes:
            self.counters.unknown_node += 1
            return []
        if det.frame <= self._done_frame:
            self.counters.late += 1
            return []
        try:
            origin, boresight, beamwidth, max_range, min_range = self._view(det)
        except NodeConfigError as exc:
            self.counters.unknown_node += 1
            log.warning("detections of %s rejected: %s", det.src, exc)
            return []
        self.counters.detections += 1
        if det.frame > self._last_frame.get(det.src, -(2**62)):
            self._last_frame[det.src] = det.frame
        positions = det.positions if det.positions is not None else np.zeros((0, 2))
        cov = det.cov
        if cov is None:
            cov = np.broadcast_to(np.eye(2) * 0.01, (positions.shape[0], 2, 2))
        if self.config.range_gate and positions.shape[0]:
            d = positions - origin
            near = np.einsum("ij,ij->i", d, d) <= max_range * max_range
            if not near.all():
                self.counters.beyond_range += int(np.count_nonzero(~near))
                positions, cov = positions[near], cov[near]
        self._pending[det.frame].append(
            SensorScan(
                sensor=det.src,
                t=det.t,
                positions=positions,
                cov=cov,
                origin=origin,
                boresight=boresight,
                beamwidth=beamwidth,
                max_range=max_range,
                min_range=min_range,
            )
        )
        reported = self._reported[det.frame]
        reported.add(det.src)
        if self.expected and self.expected <= reported:
            return self._emit(det.frame)
        return self._emit(self._due(det.frame))

    def _due(self, newest: int) -> int:
        """The last frame to process now that a detection of frame ``newest`` arrived:
        ``newest - frame_lag``, or the frame before the first pending one that waits for a
        sensor in flight (``frame_wait``)."""
        lag, wait = self.config.frame_lag, self.config.frame_wait
        upto = newest - lag
        if not wait or not self.expected:
            return upto
        for frame in sorted(f for f in self._pending if newest - lag - wait < f <= upto):
            recent = frame - lag - wait
            if any(
                recent <= self._last_frame.get(src, -(2**62)) < frame
                for src in self.expected - self._reported[frame]
            ):
                return frame - 1
        return upto

    def flush(self) -> list[TrackerOutput]:
        """Process every pending frame (end of a recording, or a quiet network)."""
        if not self._pending:
            return []
        return self._emit(max(self._pending))

    def _emit(self, upto: int) -> list[TrackerOutput]:
        if not self._pending or upto < min(self._pending):
            return []  # most detections: their frame is not due yet
        out = []
        for frame in sorted(f for f in self._pending if f <= upto):
            scans = sorted(self._pending.pop(frame), key=lambda s: s.t)
            self._reported.pop(frame, None)
            t = max(scans[-1].t, self._last_t)
            step = self.tracker.step(t, scans)
            out.append(dataclasses.replace(step, acquired=tuple(s.t for s in scans)))
            self._last_t = t
            self._done_frame = frame
            self.counters.updates += 1
        return out


def tracks_json(output: TrackerOutput) -> dict[str, object]:
    """The JSONL record of one fusion update (DESIGN.md, ``uwbnet track``)."""
    return {
        "t": round(float(output.t), 6),
        "tracks": [
            {
                "id": int(tr.id),
                "x": round(float(tr.x), 4),
                "y": round(float(tr.y), 4),
                "vx": round(float(tr.vx), 4),
                "vy": round(float(tr.vy), 4),
            }
            for tr in output.tracks
        ],
        "n_estimate": round(float(output.n_estimate), 4),
    }
