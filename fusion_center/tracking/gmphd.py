"""Labelled Gaussian-mixture PHD tracker (Section 9.2.3 of the CoLOR chapter).

The filter is the GM-PHD recursion of Vo & Ma (2006), "The Gaussian mixture probability
hypothesis density filter", IEEE Trans. Signal Process. 54(11), with

* a constant-velocity motion model, state ``[x, vx, y, vy]``;
* position measurements with the covariance each sensor reports per estimate;
* a state-dependent detection probability: ``p_D`` inside a sensor's field of view and
  range, ``p_D,out`` (0 by default) outside, so a person a sensor cannot see keeps weight;
* adaptive birth from measurements that the existing mixture explains poorly
  (Ristic, Clark, Vo & Vo 2012): they seed components used from the next step on;
* several sensors per step by the *iterated corrector*: the sensors' updates are applied
  one after another, in time order, each followed by a prediction to the next scan time
  (Mahler 2007, Sec. 10.5; exact only if detection probabilities are 1, good in practice);
* track labels beyond the chapter's nearest-neighbour labelling: each component carries an
  integer label propagated through prediction and update, a merge keeps the label of its
  heaviest member, the extraction gives a fresh label to a second heavy component of one
  label, and a label is reported only after ``confirm_steps`` steps above the extraction
  threshold (one-off clutter births never are).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy.cluster.hierarchy import linkage
from scipy.optimize import linear_sum_assignment
from scipy.spatial.distance import squareform

from . import kernels
from .base import (
    FloatArray,
    SensorScan,
    Tracker,
    TrackerOutput,
    TrackEstimate,
    constant_velocity_model,
    in_field_of_view,
)

__all__ = ["GmPhdConfig", "GmPhdTracker", "merge_components"]

IntArray = npt.NDArray[np.int64]
_TWO_PI = 2.0 * math.pi


@dataclass(frozen=True, slots=True, kw_only=True)
class GmPhdConfig:
    """Parameters of :class:`GmPhdTracker`; each is declared once here.

    Attributes
    ----------
    accel_psd : float
        Power spectral density ``q`` of the white acceleration noise per axis, m²/s³.
    survival_probability : float
        Probability that a target persists for one second; ``p_S = p^Δt`` per prediction.
    detection_probability : float
        ``p_D`` of a target inside a sensor's field of view and range.
    detection_probability_outside : float
        ``p_D`` outside the field of view or beyond ``max_range`` (0: no weight lost there).
    fov_margin : float
        Components up to this distance outside a sensor's field of view, m, still take part
        in its update with ``p_D,out``: they claim measurements near the edge of the view,
        which would otherwise seed a duplicate birth.
    clutter_rate : float
        Mean number of false position estimates per scan of one sensor.
    surveillance_area : float or None
        Area over which clutter spreads, m²; ``None``: the sensor's field-of-view sector
        ``beamwidth/2 * max_range²``. Clutter intensity ``κ = clutter_rate / area``, 1/m².
    birth_weight : float
        Weight of a birth seeded by a measurement no existing component explains.
    birth_velocity_std : float
        Standard deviation of each velocity component of a birth, m/s.
    birth_max_association : float
        A measurement seeds a birth only if the fraction ``r`` of it explained by the existing
        components is below this; the birth weight is ``birth_weight * (1 - r)``.
    gate : float
        Squared Mahalanobis gate of a component-measurement pair (13.8: χ²₂ at 99.9 %).
    prune_threshold : float
        Components lighter than this are dropped.
    merge_threshold : float
        Squared Mahalanobis distance ``U`` under which components are merged (Vo & Ma).
    max_components : int
        Cap ``J_max`` on the number of components after merging.
    max_label_weight : float
        Cap on the summed weight of one label after each update (``inf``: plain PHD). With 1,
        a label stands for at most one person, which keeps two labels apart when their people
        cross: otherwise the weight split between two co-located labels is a multiplicative
        random walk that ends with one label holding both people.
    extract_threshold : float
        A label is a target estimate when its summed weight reaches this.
    keep_threshold : float
        A confirmed label stays reported while its summed weight is above this (hysteresis:
        each missed detection of a sensor leaves ``1 - p_D`` of the weight, and several
        sensors in a row may miss; a person who left is below it after a frame or two).
    split_threshold : float
        A component of a label, other than its heaviest, that is this heavy and far from it
        (beyond the merge distance) becomes a new label: one label's weight split over two
        people (capped at 1 in all) would otherwise hide the second person, whose
        measurements it claims, so that no birth follows either.
    confirm_steps : int
        Steps with summed weight above ``extract_threshold`` before a label is reported.
    confirm_time : float
        Time (s) a label must also have spent above ``extract_threshold`` before it is
        reported, summed over its steps. A step count alone means a different time at each
        frame rate (3 steps are 60 ms at 50 Hz, 150 ms at 20 Hz); false estimates that come
        from people themselves (a swapped pairing of two people's ranges, one body part seen
        at a wrong angle) persist for a few frames, a person for seconds.
    claim_time : float
        A confirmed label claims the measurements in its gate (they seed no birth, and its
        components are not merged with other labels' in a sensor's update) until it has been
        below ``keep_threshold`` for this long (s; ``inf``: as long as it is confirmed). A
        track that died keeps a light component whose covariance grows without bound (7 m
        standard deviation after some seconds on the hall20x12 proxy): its gate then covers
        the hall, and no person entering it was born for seconds.
    relink_time : float
        A new label seeded within ``reid_radius + reid_speed * dt`` (m, m/s) of where a
        not yet confirmed label was last above ``extract_threshold``, ``dt <= relink_time``
        (s) ago, while that label is below it, takes over its confirmation history (steps
        and time above ``extract_threshold``); 0 turns it off. See
        :meth:`GmPhdTracker._relink`.
    reid_time, reid_radius, reid_speed : float
        A new track confirmed within ``reid_time`` (s) of a confirmed track's loss and within
        ``reid_radius + reid_speed * dt`` (m, m/s) of where it was last reported continues its
        id (see :meth:`GmPhdTracker._reidentify`).
    label_miss_time, max_label_miss : float
        Time constant (s) of the miss rate each established label learns, and its cap; 0 turns
        it off (see :meth:`GmPhdTracker._label_frame_miss`). ``frame_miss`` is one rate for
        all people, and the people who are seen well set it; one person may be missed in half
        the frames for seconds (a person just beyond a sensor's blind zone near a wall, seen
        obliquely by the others) while the rest are seen in nearly every frame, and with the
        shared rate each empty frame costs such a track nine tenths of its weight.
    miss_correlation_time : float
        Time (s) over which one person's missed detections are correlated; 0 turns it off.
        An established track's (weight above 0.5) probability of a frame without detection
        is raised to ``min(1, dt / miss_correlation_time)``, ``dt`` the time since the last
        frame. Beyond the chapter, whose update treats frames as independent: a person in a
        spot the sensors see badly (near a wall, at a blind zone's edge, far from all) stays
        unseen for a stretch of frames, and at 50 frames/s each empty frame would cost the
        track as much weight as at 20; tempered, a track loses weight per second, not per
        frame, above ``1 / miss_correlation_time`` frames/s. Off by default: 0.05 s raised the
        outside proxies' mean correct count (79.5 -> 80.4 %) but cost one ID switch on foyer3
        (docs/blind_zone.md).
    coast_time : float
        A confirmed track whose weight fell below ``keep_threshold`` is still reported, at its
        predicted state, for this long (s), while its label is in the mixture: people near
        walls or shadowed may go unseen by every sensor for a few frames. 0.5 s (was 0.25,
        stop 21): on the outside proxies the sensors' misses come in runs of a few tenths of
        a second (a person at a far wall, inside one sensor's blind zone): at 0.5 s the mean
        of the 12 proxies rose 87.7 -> 88.4 %, four hall seeds counted better, +100 the same,
        +500 0.1 point worse, foyer3 unchanged (issue 2, stop 21 notes). A lost track is reported
        up to this long after the person left. Timed on elapsed time (a clock stepping back
        does not prolong it). A label whose components were all pruned is not
        coasted: coasting those too (at their last state, predicted) lowered the mean count
        and cost foyer3 an ID switch per seed.
    adapt_detection : bool
        Learn each sensor's ``p_D`` online (beyond the chapter, which assumes it known): the
        fraction of established tracks (label weight > 0.5) in the sensor's view that had a
        measurement in their gate, exponentially averaged with rate ``adapt_rate`` from
        ``detection_probability`` and kept within
        ``[min_detection_probability, max_detection_probability]``. Real sensors differ
        (through-wall sensors, distance, clutter suppression), and a ``p_D`` set too high makes
        every miss cost a confirmed track most of its weight.
    adapt_rate : float
        Weight of one scan in the running ``p_D`` estimate.
    detection_range_bins : tuple of float
        Distance bin edges (m) of the learned ``p_D`` per sensor in frame fusion: the echo of a
        person weakens as :math:`1/(d_1 d_2)`, so a sensor detects near people more reliably
        than far ones, and a track in a far corner should not lose weight for each scan a
        sensor that barely reaches it stays silent.
    detection_angle_bins : tuple of float
        Bearing bin edges of the learned ``p_D`` per sensor, as fractions of the half field of
        view (``SensorScan.beamwidth / 2``, angle off the boresight); each distance bin is split
        into these bearing bins (empty: distance only). The echo power follows the antennas'
        two-way gain as well as the distance (radar equation: :math:`G_t(\theta) G_r(\theta)
        / (d_1^2 d_2^2)`), so a sensor that sees a person 60° off its boresight detects it far
        less often than one that sees it on the boresight at the same distance. (0.5, 0.8):
        the half view includes the fusion centre's view margin (0.35 rad on each side), so
        for 3 dB beams of 1.5-2.1 rad the 3 dB edge is at 0.68-0.75 of it; 0.8 lies just
        outside the 3 dB beam and 0.5 at about 0.7 of the 3 dB half beam. The bins move with
        ``FusionCoreConfig.view_margin``. The edges were chosen on the hall20x12 proxy; a
        0.05 shift of either edge moves its count by up to 8 points. Measured on the
        outside proxy recordings: without it, a person walking along a wall, seen by every
        sensor at a wide angle, kept the distance bins' ``p_D`` of people seen head-on, and
        each frame without a detection cost the track most of its weight
        (docs/integration.md).
    min_detection_probability, max_detection_probability : float
        Bounds of a learned ``p_D``.
    occlusion_radius : float
        A person shadows another for a sensor when they stand within this distance (m) of the
        line of sight from the sensor to the other, and nearer: the shadowed component's ``p_D``
        is multiplied by ``occluded_factor`` (the body attenuates the echo by 10-20 dB).
    occluded_factor : float
        ``p_D`` factor of a shadowed component.
    extent_absorb_distance : float
        In frame fusion, a sensor's estimate that the one-to-one assignment to the established
        tracks left over, within this distance (m) of a track that got another estimate of the
        same sensor, and in its gate, is a second echo of that body (limbs, torso: an extended
        target, as in the partitioned update of Granstrom & Orguner): it joins that track's
        group with no weight in the fused position and seeds no birth (``fuse_estimates``).
        0 (default): off. Measured on the outside proxies with the nodes' 8-frame integration
        and ``cluster_distance`` 0.8 it brings hall20x12 seed 422 to the 75 % count goal, but
        raises the proxies' mean OSPA and ID switches and hangs on a 0.1 m knife edge of
        both distances (docs/integration.md, stop 23).
    fusion : str
        ``"frame"`` (default; beyond the chapter): the position estimates of all sensors of one
        TDMA frame are clustered (complete linkage, at most one estimate per sensor in a
        cluster, diameter ``cluster_distance``) and fused into one measurement per cluster by
        information-weighted averaging, then one GM-PHD update uses the probability that at
        least one sensor detects the person, ``1 - prod_s (1 - p_D,s)``. Robust when each sensor
        sees only some people (field of view, shadowing). ``"sequential"``: the iterated
        corrector, one GM-PHD update per sensor scan.
    cluster_distance : float
        Largest distance (m) between two sensors' estimates of one person.
    fused_noise_floor : float
        Standard deviation (m) added to a fused measurement's covariance: the sensors' errors
        are not independent (each sees the near side of the body).
    maneuver_weight, maneuver_velocity_std : float
        Share of an established component's weight given each prediction to a copy with the
        velocity reset (standard deviation in m/s): see :meth:`GmPhdTracker._predict`.
    clutter_coincidence : float
        Factor on the clutter intensity per additional sensor in a fused measurement.
    extent_std : float
        Standard deviation (m) of a person's scattering centres about the tracked body
        centre, added to every measurement covariance: the radar sees the body's near side
        and limbs, not its centre, whatever the node's ranging precision.
    duplicate_distance, duplicate_velocity, duplicate_steps : float, float, int
        Two labels whose estimates stay within ``duplicate_distance`` (m) and
        ``duplicate_velocity`` (m/s) of each other for ``duplicate_steps`` consecutive steps
        follow one person (an extended target seeded two births): the younger label is
        folded into the older. People who cross differ in velocity and are never folded.
    duplicate_window : float
        Time constant (s) over which the gap between two labels is averaged before the
        ``duplicate_distance`` and ``duplicate_velocity`` tests (0: each step's own gap).
        Two labels on one person jitter about each other (each chases the body part its
        measurements came from: gaps of 0-1.2 m and velocity differences of 0.1-3.4 m/s
        within one second on the hall20x12 proxy), so their gap vectors average out near
        zero, while people who cross keep a steady relative velocity. A pair is followed
        while the labels are within ``3 * duplicate_distance`` of each other.
    """

    accel_psd: float = 0.5
    survival_probability: float = 0.95
    detection_probability: float = 0.5
    detection_probability_outside: float = 0.0
    fov_margin: float = 0.5
    clutter_rate: float = 0.5
    surveillance_area: float | None = None
    birth_weight: float = 0.1
    birth_velocity_std: float = 1.0
    birth_max_association: float = 0.5
    gate: float = 13.8
    prune_threshold: float = 1e-5
    merge_threshold: float = 4.0
    max_components: int = 200
    max_label_weight: float = 1.0
    extract_threshold: float = 0.5
    keep_threshold: float = 0.4
    split_threshold: float = 0.2
    confirm_steps: int = 3
    confirm_time: float = 0.5
    learn_frame_miss: bool = True
    label_miss_time: float = 1.0
    max_label_miss: float = 0.7
    miss_correlation_time: float = 0.0
    coast_time: float = 0.5
    claim_time: float = 2.0
    relink_time: float = 0.5
    reid_time: float = 2.0
    reid_radius: float = 0.5
    reid_speed: float = 1.0
    adapt_detection: bool = True
    adapt_rate: float = 0.02
    detection_range_bins: tuple[float, ...] = (3.0, 5.0, 7.0, 9.0, 12.0)
    detection_angle_bins: tuple[float, ...] = (0.5, 0.8)
    min_detection_probability: float = 0.2
    max_detection_probability: float = 0.95
    fusion: str = "frame"
    cluster_distance: float = 0.6
    fused_noise_floor: float = 0.05
    clutter_coincidence: float = 0.05
    maneuver_weight: float = 0.05
    maneuver_velocity_std: float = 1.0
    extent_std: float = 0.2
    duplicate_distance: float = 0.3
    duplicate_velocity: float = 0.5
    duplicate_steps: int = 10
    duplicate_window: float = 0.5
    occlusion_radius: float = 0.35
    occluded_factor: float = 0.2
    extent_absorb_distance: float = 0.0

    def __post_init__(self) -> None:
        # NaN fails every comparison: claim_time NaN silently switched claiming off, an
        # infinite relink_time kept every fading label and let histories jump the hall
        if not self.claim_time >= 0.0:
            raise ValueError(f"claim_time must be >= 0 (inf: always), got {self.claim_time}")
        for name in ("relink_time", "duplicate_window", "coast_time", "extent_absorb_distance"):
            value = getattr(self, name)
            if not 0.0 <= value < math.inf:
                raise ValueError(f"{name} must be finite and >= 0, got {value}")
        if self.duplicate_steps < 0:
            raise ValueError(f"duplicate_steps must be >= 0, got {self.duplicate_steps}")
        for name in ("detection_range_bins", "detection_angle_bins"):
            edges = np.asarray(getattr(self, name), float)
            if edges.size and (np.any(edges <= 0.0) or np.any(np.diff(edges) <= 0.0)):
                raise ValueError(f"{name} must be positive and increasing, got {edges.tolist()}")


@dataclass(slots=True)
class _Mixture:
    """Mutable working mixture: weights (J,), means (J, 4), covariances (J, 4, 4), labels."""

    w: FloatArray
    m: FloatArray
    P: FloatArray
    label: IntArray

    @classmethod
    def empty(cls) -> _Mixture:
        return cls(np.zeros(0), np.zeros((0, 4)), np.zeros((0, 4, 4)), np.zeros(0, dtype=np.int64))

    def take(self, idx: npt.NDArray[np.intp] | npt.NDArray[np.bool_]) -> _Mixture:
        return _Mixture(self.w[idx], self.m[idx], self.P[idx], self.label[idx])

    @staticmethod
    def concat(parts: Sequence[_Mixture]) -> _Mixture:
        return _Mixture(
            np.concatenate([p.w for p in parts]),
            np.concatenate([p.m for p in parts]),
            np.concatenate([p.P for p in parts]),
            np.concatenate([p.label for p in parts]),
        )


def _by_label(w: FloatArray, label: IntArray) -> tuple[npt.NDArray[np.intp], npt.NDArray[np.bool_]]:
    """Component order by label, then by decreasing weight, and the mask (in that order) of
    each label's first, i.e. heaviest, component."""
    order = np.lexsort((-w, label))
    lab = label[order]
    first = np.ones(lab.size, dtype=bool)
    first[1:] = lab[1:] != lab[:-1]
    return order, first


def merge_components(
    w: FloatArray,
    m: FloatArray,
    P: FloatArray,
    label: IntArray,
    threshold: float,
    protected: npt.NDArray[np.bool_] | None = None,
) -> tuple[FloatArray, FloatArray, FloatArray, IntArray]:
    """Greedy moment-matching merge of Gaussian components (Vo & Ma 2006, Table II).

    The heaviest remaining component ``l`` absorbs every remaining ``i`` with

    .. math::

        (m_i - m_l)^T P_l^{-1} (m_i - m_l) \\le U,\\qquad
        \\tilde w = \\sum_i w_i,\\quad
        \\tilde m = \\frac{1}{\\tilde w}\\sum_i w_i m_i,\\quad
        \\tilde P = \\frac{1}{\\tilde w}\\sum_i w_i \\left(P_i + (\\tilde m - m_i)
        (\\tilde m - m_i)^T\\right)

    and the merged component keeps the label of ``l``, or of the heaviest ``protected``
    member when there is one. Two components whose (different)
    labels are both ``protected`` (confirmed tracks) are never merged: two people crossing
    share a position for a moment and their velocity estimates may be close. All pairwise
    distances come from one batched solve; the only Python loop runs over the clusters.

    Parameters
    ----------
    w : ndarray, float64, shape (J,)
    m : ndarray, float64, shape (J, 4)
    P : ndarray, float64, shape (J, 4, 4)
    label : ndarray, int64, shape (J,)
    threshold : float
        ``U``.
    protected : ndarray, bool, shape (J,), optional
        Components of confirmed labels.

    Returns
    -------
    w, m, P, label
        The merged mixture, sorted by decreasing weight.
    """
    n = w.shape[0]
    order = np.argsort(-w, kind="stable")
    w, m, P, label = w[order], m[order], P[order], label[order]
    if n <= 1:
        return w, m, P, label
    diff = m[None, :, :] - m[:, None, :]  # diff[l, i] = m_i - m_l, (J, J, 4)
    # The Mahalanobis distance of the position alone (marginal 2x2 block, closed form) is a
    # lower bound of the full one: only pairs within the threshold there need the 4x4 solve.
    a, b, c = P[:, 0, 0], P[:, 0, 2], P[:, 2, 2]
    dx, dy = diff[..., 0], diff[..., 2]
    d2_pos = (c[:, None] * dx * dx - 2.0 * b[:, None] * dx * dy + a[:, None] * dy * dy) / (
        a * c - b * b
    )[:, None]
    close = d2_pos <= threshold
    np.fill_diagonal(close, False)
    rows = np.flatnonzero(close.any(axis=1))
    if rows.size:
        d2 = d2_pos[rows] + _velocity_term(P[rows], diff[rows], a, b, c, rows)
        close[rows] &= d2 <= threshold
    if protected is not None:
        prot = protected[order]
        close &= (label[:, None] == label[None, :]) | ~(prot[:, None] & prot[None, :])
    # Components close to none are clusters of their own: only the others need the greedy loop.
    lonely = ~(close.any(axis=0) | close.any(axis=1))
    assign = np.empty(n, dtype=np.intp)
    leaders = np.flatnonzero(lonely).tolist()
    assign[lonely] = np.arange(len(leaders))
    cluster = len(leaders)
    remaining = ~lonely
    while remaining.any():
        lead = int(remaining.argmax())  # heaviest remaining: the arrays are weight-sorted
        members = close[lead] & remaining
        members[lead] = True
        assign[members] = cluster
        remaining &= ~members
        leaders.append(lead)
        cluster += 1
    if cluster == n:
        return w, m, P, label
    grouped = np.argsort(assign, kind="stable")
    starts = np.searchsorted(assign[grouped], np.arange(cluster))
    wg, mg, Pg = w[grouped], m[grouped], P[grouped]
    w_new = np.add.reduceat(wg, starts)
    m_new = np.add.reduceat(wg[:, None] * mg, starts) / w_new[:, None]
    d = mg - m_new[assign[grouped]]
    spread = Pg + d[:, :, None] * d[:, None, :]
    P_new = np.add.reduceat(wg[:, None, None] * spread, starts) / w_new[:, None, None]
    label_new = label[np.asarray(leaders)]
    if protected is not None:
        # A cluster with a confirmed track keeps that track's label (its heaviest one), even
        # when a younger, heavier component joined it: the person keeps the id.
        idx = np.flatnonzero(prot)
        if idx.size:
            clusters, first = np.unique(assign[idx], return_index=True)
            label_new[clusters] = label[idx[first]]
    by_weight = np.argsort(-w_new, kind="stable")
    return w_new[by_weight], m_new[by_weight], P_new[by_weight], label_new[by_weight]


def _velocity_term(
    P: FloatArray,
    diff: FloatArray,
    a: FloatArray,
    b: FloatArray,
    c: FloatArray,
    rows: npt.NDArray[np.intp],
) -> FloatArray:
    """Velocity part of the squared Mahalanobis distance :math:`d^T P^{-1} d`, shape (L, J).

    With the state ``[x, vx, y, vy]`` split into position ``p`` and velocity ``v`` blocks,
    :math:`P = [[A, B], [B^T, C]]`, the block inverse (Schur complement
    :math:`S = C - B^T A^{-1} B`) gives

    .. math::

        d^T P^{-1} d = d_p^T A^{-1} d_p + r^T S^{-1} r,\\qquad r = d_v - B^T A^{-1} d_p,

    whose first term the caller has already. Every block is 2x2, so this is closed-form
    elementwise arithmetic: a batched ``np.linalg.solve`` over (L, 4, 4) costs more in call
    overhead than the whole merge at the mixture sizes of a live tracker.

    ``P`` (L, 4, 4) are the leaders' covariances, ``diff`` (L, J, 4) the offsets to every
    component, ``a, b, c`` the position blocks' entries ``P[:, 0, 0], P[:, 0, 2],
    P[:, 2, 2]`` of all components, indexed by ``rows``.
    """
    a, b, c = a[rows], b[rows], c[rows]
    inv_det = 1.0 / (a * c - b * b)
    ia, ib, ic = c * inv_det, -b * inv_det, a * inv_det  # A^{-1}
    # B: rows position (x, y), columns velocity (vx, vy).
    b00, b01, b10, b11 = P[:, 0, 1], P[:, 0, 3], P[:, 2, 1], P[:, 2, 3]
    g00, g01 = ia * b00 + ib * b10, ia * b01 + ib * b11  # G = A^{-1} B
    g10, g11 = ib * b00 + ic * b10, ib * b01 + ic * b11
    s00 = P[:, 1, 1] - (b00 * g00 + b10 * g10)  # S = C - B^T G
    s01 = P[:, 1, 3] - (b00 * g01 + b10 * g11)
    s11 = P[:, 3, 3] - (b01 * g01 + b11 * g11)
    dx, dvx, dy, dvy = diff[..., 0], diff[..., 1], diff[..., 2], diff[..., 3]
    ux = ia[:, None] * dx + ib[:, None] * dy  # A^{-1} d_p
    uy = ib[:, None] * dx + ic[:, None] * dy
    r0 = dvx - (b00[:, None] * ux + b10[:, None] * uy)  # d_v - B^T A^{-1} d_p
    r1 = dvy - (b01[:, None] * ux + b11[:, None] * uy)
    s_det = (s00 * s11 - s01 * s01)[:, None]
    return (s11[:, None] * r0 * r0 - 2.0 * s01[:, None] * r0 * r1 + s00[:, None] * r1 * r1) / s_det


def flat_clusters(tree: FloatArray, t: float) -> IntArray:
    """Flat clusters of a hierarchical clustering cut at height ``t``: the numbers (1, 2, ...)
    that ``scipy.cluster.hierarchy.fcluster(tree, t, criterion="distance")`` gives.

    A subtree whose largest merge distance is at most ``t`` is one cluster. The numbering is
    ``fcluster``'s: a depth-first walk from the root that enters a node's merged children
    (left first) before it numbers its single leaves (left first); a cluster is numbered
    when the walk enters its root. Written out because ``fcluster``'s validation of the
    tree costs about 180 us per call against a few us for this walk over the handful of
    estimates of one frame; a unit test compares both on random and tied trees.

    Parameters
    ----------
    tree : ndarray, (n - 1, 4), a linkage matrix (``scipy.cluster.hierarchy.linkage``).
    t : the cut height (the distance of ``tree``'s merges).
    """
    n = tree.shape[0] + 1
    rows = [(int(a), int(b), d) for a, b, d, _ in tree.tolist()]
    # the largest merge distance within each subtree (children precede their parents)
    top = [0.0] * (2 * n - 1)
    for i, (a, b, d) in enumerate(rows):
        top[n + i] = max(d, top[a], top[b])
    out = np.zeros(n, dtype=np.int64)
    number, leader = 0, -1
    stack = [2 * n - 2]
    entered = set(stack)
    while stack:
        node = stack[-1]
        a, b, _ = rows[node - n]
        if leader < 0 and top[node] <= t:
            leader, number = node, number + 1
        if a >= n and a not in entered:
            entered.add(a)
            stack.append(a)
            continue
        if b >= n and b not in entered:
            entered.add(b)
            stack.append(b)
            continue
        for leaf in (a, b):
            if leaf < n:
                if leader < 0:
                    number += 1
                out[leaf] = number
        if leader == node:
            leader = -1
        stack.pop()
    return out


def fuse_estimates(
    z: FloatArray,
    R: FloatArray,
    owner: npt.NDArray[np.int64],
    cluster_distance: float,
    noise_floor: float,
    anchors: FloatArray | None = None,
    anchor_cov: FloatArray | None = None,
    gate: float = 9.21,
    absorb_distance: float = 0.0,
) -> tuple[FloatArray, FloatArray]:
    """Group several sensors' position estimates of one frame per person and fuse each group.

    A person is an extended target: sensors see different parts of the body, which breaks the
    GM-PHD's one-measurement-per-target assumption. So estimates are grouped first: each
    sensor's estimates are assigned one-to-one to the predicted track positions (``anchors``)
    whose gate they are in (squared Mahalanobis distance ``gate`` with ``anchor_cov + R``),
    minimising the total distance; the rest are clustered by complete linkage
    (``scipy.cluster.hierarchy``) with diameter ``cluster_distance``, two estimates of one
    sensor never sharing a cluster. Each group is fused by information weighting,

    .. math::

        R_f = \\Big(\\sum_i R_i^{-1}\\Big)^{-1} + \\sigma_f^2 I,\\quad
        z_f = \\Big(\\sum_i R_i^{-1}\\Big)^{-1} \\sum_i R_i^{-1} z_i .

    Parameters
    ----------
    z : ndarray, (n, 2), world x, y, m.
    R : ndarray, (n, 2, 2), covariances, m².
    owner : ndarray, int, (n,), index of the sensor of each estimate.
    anchors, anchor_cov : ndarray, (h, 2) and (h, 2, 2): predicted positions of established
        tracks and their covariances, or None.
    absorb_distance : a sensor's estimate left over by the one-to-one assignment that lies
        within this distance (m) of a track to which the same sensor's estimate was assigned,
        and in its gate, is a second echo of that body: it joins the track's group with no
        weight in the fused position (it seeds no birth). 0: off.

    Returns
    -------
    (m, 2) fused positions, (m, 2, 2) covariances (m <= n), and (n,) the fused measurement
    each estimate went into.
    """
    n = z.shape[0]
    if n == 0:
        return z.reshape(0, 2), R.reshape(0, 2, 2), np.zeros(0, dtype=np.int64)
    labels = np.full(n, -1, dtype=np.int64)
    absorbed = np.zeros(n, dtype=bool)
    n_groups = 0
    if anchors is not None and anchors.shape[0]:
        assert anchor_cov is not None
        S = anchor_cov[:, None] + R[None]  # (h, n, 2, 2)
        nu = z[None] - anchors[:, None]
        det = S[..., 0, 0] * S[..., 1, 1] - S[..., 0, 1] * S[..., 1, 0]
        d2 = (
            S[..., 1, 1] * nu[..., 0] ** 2
            - 2.0 * S[..., 0, 1] * nu[..., 0] * nu[..., 1]
            + S[..., 0, 0] * nu[..., 1] ** 2
        ) / det
        # One estimate per sensor and track: each sensor's estimates are assigned to the
        # tracks one-to-one (minimum total distance), so two people who pass close to each
        # other keep one measurement each whenever a sensor resolves them.
        cost = np.where(d2 < gate, d2, 1e6)
        gated = (d2 < gate).any(axis=0)
        # each sensor's estimates, in index order (a stable sort keeps it within a sensor)
        order = np.argsort(owner, kind="stable")
        _, first, count = np.unique(owner[order], return_index=True, return_counts=True)
        # a sensor with nothing in any gate is skipped (the assignment would keep nothing):
        # found for all sensors at once, most of a frame's sensors see no one
        in_gate = np.logical_or.reduceat(gated[order], first)
        for i, k in zip(first[in_gate].tolist(), count[in_gate].tolist(), strict=True):
            cols = order[i : i + k]
            if k == 1:
                # one estimate: the assignment is the nearest track
                col = int(cols[0])
                row = int(np.argmin(cost[:, col]))
                if cost[row, col] < gate:
                    labels[col] = row
                continue
            rows, picked = linear_sum_assignment(cost[:, cols])
            ok = cost[rows, cols[picked]] < gate
            labels[cols[picked[ok]]] = rows[ok]
            if absorb_distance > 0.0 and ok.any():
                # An extended target: one sensor may resolve two scattering parts of one
                # body; the assignment gives the track one, the other would seed a second
                # label (Granstrom & Orguner's partitioned update, reduced to one cell).
                left = cols[labels[cols] < 0]
                owned = rows[ok]
                if left.size:
                    dist = np.linalg.norm(z[left][:, None] - anchors[owned][None], axis=2)
                    dist = np.where(cost[owned][:, left].T < gate, dist, np.inf)
                    near_h = np.argmin(dist, axis=1)
                    take = dist[np.arange(left.size), near_h] < absorb_distance
                    labels[left[take]] = owned[near_h[take]]
                    absorbed[left[take]] = True
        n_groups = anchors.shape[0]
    rest = np.flatnonzero(labels < 0)
    if rest.size == 1:
        labels[rest] = n_groups
    elif rest.size > 1:
        zr, orr = z[rest], owner[rest]
        d = np.linalg.norm(zr[:, None, :] - zr[None, :, :], axis=2)
        d[orr[:, None] == orr[None, :]] = 1e6
        np.fill_diagonal(d, 0.0)
        tree = linkage(squareform(d, checks=False), method="complete")
        labels[rest] = n_groups + flat_clusters(tree, cluster_distance) - 1
    _, labels = np.unique(labels, return_inverse=True)
    det = R[:, 0, 0] * R[:, 1, 1] - R[:, 0, 1] * R[:, 1, 0]
    info = np.empty_like(R)
    info[:, 0, 0], info[:, 1, 1] = R[:, 1, 1] / det, R[:, 0, 0] / det
    info[:, 0, 1], info[:, 1, 0] = -R[:, 0, 1] / det, -R[:, 1, 0] / det
    info[absorbed] = 0.0  # a group always holds its assigned, unabsorbed estimate
    m = int(labels.max()) + 1
    info_sum = np.zeros((m, 2, 2))
    np.add.at(info_sum, labels, info)
    vec = np.zeros((m, 2))
    np.add.at(vec, labels, np.einsum("nij,nj->ni", info, z))
    Rf = np.linalg.inv(info_sum)  # batched 2x2 information sums, well conditioned
    zf = np.einsum("nij,nj->ni", Rf, vec)
    return zf, Rf + noise_floor**2 * np.eye(2), labels


def _writable(a: FloatArray) -> FloatArray:
    """``a`` as a writable float64 array (the compiled kernels take no read-only views)."""
    a = np.asarray(a, dtype=np.float64)
    return a if a.flags.writeable else a.copy()


def _cap_label_weight(w: FloatArray, label: IntArray, cap: float) -> FloatArray:
    """Scale each label's components so that their summed weight is at most ``cap``."""
    _, inv = np.unique(label, return_inverse=True)
    total = np.bincount(inv, weights=w)
    return w * np.minimum(1.0, cap / np.maximum(total, 1e-300))[inv]


class GmPhdTracker(Tracker):
    """Labelled GM-PHD multi-target tracker over the sensors' position estimates.

    Parameters
    ----------
    config : GmPhdConfig, optional
        Filter parameters.

    Notes
    -----
    One step: add last step's births; for each scan in time order, predict to its time,
    apply the GM-PHD update (Vo & Ma 2006, eqs. (20)-(21)), prune and merge the updated
    components; predict to ``t``; cap; extract labelled estimates. For a component ``j``
    and a measurement ``z_k`` with covariance ``R_k``, with ``H`` selecting ``x, y``:

    .. math::

        S_{jk} = H P_j H^T + R_k,\\quad
        q_{jk} = \\mathcal N(z_k; H m_j, S_{jk}),\\quad
        w_{jk} = \\frac{p_D(m_j)\\, w_j\\, q_{jk}}{\\kappa + \\sum_i p_D(m_i)\\, w_i\\, q_{ik}}

    and the missed-detection component keeps weight ``(1 - p_D(m_j)) w_j``. ``S`` is 2x2
    and inverted in closed form; pairs outside the gate are skipped.
    """

    def __init__(self, config: GmPhdConfig | None = None) -> None:
        self.config = config or GmPhdConfig()
        self._model_cache: dict[float, tuple[FloatArray, FloatArray, FloatArray]] = {}
        #: Optional factor (0..1) on a sensor's ``p_D`` at world positions ``xy``, e.g. the
        #: walls in its line of sight (:class:`fusion_center.tracking.walls.WallSightModel`);
        #: ``None``: sensors see through walls. Positions with a factor below 1 are left
        #: out of the learned detection profiles.
        self.sight: Callable[[SensorScan, FloatArray], FloatArray] | None = None
        #: Correct, prune and merge with the compiled kernels (``tracking.kernels``); False:
        #: with the numpy reference code, which the kernels match up to rounding.
        self.compiled = True
        self.reset()

    def _sight(self, scan: SensorScan, xy: FloatArray) -> FloatArray:
        return np.ones(xy.shape[0]) if self.sight is None else self.sight(scan, xy)

    def reset(self) -> None:
        self._mix = _Mixture.empty()
        self._births = _Mixture.empty()
        self._t: float | None = None
        self._next_label = 1
        self._hits: dict[int, int] = {}
        self._strong_time: dict[int, float] = {}
        #: Learned probability that no sensor detects an established track in a frame.
        self.frame_miss = 1.0 - self.config.max_detection_probability
        #: Learned probability, per established label, that no sensor detects it in a frame.
        self.label_miss: dict[int, float] = {}
        self._t_frame: float | None = None
        self._t_miss: float | None = None
        self._t_extract: float | None = None
        #: Elapsed time (s): the sum of the positive steps between extractions. Coasting and
        #: claiming are timed on it, so a clock that steps back (a replay restarted without
        #: ``reset``) neither freezes a coast nor lets a dead track claim until it catches up.
        self._elapsed = 0.0
        self._confirmed: set[int] = set()
        self._confirmed_arr = np.zeros(0, dtype=np.int64)
        #: Confirmed labels that claim the measurements in their gate (see ``claim_time``).
        self._claim_arr = np.zeros(0, dtype=np.int64)
        self._confirmed_t: dict[int, float] = {}
        self._dup_count: dict[tuple[int, int], int] = {}
        #: Pairs of labels followed (``duplicate_window``), sorted by key ``older << 32 |
        #: younger``: keys, steps, mean state difference older - younger (x, vx, y, vy).
        self._dup_gap: tuple[IntArray, IntArray, FloatArray] = (
            np.zeros(0, dtype=np.int64),
            np.zeros(0, dtype=np.int64),
            np.zeros((0, 4)),
        )
        self._t_dup: float | None = None
        self._last_strong: dict[int, float] = {}
        self._last_report: dict[int, tuple[float, float, float]] = {}
        self._lost: dict[int, tuple[float, float, float]] = {}
        #: Unconfirmed labels last above ``extract_threshold``: time, x, y, steps, time above.
        self._fading: dict[int, tuple[float, float, float, int, float]] = {}
        #: Learned detection probability per sensor id (see ``adapt_detection``).
        self.detection_probabilities: dict[str, float] = {}
        #: Learned detection probability per sensor and distance bin (frame fusion).
        self.detection_profiles: dict[str, FloatArray] = {}

    # -- recursion ----------------------------------------------------------------------

    def _model(self, dt: float) -> tuple[FloatArray, FloatArray, FloatArray]:
        key = round(dt, 9)
        cached = self._model_cache.get(key)
        if cached is None:
            F, Q = constant_velocity_model(key, self.config.accel_psd)
            cached = (F, F.T.copy(), Q)
            if len(self._model_cache) > 64:
                self._model_cache.clear()
            self._model_cache[key] = cached
        return cached

    def _predict(self, dt: float) -> None:
        """Vo & Ma eq. (16)-(17): ``w ← p_S w``, ``m ← F m``, ``P ← F P F^T + Q``.

        Beyond the chapter, the motion model is a two-part mixture: established components
        (weight > 0.3) also spawn a *manoeuvre* copy, with ``maneuver_weight`` of the weight,
        the predicted position and the velocity reset to zero with standard deviation
        ``maneuver_velocity_std``. A person who stops or turns back is caught by it under the
        same label instead of being lost and re-born under a new one.
        """
        if dt <= 0.0 or self._mix.w.size == 0:
            return
        cfg = self.config
        F, Ft, Q = self._model(dt)
        mix = self._mix
        if self.compiled:
            w, m, P, src = kernels.predict_mixture(
                mix.w,
                mix.m,
                mix.P,
                F,
                Q,
                cfg.survival_probability**dt,
                cfg.maneuver_weight,
                cfg.maneuver_velocity_std**2,
            )
            self._mix = _Mixture(w, m, P, mix.label[src])
            return
        mix.w = mix.w * cfg.survival_probability**dt
        mix.m = mix.m @ Ft
        mix.P = F @ mix.P @ Ft + Q
        if cfg.maneuver_weight > 0.0:
            src = np.flatnonzero(mix.w > 0.3)
            if src.size:
                m = mix.m[src].copy()
                m[:, 1::2] = 0.0
                P = mix.P[src].copy()
                P[:, 1::2, :] = 0.0
                P[:, :, 1::2] = 0.0
                P[:, 1, 1] = P[:, 3, 3] = cfg.maneuver_velocity_std**2
                w = mix.w[src] * cfg.maneuver_weight
                mix.w[src] -= w
                self._mix = _Mixture.concat((mix, _Mixture(w, m, P, mix.label[src].copy())))

    def _protected(
        self, mix: _Mixture, arr: IntArray | None = None
    ) -> npt.NDArray[np.bool_] | None:
        """Components of confirmed labels (or of the sorted labels ``arr``), or None when
        there are none."""
        arr = self._confirmed_arr if arr is None else arr  # sorted
        if arr.size == 0:
            return None
        pos = np.minimum(np.searchsorted(arr, mix.label), arr.size - 1)
        return arr[pos] == mix.label

    def _clutter_intensity(self, scan: SensorScan) -> float:
        cfg = self.config
        area = cfg.surveillance_area
        if area is None:
            area = 0.5 * scan.beamwidth * scan.max_range**2
            if not math.isfinite(area):
                raise ValueError(
                    "surveillance_area must be set when a sensor has an infinite max_range"
                )
        return cfg.clutter_rate / area

    def _update(
        self,
        scan: SensorScan,
        frame: tuple[FloatArray, FloatArray, FloatArray] | None = None,
    ) -> _Mixture:
        """Correct the mixture with one scan; return the births it seeds.

        With ``frame = (detect (J, K), miss (J,), kappa (K,))``, ``scan`` holds a frame's fused
        measurements: ``detect[j, k]`` is the probability that exactly the sensors behind fused
        measurement ``k`` detect component ``j``, ``miss[j]`` that no sensor does, and
        ``kappa[k]`` the clutter intensity of measurement ``k``.
        """
        pd_frame = None if frame is None else frame[1]
        cfg = self.config
        mix = self._mix
        z, R = scan.positions, scan.cov
        if pd_frame is None:
            R = R + cfg.extent_std**2 * np.eye(2)
        n_meas = z.shape[0]
        pd_out = cfg.detection_probability_outside
        if pd_frame is not None:
            visible = pd_frame > 0.0
            active = np.ones_like(visible)
        elif mix.w.size:
            xy = mix.m[:, ::2]
            visible = in_field_of_view(scan, xy)
            # Components far outside the view are untouched when p_D,out = 0: keep them aside.
            if pd_out == 0.0:
                active = in_field_of_view(scan, xy, cfg.fov_margin) | visible
            else:
                active = np.ones_like(visible)
        else:
            visible = active = np.zeros(0, dtype=bool)
        act = mix.take(active)
        rest = mix.take(~active)
        if pd_frame is not None:
            pd = 1.0 - pd_frame  # frame[1] is the probability that no sensor detects
        else:
            pd_sensor = self.detection_probabilities.get(scan.sensor, cfg.detection_probability)
            pd = np.where(visible[active], pd_sensor, pd_out) * self._sight(scan, act.m[:, ::2])
            if act.w.size > 1 and cfg.occluded_factor < 1.0:
                pd = pd * np.where(self._occluded(scan, act), cfg.occluded_factor, 1.0)

        if self.compiled:
            kappa_k = frame[2] if frame is not None else self._clutter_intensity(scan)
            return self._correct_compiled(
                scan, act, rest, z, R, pd, kappa_k, frame, visible[active]
            )
        explained = np.zeros(n_meas)
        claimed = np.zeros(n_meas, dtype=bool)
        if act.w.size and n_meas:
            Pa = act.P
            nu = z[None, :, :] - act.m[:, None, ::2]  # (Ja, k, 2)
            s00 = Pa[:, None, 0, 0] + R[None, :, 0, 0]
            s01 = Pa[:, None, 0, 2] + R[None, :, 0, 1]
            s11 = Pa[:, None, 2, 2] + R[None, :, 1, 1]
            det = s00 * s11 - s01 * s01
            n0, n1 = nu[..., 0], nu[..., 1]
            d2 = (s11 * n0 * n0 - 2.0 * s01 * n0 * n1 + s00 * n1 * n1) / det
            gated = d2 < cfg.gate
            q = np.exp(-0.5 * d2) / (_TWO_PI * np.sqrt(det))
            if frame is None:
                num = np.where(gated, (pd * act.w)[:, None] * q, 0.0)  # (Ja, k)
                kappa: FloatArray | float = self._clutter_intensity(scan)
            else:
                num = np.where(gated, act.w[:, None] * frame[0] * q, 0.0)
                kappa = frame[2]
            total = num.sum(axis=0)
            wdet = num / (kappa + total)
            explained = total / (kappa + total)
            # A measurement in the gate of a confirmed track seeds no birth, however light the
            # track is after missed detections: the birth would later absorb it in a merge.
            owned = self._protected(act, self._claim_arr)
            if owned is not None:
                claimed = (gated & owned[:, None]).any(axis=0)
            if cfg.adapt_detection and pd_frame is None:
                self._learn_detection(scan, act, visible[active], gated)
            jj, kk = np.nonzero(wdet > cfg.prune_threshold)
            if jj.size:
                # K = P H^T S^{-1} with the closed-form 2x2 inverse of S.
                inv_det = 1.0 / det[jj, kk]
                a, b, c = s11[jj, kk] * inv_det, -s01[jj, kk] * inv_det, s00[jj, kk] * inv_det
                Pj = Pa[jj]
                PHt = Pj[:, :, ::2]  # (n, 4, 2)
                K0 = PHt[:, :, 0] * a[:, None] + PHt[:, :, 1] * b[:, None]
                K1 = PHt[:, :, 0] * b[:, None] + PHt[:, :, 1] * c[:, None]
                v0, v1 = n0[jj, kk], n1[jj, kk]
                m_det = act.m[jj] + K0 * v0[:, None] + K1 * v1[:, None]
                # P - K H P, with H P = (P H^T)^T.
                P_det = (
                    Pj - K0[:, :, None] * PHt[:, None, :, 0] - K1[:, :, None] * PHt[:, None, :, 1]
                )
                detected = _Mixture(wdet[jj, kk], m_det, P_det, act.label[jj])
            else:
                detected = _Mixture.empty()
            missed = _Mixture(act.w * (1.0 - pd), act.m, act.P, act.label)
            act = _Mixture.concat((missed, detected))
        elif act.w.size:
            act.w = act.w * (1.0 - pd)

        if act.w.size:
            act = act.take(act.w > cfg.prune_threshold)
            act = _Mixture(
                *merge_components(
                    act.w,
                    act.m,
                    act.P,
                    act.label,
                    cfg.merge_threshold,
                    self._protected(act, self._claim_arr),
                )
            )
            if math.isfinite(cfg.max_label_weight):
                act.w = _cap_label_weight(act.w, act.label, cfg.max_label_weight)
            self._mix = _Mixture.concat((rest, act)) if rest.w.size else act
        else:
            self._mix = rest
        return self._births_from(scan, explained, claimed)

    def _correct_compiled(
        self,
        scan: SensorScan,
        act: _Mixture,
        rest: _Mixture,
        z: FloatArray,
        R: FloatArray,
        pd: FloatArray,
        kappa: FloatArray | float,
        frame: tuple[FloatArray, FloatArray, FloatArray] | None,
        visible: npt.NDArray[np.bool_],
    ) -> _Mixture:
        """The end of :meth:`_update` (correct, prune, merge, cap; births) in one call of
        :func:`~fusion_center.tracking.kernels.gmphd_correct`."""
        cfg = self.config
        n_act, n_meas = act.w.size, z.shape[0]
        if frame is None:
            detect = np.empty((n_act, n_meas))
            detect[:] = pd[:, None]
        else:
            detect = frame[0]
        w, m, P, label, explained, claimed, gated = kernels.gmphd_correct(
            act.w,
            act.m,
            act.P,
            act.label,
            _writable(detect),
            1.0 - pd,
            _writable(z),
            _writable(R),
            np.broadcast_to(kappa, (n_meas,)).astype(np.float64),
            self._claim_arr,
            cfg.gate,
            cfg.prune_threshold,
            cfg.merge_threshold,
            cfg.max_label_weight,
        )
        if cfg.adapt_detection and frame is None and n_act and n_meas:
            self._learn_detection(scan, act, visible, gated)
        done = _Mixture(w, m, P, label)
        self._mix = _Mixture.concat((rest, done)) if rest.w.size else done
        return self._births_from(scan, explained, claimed)

    def _frame_update(self, t: float, scans: Sequence[SensorScan]) -> _Mixture:
        """One GM-PHD update with the fused measurements of a frame (``fusion = "frame"``).

        Multi-sensor likelihood of a fused measurement ``k`` made of the estimates of the
        sensor set :math:`C_k`, for a component at :math:`x`:

        .. math::

            \\prod_{s \\in C_k} p_{D,s}(x) \\prod_{s \\notin C_k} (1 - p_{D,s}(x))
            \\; \\mathcal N(z_k; Hx, S)

        so a ghost that one sensor reports while others that see the spot stay silent gets
        little weight, and a person seen by several sensors much.
        """
        cfg = self.config
        z = np.concatenate([s.positions for s in scans])
        R = np.concatenate([s.cov for s in scans]) + cfg.extent_std**2 * np.eye(2)
        owner = np.repeat(np.arange(len(scans)), [s.positions.shape[0] for s in scans])
        mix = self._mix
        n_s = len(scans)
        pd_js = np.zeros((mix.w.size, n_s))
        if mix.w.size:
            xy = mix.m[:, ::2]
            heavy = mix.w > 0.5
            near = np.linalg.norm(xy[heavy, None, :] - z[None, :, :], axis=2) < cfg.cluster_distance
            if len({scan.sensor for scan in scans}) == n_s:
                pd_js = self._frame_detection(scans, mix, xy, heavy, near, owner)
            else:
                # A sensor with several scans in the frame: its profile adapts scan by scan.
                for i, scan in enumerate(scans):
                    one = near[:, owner == i]
                    pd_js[:, i] = self._frame_detection([scan], mix, xy, heavy, one, None)[:, 0]
        anchors = anchor_cov = None
        if mix.w.size:
            # One predicted position per established label: its heaviest component.
            est = mix.w > 0.5
            if est.any():
                order = np.flatnonzero(est)[np.argsort(-mix.w[est])]
                _, first = np.unique(mix.label[order], return_index=True)
                top = order[first]
                anchors = mix.m[top][:, ::2]
                anchor_cov = mix.P[top][:, ::2, ::2]
        zf, Rf, group = fuse_estimates(
            z,
            R,
            owner,
            cfg.cluster_distance,
            cfg.fused_noise_floor,
            anchors,
            anchor_cov,
            absorb_distance=cfg.extent_absorb_distance,
        )
        cells = np.zeros((zf.shape[0], n_s))
        cells[group, owner] = 1.0
        # A sensor that reported a person it should not see (edge of its view) still counts.
        eps = 1e-6
        log_pd = np.log(np.maximum(pd_js, 1e-3))
        log_miss = np.log(np.maximum(1.0 - pd_js, eps))
        detect = np.exp(log_pd @ cells.T + log_miss @ (1.0 - cells).T)  # (J, K)
        miss = np.exp(log_miss.sum(axis=1))
        if cfg.learn_frame_miss and mix.w.size:
            # Sensors' misses are not independent (a person standing still, shadowed, in a far
            # corner is missed by all for a while): the probability that no sensor detects a
            # person is at least the learned rate of frames in which an established track
            # (weight > 0.5, as for ``adapt_detection``) in some sensor's view had no
            # estimate near it from any sensor.
            seen_by = heavy & (pd_js > 0.0).any(axis=1)
            if cfg.adapt_detection and seen_by.any():
                unseen = ~near[seen_by[heavy]].any(axis=1)
                self.frame_miss += cfg.adapt_rate * (float(np.mean(unseen)) - self.frame_miss)
            miss = np.where(pd_js.any(axis=1), np.maximum(miss, self.frame_miss), miss)
            if cfg.label_miss_time > 0.0:
                miss = self._label_frame_miss(t, mix, heavy, near, pd_js, miss)
        if cfg.miss_correlation_time > 0.0 and mix.w.size and self._t_miss is not None:
            power = min(1.0, max(t - self._t_miss, 0.0) / cfg.miss_correlation_time)
            miss = np.where(heavy, miss**power, miss)
        self._t_miss = t
        # Each sensor's false estimates spread over its own view: the intensities add up; a
        # fused measurement of several sensors is clutter only if their false alarms coincide.
        kappa0 = sum(self._clutter_intensity(scan) for scan in scans)
        kappa = kappa0 * cfg.clutter_coincidence ** (cells.sum(axis=1) - 1.0)
        fused = SensorScan(sensor="*", t=t, positions=zf, cov=Rf, origin=np.zeros(2))
        return self._update(fused, frame=(detect, miss, kappa))

    def _frame_detection(
        self,
        scans: Sequence[SensorScan],
        mix: _Mixture,
        xy: FloatArray,
        heavy: npt.NDArray[np.bool_],
        near: npt.NDArray[np.bool_],
        owner: npt.NDArray[np.intp] | None,
    ) -> FloatArray:
        """``p_D,s(m_j)`` of every component j for every sensor s of a frame, shape (J, S),
        and the adaptation of the sensors' detection profiles (``adapt_detection``).

        Per sensor: zero outside its field of view (``fov_margin``) and in its blind zone
        (``min_range``), else its learned profile
        at the component's distance and bearing bin (``detection_range_bins``,
        ``detection_angle_bins``), times the ``sight`` factor and, for a component
        shadowed by a heavier one, ``occluded_factor``. A profile bin moves by ``adapt_rate``
        towards the fraction of established components (weight > 0.5) in clear sight in that
        bin that have an estimate of the sensor within ``cluster_distance`` (``near``:
        components x estimates; ``owner``: the scan of each estimate, ``None``: all from
        the one scan). The sensors are distinct, so every profile adapts once: all sensors
        are handled in one pass of array operations (at 100 sensors a loop over them cost
        more than the rest of the update). With ``compiled`` only the (component, sensor)
        pairs within a sensor's distance limits are handled (:meth:`_frame_detection_pairs`);
        this dense form is the reference.
        """
        if self.compiled:
            return self._frame_detection_pairs(scans, mix, xy, heavy, near, owner)
        cfg = self.config
        n_j, n_s = xy.shape[0], len(scans)
        origin = np.array([scan.origin for scan in scans])  # (S, 2)
        d = xy[:, None, :] - origin[None, :, :]  # (J, S, 2)
        r2 = np.einsum("jsi,jsi->js", d, d)
        max_range = np.array([scan.max_range for scan in scans])
        vis = r2 <= (max_range + cfg.fov_margin) ** 2  # in_field_of_view, all sensors at once
        vis &= r2 >= np.array([scan.min_range for scan in scans]) ** 2  # blind zone
        beamwidth = np.array([scan.beamwidth for scan in scans])
        sector = beamwidth < 2.0 * math.pi
        angles = np.asarray(cfg.detection_angle_bins)
        abin = np.zeros((n_j, n_s), dtype=np.intp)
        if sector.any():
            bearing = np.arctan2(d[..., 1], d[..., 0]) - np.array([s.boresight for s in scans])
            off = np.abs((bearing + math.pi) % (2.0 * math.pi) - math.pi)
            half = 0.5 * beamwidth
            if angles.size:
                # the bearing's fraction of the half field of view (0 for all-round sensors)
                abin = np.where(sector, np.searchsorted(angles, off / half), 0)
            if cfg.fov_margin > 0.0:
                with np.errstate(divide="ignore"):
                    half = half + np.arcsin(np.minimum(1.0, cfg.fov_margin / np.sqrt(r2)))
            vis &= (off <= half) | ~sector
        active = vis.any(axis=0)  # sensors that see some component
        pd_js = np.zeros((n_j, n_s))
        if not active.any():
            return pd_js
        cols = np.flatnonzero(active)
        edges = np.asarray(cfg.detection_range_bins)
        n_a = angles.size + 1
        nb = (edges.size + 1) * n_a
        profiles = self._profiles(scans, cols, edges.size + 1, n_a)
        v = vis[:, cols]
        # profile cell of each component and sensor: distance bin x bearing bin (J, S')
        cell = np.searchsorted(edges, np.linalg.norm(d[:, cols], axis=2)) * n_a + abin[:, cols]
        sight = self._sights([scans[i] for i in cols.tolist()], xy, v)
        pd = np.where(v, profiles[np.arange(cols.size), cell], 0.0) * sight
        if cfg.occluded_factor < 1.0 and n_j > 1:
            pd *= np.where(self._occluded_many(origin[cols], mix, v), cfg.occluded_factor, 1.0)
        pd_js[:, cols] = pd
        if cfg.adapt_detection:
            seen = (v & (sight >= 1.0))[heavy]  # (H, S')
            if seen.any():
                if owner is None:
                    hit = np.broadcast_to(near.any(axis=1)[:, None], seen.shape)
                else:
                    by_sensor = np.zeros((near.shape[1], n_s), bool)
                    by_sensor[np.arange(owner.size), owner] = True
                    hit = (near.astype(np.int64) @ by_sensor[:, cols]) > 0
                flat = (np.arange(cols.size) * nb + cell[heavy])[seen]
                self._adapt_profiles(scans, cols, profiles, flat, hit[seen])
        return pd_js

    def _profiles(
        self, scans: Sequence[SensorScan], cols: npt.NDArray[np.intp], n_r: int, n_a: int
    ) -> FloatArray:
        """The detection profiles of the sensors of ``scans[cols]`` as rows, shape
        (len(cols), n_r * n_a) (a copy; a new sensor's is created)."""
        nb = n_r * n_a
        profiles = np.empty((cols.size, nb))
        for c, i in enumerate(cols.tolist()):
            profile = self.detection_profiles.get(scans[i].sensor)
            if profile is None or profile.size != nb:
                # new sensor, or a profile learned with other bins (a config swapped on a
                # live tracker): keep what was learned per distance when it can be kept
                if profile is not None and profile.size == n_r:
                    profile = np.repeat(profile, n_a)
                else:
                    profile = np.full(nb, self.config.detection_probability)
                self.detection_profiles[scans[i].sensor] = profile
            profiles[c] = profile
        return profiles

    def _adapt_profiles(
        self,
        scans: Sequence[SensorScan],
        cols: npt.NDArray[np.intp],
        profiles: FloatArray,
        flat: npt.NDArray[np.intp],
        hit: npt.NDArray[np.bool_],
    ) -> None:
        """Move the profile bins ``flat`` (row x bins + bin of ``profiles``, one per
        established component in clear sight) towards the fraction with ``hit``."""
        cfg = self.config
        n_c, nb = profiles.shape
        count = np.bincount(flat, minlength=n_c * nb).reshape(n_c, nb)
        rate = np.bincount(flat, weights=hit, minlength=n_c * nb).reshape(n_c, nb)
        # All sensors' profiles at once (``profiles`` holds them as they were): the bins with
        # a count move towards their rate, then an updated profile is clipped as a whole. A
        # loop over the sensors cost a third of the update.
        upd = count > 0
        moved = profiles.copy()
        moved[upd] += cfg.adapt_rate * (rate[upd] / count[upd] - profiles[upd])
        np.clip(moved, cfg.min_detection_probability, cfg.max_detection_probability, out=moved)
        for c in np.flatnonzero(upd.any(axis=1)).tolist():
            self.detection_profiles[scans[cols[c]].sensor][:] = moved[c]

    def _frame_detection_pairs(
        self,
        scans: Sequence[SensorScan],
        mix: _Mixture,
        xy: FloatArray,
        heavy: npt.NDArray[np.bool_],
        near: npt.NDArray[np.bool_],
        owner: npt.NDArray[np.intp] | None,
    ) -> FloatArray:
        """:meth:`_frame_detection` on the (component, sensor) pairs within the sensors'
        distance limits only, found by one compiled loop (``kernels.range_pairs``), instead
        of a dozen dense (J, S) arrays: at 48 sensors a sensor's range holds a few of the
        components. Each pair gets the same element-wise operations as in the dense form
        (numpy's ``arctan2``, ``arcsin`` and ``searchsorted`` included), so the same values
        bit for bit (``tests/unit/tracking/test_frame_detection.py``)."""
        cfg = self.config
        n_j, n_s = xy.shape[0], len(scans)
        pd_js = np.zeros((n_j, n_s))
        origin = np.array([scan.origin for scan in scans])  # (S, 2)
        # float64 after the arithmetic: the kernel takes float64 only, and integer or float32
        # limits (a scan built by hand) must square as the dense form squares them
        hi2 = ((np.array([scan.max_range for scan in scans]) + cfg.fov_margin) ** 2).astype(
            np.float64, copy=False
        )
        lo2 = (np.array([scan.min_range for scan in scans]) ** 2).astype(np.float64, copy=False)
        j, s, dx, dy, r2 = kernels.range_pairs(xy, origin, hi2, lo2)
        beamwidth = np.array([scan.beamwidth for scan in scans])
        sector = beamwidth < 2.0 * math.pi
        angles = np.asarray(cfg.detection_angle_bins)
        abin = np.zeros(j.size, dtype=np.intp)
        if sector.any() and j.size:
            bearing = np.arctan2(dy, dx) - np.array([scan.boresight for scan in scans])[s]
            off = np.abs((bearing + math.pi) % (2.0 * math.pi) - math.pi)
            half, sec = (0.5 * beamwidth)[s], sector[s]
            if angles.size:
                abin = np.where(sec, np.searchsorted(angles, off / half), 0)
            if cfg.fov_margin > 0.0:
                with np.errstate(divide="ignore"):
                    half = half + np.arcsin(np.minimum(1.0, cfg.fov_margin / np.sqrt(r2)))
            keep = (off <= half) | ~sec
            j, s, r2, abin = j[keep], s[keep], r2[keep], abin[keep]
        if not j.size:
            return pd_js
        active = np.zeros(n_s, dtype=bool)
        active[s] = True
        cols = np.flatnonzero(active)
        c = (np.cumsum(active) - 1)[s]  # each pair's row among the active sensors
        edges = np.asarray(cfg.detection_range_bins)
        n_a = angles.size + 1
        nb = (edges.size + 1) * n_a
        profiles = self._profiles(scans, cols, edges.size + 1, n_a)
        cell = np.searchsorted(edges, np.sqrt(r2)) * n_a + abin
        if self.sight is None:
            sight = np.ones(j.size)
        elif getattr(self.sight, "pairs", None) is not None:
            sight = self.sight.pairs(origin[s], xy[j])
        else:
            sight = np.stack([self.sight(scans[i], xy) for i in cols.tolist()], axis=1)[j, c]
        pd = profiles[c, cell] * sight
        if cfg.occluded_factor < 1.0 and n_j > 1:
            v = np.zeros((n_j, cols.size), dtype=bool)
            v[j, c] = True
            occluded = self._occluded_many(origin[cols], mix, v)[j, c]
            pd *= np.where(occluded, cfg.occluded_factor, 1.0)
        pd_js[j, s] = pd
        if cfg.adapt_detection:
            seen = heavy[j] & (sight >= 1.0)
            if seen.any():
                row = (np.cumsum(heavy) - 1)[j[seen]]  # each seen pair's row of ``near``
                if owner is None:
                    hit = near.any(axis=1)[row]
                else:
                    by_sensor = np.zeros((near.shape[1], n_s), bool)
                    by_sensor[np.arange(owner.size), owner] = True
                    hit = ((near.astype(np.int64) @ by_sensor[:, cols]) > 0)[row, c[seen]]
                flat = c[seen] * nb + cell[seen]
                self._adapt_profiles(scans, cols, profiles, flat, hit)
        return pd_js

    def _sights(
        self, scans: Sequence[SensorScan], xy: FloatArray, vis: npt.NDArray[np.bool_]
    ) -> FloatArray:
        """The ``sight`` factor of each scan's sensor at ``xy``, shape (J, S); 1 where
        ``vis`` (J, S) is false (outside the sensor's view the factor does not matter)."""
        if self.sight is None:
            return np.ones((xy.shape[0], len(scans)))
        pairs = getattr(self.sight, "pairs", None)
        if pairs is None:
            return np.stack([self.sight(scan, xy) for scan in scans], axis=1)
        out = np.ones((xy.shape[0], len(scans)))
        j, s = np.nonzero(vis)
        out[j, s] = pairs(np.array([scan.origin for scan in scans])[s], xy[j])
        return out

    def _occluded_many(
        self, origins: FloatArray, mix: _Mixture, mask: npt.NDArray[np.bool_] | None = None
    ) -> npt.NDArray[np.bool_]:
        """:meth:`_occluded` for sensors at ``origins`` (S, 2) at once, shape (J, S); where
        ``mask`` (J, S) is False (a sensor that cannot see the component) the result may be
        False whatever the geometry."""
        cfg = self.config
        if self.compiled:
            if mask is None:
                mask = np.ones((mix.w.size, origins.shape[0]), dtype=bool)
            return kernels.occluded(mix.w, mix.m, mix.label, origins, mask, cfg.occlusion_radius)
        heavy = mix.w > 0.3
        if heavy.sum() == 0:
            return np.zeros((mix.w.size, origins.shape[0]), dtype=bool)
        xy = mix.m[None, :, ::2] - origins[:, None, :]  # (S, J, 2)
        occ, occ_label = xy[:, heavy], mix.label[heavy]  # (S, O, 2)
        dist = np.linalg.norm(xy, axis=2)  # (S, J)
        unit = xy / np.maximum(dist, 1e-9)[..., None]
        along = occ @ np.swapaxes(unit, 1, 2)  # (S, O, J)
        perp = np.abs(
            occ[:, :, 0, None] * unit[:, None, :, 1] - occ[:, :, 1, None] * unit[:, None, :, 0]
        )
        shadows = (
            (along > 0.0)
            & (along < dist[:, None, :] - 2.0 * cfg.occlusion_radius)
            & (perp < cfg.occlusion_radius)
            & (occ_label[:, None] != mix.label[None, :])[None]
        )
        return shadows.any(axis=1).T

    def _label_frame_miss(
        self,
        t: float,
        mix: _Mixture,
        heavy: npt.NDArray[np.bool_],
        near: npt.NDArray[np.bool_],
        pd_js: FloatArray,
        miss: FloatArray,
    ) -> FloatArray:
        """The frame's miss probability of each component, raised to its label's learned rate.

        Beyond the chapter (see ``label_miss_time``): each established label (a component
        above 0.5 in some sensor's view) learns the rate of frames in which no estimate of any
        sensor fell within ``cluster_distance`` of it, an exponential average with time
        constant ``label_miss_time``, starting from the shared ``frame_miss``. The probability
        that no sensor detects a component is never below its label's rate (capped at
        ``max_label_miss``).

        Parameters
        ----------
        t : float
            Frame time, s.
        mix : _Mixture
            The predicted mixture (J components).
        heavy : ndarray, bool, shape (J,)
            Components above weight 0.5.
        near : ndarray, bool, shape (H, K)
            For each heavy component, whether each measurement is within ``cluster_distance``.
        pd_js : ndarray, shape (J, S)
            Each sensor's detection probability of each component.
        miss : ndarray, shape (J,)
            The probability that no sensor detects each component, so far.

        Returns
        -------
        ndarray, shape (J,)
            ``miss`` raised to the label rates.
        """
        cfg = self.config
        dt = 0.0 if self._t_frame is None else max(t - self._t_frame, 0.0)
        self._t_frame = t
        in_view = pd_js.any(axis=1)
        rates = self.label_miss
        seen = heavy & in_view
        if dt > 0.0 and seen.any():
            gain = -math.expm1(-dt / cfg.label_miss_time)
            hit = near[seen[heavy]].any(axis=1)
            # one observation per label: hit if any of its heavy components was hit
            labels, inverse = np.unique(mix.label[seen], return_inverse=True)
            label_hit = np.zeros(labels.size, dtype=bool)
            np.logical_or.at(label_hit, inverse, hit)
            for lb, h in zip(labels.tolist(), label_hit.tolist(), strict=True):
                old = rates.get(lb, self.frame_miss)
                rates[lb] = old + gain * ((0.0 if h else 1.0) - old)
            if len(rates) > 2 * labels.size + 64:  # forget labels that left the mixture
                live = set(mix.label.tolist())
                self.label_miss = rates = {k: v for k, v in rates.items() if k in live}
        if not rates:
            return miss
        keys = np.fromiter(rates.keys(), dtype=np.int64, count=len(rates))
        vals = np.fromiter(rates.values(), dtype=np.float64, count=len(rates))
        order = np.argsort(keys)
        keys, vals = keys[order], np.minimum(vals[order], cfg.max_label_miss)
        idx = np.minimum(np.searchsorted(keys, mix.label), keys.size - 1)
        own = np.where(keys[idx] == mix.label, vals[idx], 0.0)
        return np.where(in_view, np.maximum(miss, own), miss)

    def _occluded(self, scan: SensorScan, mix: _Mixture) -> npt.NDArray[np.bool_]:
        """Components shadowed, for ``scan``'s sensor, by a heavier component of another label
        nearer to the sensor within ``occlusion_radius`` of the line of sight."""
        cfg = self.config
        if self.compiled:
            origin = np.array(scan.origin, dtype=np.float64).reshape(1, 2)
            everywhere = np.ones((mix.w.size, 1), dtype=bool)
            return kernels.occluded(
                mix.w, mix.m, mix.label, origin, everywhere, cfg.occlusion_radius
            )[:, 0]
        xy = mix.m[:, ::2] - scan.origin  # (J, 2), relative to the sensor
        heavy = mix.w > 0.3
        if heavy.sum() == 0:
            return np.zeros(mix.w.size, dtype=bool)
        occ, occ_label = xy[heavy], mix.label[heavy]
        dist = np.linalg.norm(xy, axis=1)  # (J,)
        unit = xy / np.maximum(dist, 1e-9)[:, None]
        along = occ @ unit.T  # (O, J): distance of each occluder along each line of sight
        perp = np.abs(occ[:, 0, None] * unit[None, :, 1] - occ[:, 1, None] * unit[None, :, 0])
        shadows = (
            (along > 0.0)
            & (along < dist[None, :] - 2.0 * cfg.occlusion_radius)
            & (perp < cfg.occlusion_radius)
            & (occ_label[:, None] != mix.label[None, :])
        )
        return shadows.any(axis=0)

    def _learn_detection(
        self,
        scan: SensorScan,
        mix: _Mixture,
        visible: npt.NDArray[np.bool_],
        gated: npt.NDArray[np.bool_],
    ) -> None:
        """Update the sensor's learned ``p_D`` with the fraction of the established labels in its
        view (heaviest component above 0.5) that had a measurement in their gate."""
        cfg = self.config
        heavy = visible & (mix.w > 0.5)
        labels = np.unique(mix.label[heavy])
        if labels.size == 0:
            return
        hit_labels = np.unique(mix.label[gated.any(axis=1) & heavy])
        rate = np.isin(labels, hit_labels).mean()
        pd = self.detection_probabilities.get(scan.sensor, cfg.detection_probability)
        pd += cfg.adapt_rate * (rate - pd)
        self.detection_probabilities[scan.sensor] = float(
            min(max(pd, cfg.min_detection_probability), cfg.max_detection_probability)
        )

    def _merge_births(self, births: _Mixture) -> _Mixture:
        """One birth per person: births of one step closer than ``cluster_distance`` (a
        person's body seen as separate estimates by different sensors) are merged, weights
        summed (capped at 1) and moments matched; the merged birth keeps the first label."""
        n = births.w.size
        if n < 2:
            return births
        if self.compiled:
            return _Mixture(
                *kernels.merge_births(
                    births.w, births.m, births.P, births.label, self.config.cluster_distance
                )
            )
        xy = births.m[:, ::2]
        # Leader clustering (a few births per step): each birth joins the first earlier
        # leader within ``cluster_distance``, else leads a group of its own.
        near = np.linalg.norm(xy[:, None] - xy[None], axis=2) <= self.config.cluster_distance
        group = np.full(n, -1, dtype=np.int64)
        k = 0
        for i in range(n):
            if group[i] < 0:
                group[(group < 0) & near[i]] = k
                k += 1
        if k == n:
            return births
        w = np.zeros(k)
        np.add.at(w, group, births.w)
        m = np.zeros((k, 4))
        np.add.at(m, group, births.w[:, None] * births.m)
        m /= w[:, None]
        d = births.m - m[group]
        P = np.zeros((k, 4, 4))
        np.add.at(P, group, births.w[:, None, None] * (births.P + d[:, :, None] * d[:, None, :]))
        P /= w[:, None, None]
        first = np.full(k, n)
        np.minimum.at(first, group, np.arange(n))
        return _Mixture(np.minimum(w, 1.0), m, P, births.label[first])

    def _births_from(
        self, scan: SensorScan, explained: FloatArray, claimed: npt.NDArray[np.bool_]
    ) -> _Mixture:
        """Adaptive birth: one component per poorly explained, unclaimed measurement."""
        cfg = self.config
        if self.compiled:
            w, m, P = kernels.seed_births(
                _writable(scan.positions),
                _writable(scan.cov),
                explained,
                claimed,
                cfg.birth_max_association,
                cfg.birth_weight,
                cfg.birth_velocity_std**2,
            )
            labels = np.arange(self._next_label, self._next_label + w.size, dtype=np.int64)
            self._next_label += w.size
            return _Mixture(w, m, P, labels)
        seed = (explained < cfg.birth_max_association) & ~claimed
        n = int(seed.sum())
        if n == 0:
            return _Mixture.empty()
        z, R = scan.positions[seed], scan.cov[seed]
        m = np.zeros((n, 4))
        m[:, ::2] = z
        P = np.zeros((n, 4, 4))
        P[:, 0, 0], P[:, 0, 2], P[:, 2, 0], P[:, 2, 2] = (
            R[:, 0, 0],
            R[:, 0, 1],
            R[:, 1, 0],
            R[:, 1, 1],
        )
        P[:, 1, 1] = P[:, 3, 3] = cfg.birth_velocity_std**2
        labels = np.arange(self._next_label, self._next_label + n, dtype=np.int64)
        self._next_label += n
        return _Mixture(cfg.birth_weight * (1.0 - explained[seed]), m, P, labels)

    # -- public ---------------------------------------------------------------------------

    def step(self, t: float, scans: Sequence[SensorScan]) -> TrackerOutput:
        """Advance the filter to ``t`` with this frame's scans.

        Parameters
        ----------
        t : float
            Output time, s.
        scans : sequence of SensorScan
            The frame's scans; processed in order of ``scan.t`` (iterated corrector).

        Returns
        -------
        TrackerOutput
            Confirmed labelled tracks at ``t`` and the expected target number
            ``Σ_j w_j``.
        """
        if self._t is None:
            self._t = min([t, *(s.t for s in scans)])
        if self._births.w.size:
            self._mix = (
                _Mixture.concat((self._mix, self._births)) if self._mix.w.size else self._births
            )
            self._births = _Mixture.empty()
        births = []
        # With one sensor in the frame, the frame update is the plain GM-PHD update.
        frame_mode = self.config.fusion == "frame" and len(scans) > 1
        if frame_mode:
            tf = max(s.t for s in scans)
            if tf > self._t:
                self._predict(tf - self._t)
                self._t = tf
            b = self._frame_update(tf, scans)
            if b.w.size:
                births.append(b)
        for scan in () if frame_mode else sorted(scans, key=lambda s: s.t):
            if scan.t > self._t:
                self._predict(scan.t - self._t)
                self._t = scan.t
            b = self._update(scan)
            if b.w.size:
                births.append(b)
        if t > self._t:
            self._predict(t - self._t)
            self._t = t
        if births:
            self._births = self._merge_births(
                births[0] if len(births) == 1 else _Mixture.concat(births)
            )
        if len(scans) > 1 and self._mix.w.size > 1:
            # Components of one target seen by different sensors were merged per sensor only.
            mix = self._mix
            if self.compiled:
                merged = kernels.merge_mixture(
                    mix.w,
                    mix.m,
                    mix.P,
                    mix.label,
                    self._confirmed_arr,
                    self.config.merge_threshold,
                    math.inf,
                )
            else:
                merged = merge_components(
                    mix.w,
                    mix.m,
                    mix.P,
                    mix.label,
                    self.config.merge_threshold,
                    self._protected(mix),
                )
            self._mix = _Mixture(*merged)
        mix = self._mix
        if mix.w.size > self.config.max_components:
            self._mix = mix.take(np.argsort(-mix.w)[: self.config.max_components])
        if self.config.duplicate_window > 0.0:
            self._fold_mean_gap_duplicates(t)
        else:
            self._fold_duplicate_labels()
        return self._extract(t)

    def _reidentify(self, t: float, m: FloatArray) -> int | None:
        """The label of a recently lost track that a new track at state ``m`` continues.

        Track continuity beyond the chapter: a person who went unseen for a moment (a
        corner no sensor covers well, shadowed by another) is re-born as a new label; if it
        appears within ``reid_radius + reid_speed * dt`` of where a confirmed track was last
        reported ``dt <= reid_time`` ago, it gets that track's id back (nearest wins).
        """
        cfg = self.config
        best, best_d = None, math.inf
        for lb, (tl, x, y) in self._lost.items():
            dt = t - tl
            d = math.hypot(m[0] - x, m[2] - y)
            if dt <= cfg.reid_time and d <= cfg.reid_radius + cfg.reid_speed * dt and d < best_d:
                best, best_d = lb, d
        if best is not None:
            del self._lost[best]
        return best

    def _relink(
        self,
        t: float,
        m: FloatArray,
        labels: npt.NDArray[np.int64],
        strong: npt.NDArray[np.bool_],
    ) -> None:
        """Hand the confirmation history of fading unconfirmed labels to new labels.

        Beyond the chapter: a person seen in a third of the frames (entering at the far end
        of a hall, by a wall, where every sensor sees the body at a wide angle) gains a label
        that the next few empty frames cost all its weight (the sensors' misses are treated as
        independent, and they are not), and the next detection seeds a new label with no
        history, so no label stays above ``extract_threshold`` for ``confirm_time``. A new
        label (first seen this step, heads ``m`` of ``labels``) near where an unconfirmed
        label was last strong (see ``relink_time``), which is not strong now, continues its
        count of steps and time above the threshold (nearest wins; each history is handed on
        once). The new label keeps its own id: unconfirmed labels are not reported.
        """
        cfg = self.config
        fading = self._fading
        if fading:
            for lb in [lb for lb, e in fading.items() if t - e[0] > cfg.relink_time]:
                del fading[lb]
        lab = labels.tolist()
        confirmed = self._confirmed
        new = [i for i, lb in enumerate(lab) if lb not in self._hits] if fading else []
        cand: list[int] = []
        if new:
            strong_now = set(labels[strong].tolist())
            cand = [lb for lb in fading if lb not in strong_now and lb not in confirmed]
        if new and cand:
            xy = m[new][:, ::2]
            past = np.array([fading[lb][:3] for lb in cand])  # (C, 3): t, x, y
            d = np.linalg.norm(xy[:, None, :] - past[None, :, 1:], axis=2)
            d[d > cfg.reid_radius + cfg.reid_speed * (t - past[:, 0])] = math.inf
            conf = np.fromiter((lb in confirmed for lb in lab), bool, len(lab))
            if conf.any():
                # a new label on a confirmed track is a second label of that person, not a
                # person's re-birth
                gap = np.linalg.norm(xy[:, None, :] - m[conf][None, :, ::2], axis=2)
                d[gap.min(axis=1) < cfg.reid_radius] = math.inf
            taken_new = np.zeros(d.shape[0], bool)
            taken_cand = np.zeros(d.shape[1], bool)
            # nearest pair first over all new labels and histories; each handed on once
            flat = np.argsort(d, axis=None)
            for f, dist in zip(flat.tolist(), d.ravel()[flat].tolist(), strict=True):
                if dist == math.inf:
                    break
                k, j = divmod(f, d.shape[1])
                if not (taken_new[k] or taken_cand[j]):
                    taken_new[k] = taken_cand[j] = True
                    i = new[k]
                    src = cand[j]
                    _, _, _, h, st = fading.pop(src)
                    self._hits[lab[i]], self._strong_time[lab[i]] = h, st
                    # moved, not copied: the weak source label starts again from nothing
                    # (with a copy both labels reached confirmation on one person)
                    self._hits[src], self._strong_time[src] = 0, 0.0
        for lb in confirmed:
            fading.pop(lb, None)
        for i in np.flatnonzero(strong).tolist():
            lb = lab[i]
            if lb not in confirmed:
                fading[lb] = (
                    t,
                    float(m[i, 0]),
                    float(m[i, 2]),
                    self._hits.get(lb, 0) + 1,
                    self._strong_time.get(lb, 0.0),
                )

    def _fold_duplicate_labels(self) -> None:
        """Fold labels that follow one person into the oldest (see ``duplicate_steps``)."""
        cfg = self.config
        mix = self._mix
        if mix.w.size < 2 or cfg.duplicate_steps <= 0:
            self._dup_count.clear()
            return
        if self.compiled:
            pairs = kernels.duplicate_pairs(
                mix.w, mix.m, mix.label, 0.05, cfg.duplicate_distance, cfg.duplicate_velocity
            )
            self._count_duplicates(pairs.tolist() if pairs.shape[1] == 2 else None)
            return
        order, first = _by_label(mix.w, mix.label)
        heads = order[first]
        heads = heads[mix.w[heads] > 0.05]
        labels = mix.label[heads]
        if labels.size < 2:
            self._dup_count.clear()
            return
        m = mix.m[heads]
        dp = np.linalg.norm(m[:, None, ::2] - m[None, :, ::2], axis=2)
        dv = np.linalg.norm(m[:, None, 1::2] - m[None, :, 1::2], axis=2)
        close = np.triu((dp < cfg.duplicate_distance) & (dv < cfg.duplicate_velocity), 1)
        self._count_duplicates(
            [(int(labels[i]), int(labels[j])) for i, j in zip(*np.nonzero(close), strict=True)]
        )

    def _fold_mean_gap_duplicates(self, t: float) -> None:
        """Fold labels whose mean gap stays within a body width (see ``duplicate_window``).

        Each pair of label heads (weight above 0.05) within ``3 * duplicate_distance`` of each
        other keeps an exponential average, time constant ``duplicate_window``, of its state
        difference; after ``duplicate_steps`` steps with a mean position gap below
        ``duplicate_distance`` and a mean velocity gap below ``duplicate_velocity`` (a step
        outside them costs one step, as in :meth:`_count_duplicates`), the younger label is
        folded into the older.
        """
        cfg = self.config
        mix = self._mix
        dt = 0.0 if self._t_dup is None else max(t - self._t_dup, 0.0)
        self._t_dup = t
        keys = np.zeros(0, dtype=np.int64)
        n = np.zeros(0, dtype=np.int64)
        mean = np.zeros((0, 4))
        if mix.w.size >= 2 and cfg.duplicate_steps > 0:
            order, first = _by_label(mix.w, mix.label)
            heads = order[first]
            heads = heads[mix.w[heads] > 0.05]
            labels = mix.label[heads]
            xy = mix.m[heads][:, ::2]
            dp = np.linalg.norm(xy[:, None, :] - xy[None, :, :], axis=2)
            ii, jj = np.nonzero(np.triu(dp < 3.0 * cfg.duplicate_distance, 1))
            if ii.size:
                swap = labels[ii] > labels[jj]
                lo, hi = np.where(swap, jj, ii), np.where(swap, ii, jj)  # older label first
                diff = mix.m[heads[lo]] - mix.m[heads[hi]]
                keys = (labels[lo] << 32) + labels[hi]
                pk, pn, pm = self._dup_gap
                at = np.minimum(np.searchsorted(pk, keys), max(pk.size - 1, 0))
                found = (pk[at] == keys) if pk.size else np.zeros(keys.size, bool)
                mean = np.where(found[:, None], pm[at] if pk.size else diff, diff)
                mean = mean - math.expm1(-dt / cfg.duplicate_window) * (diff - mean)
                close = (np.hypot(mean[:, 0], mean[:, 2]) < cfg.duplicate_distance) & (
                    np.hypot(mean[:, 1], mean[:, 3]) < cfg.duplicate_velocity
                )
                n = np.where(found, pn[at] if pk.size else 0, 0)
                n = np.where(close, n + 1, np.maximum(n - 1, 0))
                srt = np.argsort(keys)
                keys, n, mean = keys[srt], n[srt], mean[srt]
        self._dup_gap = (keys, n, mean)
        self._fold_pairs(
            [(k >> 32, k & 0xFFFFFFFF) for k in keys[n >= cfg.duplicate_steps].tolist()]
        )

    def _fold_pairs(self, pairs: list[tuple[int, int]]) -> None:
        """Fold each pair ``(older, younger)`` of labels into one: the older label, unless
        only the younger is confirmed (its id is the one users see: keeping the older one was
        an id switch). A label folded earlier in the list stands for the one it went into
        (three heads in a row gave pairs (1, 2) and (2, 3): 2 came back on 3's components)."""
        mix = self._mix
        into: dict[int, int] = {}
        for a, b in pairs:
            while a in into:
                a = into[a]
            while b in into:
                b = into[b]
            if a == b:
                continue
            keep, drop = min(a, b), max(a, b)
            if drop in self._confirmed and keep not in self._confirmed:
                keep, drop = drop, keep
            mix.label[mix.label == drop] = keep
            into[drop] = keep
            self._confirmed.discard(drop)
            self._hits.pop(drop, None)
            self._strong_time.pop(drop, None)

    def _count_duplicates(self, pairs: list[tuple[int, int]] | list[list[int]] | None) -> None:
        """Count each pair of labels ``pairs`` found close this step and fold those close for
        ``duplicate_steps`` (``None``: fewer than two labels, every count is reset)."""
        cfg = self.config
        if pairs is None:
            self._dup_count.clear()
            return
        # A pair that is apart for a step loses one count rather than all: the weights of
        # labels sharing one person fluctuate, and one step apart is no proof of two people.
        counts = {k: v - 1 for k, v in self._dup_count.items() if v > 1}
        for pair in pairs:
            a, b = sorted(pair)
            counts[(a, b)] = self._dup_count.get((a, b), 0) + 1
        self._dup_count = counts
        self._fold_pairs([pair for pair, n in counts.items() if n >= cfg.duplicate_steps])

    def _label_heads(self, mix: _Mixture) -> tuple[npt.NDArray[np.intp], FloatArray]:
        """Each label's heaviest component (ascending label order) and summed weight, after
        giving a second heavy component of a label, away from its head, a fresh label."""
        cfg = self.config
        order, first = _by_label(mix.w, mix.label)
        # A second heavy component of one label is another target: give it a fresh label.
        dup = ~first & (mix.w[order] >= cfg.split_threshold)
        if dup.any():
            # ... unless it sits on the head of its label (it differs in velocity only).
            head_of = order[np.maximum.accumulate(np.where(first, np.arange(first.size), 0))]
            cand, head = order[dup], head_of[dup]
            dp = mix.m[cand][:, ::2] - mix.m[head][:, ::2]
            Ph = mix.P[head][:, ::2, ::2]
            d2 = np.einsum("ni,ni->n", dp, np.linalg.solve(Ph, dp[:, :, None])[:, :, 0])
            dup[dup] = d2 > cfg.merge_threshold
        if dup.any():
            n_dup = int(dup.sum())
            idx = order[dup]
            mix.label[idx] = np.arange(self._next_label, self._next_label + n_dup)
            self._next_label += n_dup
            order, first = _by_label(mix.w, mix.label)
        starts = np.flatnonzero(first)
        label_w = np.add.reduceat(mix.w[order], starts)
        heads = order[starts]
        return heads, label_w

    def _extract(self, t: float) -> TrackerOutput:
        """Labelled estimates: per label, the heaviest component; sum of weights as ``w``."""
        cfg = self.config
        mix = self._mix
        dt = 0.0 if self._t_extract is None else max(t - self._t_extract, 0.0)
        self._t_extract = t
        self._elapsed += dt
        now = self._elapsed
        if mix.w.size == 0:
            self._lost.update(self._last_report)
            self._last_report = {}
            self._hits.clear()
            self._strong_time.clear()
            self._confirmed.clear()
            self._confirmed_arr = np.zeros(0, dtype=np.int64)
            self._claim_arr = self._confirmed_arr
            return TrackerOutput(t=t, tracks=(), n_estimate=0.0)
        if self.compiled:
            mix.label, heads, label_w, self._next_label = kernels.label_heads(
                mix.w,
                mix.m,
                mix.P,
                mix.label,
                cfg.split_threshold,
                cfg.merge_threshold,
                self._next_label,
            )
        else:
            heads, label_w = self._label_heads(mix)
        labels = mix.label[heads]
        strong = label_w >= cfg.extract_threshold

        hits, strong_time = {}, {}
        if cfg.relink_time > 0.0:
            self._relink(t, mix.m[heads], labels, strong)
        for label, is_strong in zip(labels.tolist(), strong.tolist(), strict=True):
            hits[label] = self._hits.get(label, 0) + int(is_strong)
            strong_time[label] = self._strong_time.get(label, 0.0) + dt * is_strong
        self._hits, self._strong_time = hits, strong_time
        confirmed = {lb for lb in self._confirmed if lb in hits}
        newly = [lb for lb, h in hits.items() if h >= cfg.confirm_steps and lb not in confirmed]
        for lb in newly:
            # A track lost a moment ago that re-appears where it was is not a new person:
            # it is confirmed at once; any other new label waits for ``confirm_time``.
            old = self._reidentify(t, mix.m[heads[labels == lb][0]])
            if old is not None and old in hits:
                old = None  # still in the mixture under its own label: never two with one id
            if old is None and strong_time[lb] < cfg.confirm_time:
                continue
            if old is not None:
                mix.label[mix.label == lb] = old
                labels[labels == lb] = old
                hits[old] = hits.pop(lb)
                strong_time[old] = strong_time.pop(lb)
                lb = old
            confirmed.add(lb)
            self._confirmed_t[lb] = now
        self._confirmed = confirmed
        self._confirmed_arr = np.sort(np.fromiter(confirmed, dtype=np.int64, count=len(confirmed)))

        is_confirmed = np.fromiter((lb in confirmed for lb in labels.tolist()), bool)
        strong_now = label_w >= cfg.keep_threshold
        seen = {lb: now for lb, ok in zip(labels.tolist(), strong_now.tolist(), strict=True) if ok}
        self._last_strong = {
            lb: seen.get(lb, self._last_strong.get(lb, -math.inf)) for lb in labels.tolist()
        }
        # Coast: a confirmed track stays reported (predicted) through short gaps in detection.
        coasting = np.fromiter(
            (now - self._last_strong[lb] <= cfg.coast_time for lb in labels.tolist()), bool
        )
        report = is_confirmed & (strong_now | coasting)
        # (a re-identified track may be confirmed while below keep_threshold: its time counts
        # from the confirmation)
        self._confirmed_t = {lb: self._confirmed_t.get(lb, now) for lb in confirmed}
        claim = [
            lb
            for lb in labels[is_confirmed].tolist()
            if now - max(self._last_strong[lb], self._confirmed_t[lb]) <= cfg.claim_time
        ]
        self._claim_arr = np.sort(np.array(claim, dtype=np.int64))
        reported = labels[report].tolist()
        for lb in set(self._last_report) - set(reported):
            self._lost[lb] = self._last_report[lb]  # it was reported last step, not now
        self._last_report = {
            lb: (t, mm[0], mm[2])
            for lb, mm in zip(reported, mix.m[heads[report]].tolist(), strict=True)
        }
        for lb in [lb for lb, (tl, _, _) in self._lost.items() if t - tl > cfg.reid_time]:
            del self._lost[lb]
        tracks = tuple(
            TrackEstimate(id=int(lb), x=mm[0], vx=mm[1], y=mm[2], vy=mm[3], cov=PP, w=ww)
            for lb, mm, PP, ww in zip(
                labels[report].tolist(),
                mix.m[heads[report]].tolist(),
                mix.P[heads[report]],
                label_w[report].tolist(),
                strict=True,
            )
        )
        return TrackerOutput(t=t, tracks=tracks, n_estimate=float(mix.w.sum()))
