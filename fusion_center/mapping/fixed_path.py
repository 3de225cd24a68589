r"""The map of a robot's echoes along a known path (batch mapping at fixed poses).

Given every acquisition's pose (a path from another estimator, e.g. stop-to-stop scan
registration), the landmarks are estimated directly, without a filter:

1. every echo pair ``(r1, r2)`` is inverted in the array frame (Fig. 19 / eq. (11) of the
   CoLOR chapter, :func:`~fusion_center.mapping.models.invert_image` and
   :func:`~fusion_center.mapping.models.invert_point`) and moved into the world frame; an echo
   group of the measurement-space association (:mod:`fusion_center.mapping.grouping`, one
   track within one stop) gives one robust mean image point ``T'`` and point ``p``;
2. each group is a wall hypothesis (the perpendicular bisector of ``tx`` and ``T'``, normal
   along ``T' - tx``) and a point-like one (a corner at ``(tx + T') / 2`` or a point at
   ``p``). A turn on the spot cannot tell them apart; a second stop can: a wall's
   hypotheses from two stops lie on one line, a corner's or edge's at one position. A group
   takes the kind that stays consistent with groups from more other stops (both kinds on a
   tie: the fit and association of step 3 decide);
3. groups of one kind are clustered greedily (most pairs first) into landmarks; each
   landmark is fitted to all its echo pairs by iteratively reweighted Gauss-Newton with a
   Cauchy loss (:meth:`~fusion_center.mapping.smoothing.LeastSquaresPathMapSmoother.fit_alone`),
   every group is re-associated with the landmark whose predicted echoes explain it best
   (gated per pair), landmarks on the same line or spot are merged
   (:func:`~fusion_center.mapping.smoothing.merge_duplicates`), and this is repeated;
4. optionally the path is refined: every stop (a run of acquisitions between drives) gets
   one rigid correction ``(dx, dy, dyaw)`` about its centre, fitted to its echoes against the
   current landmarks with a Gaussian prior of the path's expected error (alternated with
   step 3; the first stop is held: it defines the frame);
5. the landmarks with enough pairs from at least two stops become a
   :class:`~fusion_center.mapping.features.SlamMap`
   (:func:`~fusion_center.mapping.features.build_map`); a corner heard from stops spread
   over more than a corner's quadrant is mapped as a point at its point fit when that model
   fits it and left out otherwise, and a corner heard by a small fraction of the looks from
   the stops that could hear it, or next to a better-supported corner, is left out
   (``corner_span``, ``corner_point_cost``, ``corner_rate``, ``corner_separation``;
   :meth:`_FixedPathMapper.corner_evidence`).

Steps 3 and 4 minimise, over the landmark states :math:`\ell_k` (and, with the
refinement, the stop corrections :math:`c_s = (\delta x, \delta y, \delta\psi)`, stop 0
held), the Cauchy cost of the echo pairs :math:`z_i = (r_1, r_2)` associated with landmark
:math:`k(i)` at pose :math:`p_i` of stop :math:`s(i)`, plus the path prior:

.. math::

   J = \sum_i \sum_{j=1,2} \tfrac{1}{2} c^2 \log\Bigl(1 + \frac{e_{ij}^2}{c^2}\Bigr)
       + \tfrac{1}{2} \sum_{s \ge 1} c_s^\top \Sigma^{-1} c_s,
   \qquad e_{ij} = \frac{z_{ij} - h_j(\ell_{k(i)}, p_i \oplus c_{s(i)})}{\sigma_r},

with :math:`h` the Fig. 19 range model of the landmark's kind, :math:`c` = ``loss_scale``,
:math:`\sigma_r` = ``range_sigma`` and :math:`\Sigma = \mathrm{diag}(\sigma_{xy}^2,
\sigma_{xy}^2, \sigma_\psi^2)` from ``path_sigma``; :math:`p \oplus c` rotates the
transmitter by :math:`\delta\psi` about the stop's mean transmitter position and shifts it by
:math:`(\delta x, \delta y)`. Without the refinement the poses are fixed and :math:`J`
separates per landmark. A point-like landmark is a corner or a point by the lower :math:`J`
of the two models when they differ by more than ``kind_margin``.

The clustering by cross-stop consistency and the per-stop rigid refinement go beyond the
chapter (a batch relative of its Section 6 mapping; the refinement is a block-coordinate
bundle adjustment, cf. Triggs et al. 2000, "Bundle adjustment - a modern synthesis").
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt
from scipy.spatial import cKDTree

from fusion_center.mapping.features import LandmarkSet, SlamMap, build_map
from fusion_center.mapping.models import (
    CORNER,
    POINT,
    WALL,
    invert_image,
    invert_point,
    rotate,
    wall_tangent,
)
from fusion_center.mapping.smoothing import (
    LeastSquaresPathMapSmoother,
    SmootherConfig,
    _wrap,
    merge_duplicates,
)

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]


@dataclass(frozen=True, slots=True, kw_only=True)
class FixedPathConfig:
    """Parameters of :func:`map_fixed_path` (SI units: m, rad).

    Attributes
    ----------
    range_sigma : float
        Standard deviation of one bistatic range in the fit, m.
    loss_scale : float
        Residual, in ``range_sigma``, beyond which the Cauchy loss discounts an echo.
    min_group_pairs : int
        Pairs an echo group needs to found or join a landmark hypothesis (the mapper's
        ``MapperConfig.confirm``; 1 uses every pair, e.g. for coarse turning steps).
    wall_gate, wall_angle : float
        Two groups' wall hypotheses are consistent when each one's foot point lies within
        ``wall_gate`` of the other's line and their normals are within ``wall_angle``.
    point_gate : float
        Two groups' point-like hypotheses are consistent within this distance.
    assoc_gate : float
        A pair is explained by a landmark only if both its ranges are within this of the
        landmark's predicted echoes, m.
    assoc_gate_start : float
        The gate of the first round; it shrinks geometrically to ``assoc_gate`` in the last
        (a wider first gate lets the path refinement pull in stops that are further off).
    fov : float
        Half-angle around the boresight within which a landmark echoes.
    min_pairs, min_stops : int
        Support a landmark needs to be mapped: associated pairs, and distinct stops.
    rounds : int
        Association and fit rounds.
    drive_distance : float
        A step of the path longer than this starts a new stop, m.
    merge_dist, merge_angle, merge_point_dist : float
        Between rounds, walls within ``merge_dist`` and ``merge_angle`` and point-like
        landmarks within ``merge_point_dist`` are merged.
    refine_path : bool
        Fit one rigid correction per stop (step 4 of the module docstring).
    path_sigma : tuple of float
        Prior standard deviation of a stop's correction: (m per axis, rad).
    extent_quantile : float
        A wall's extent spans these quantiles of its specular points.
    wall_gap : float
        Specular points of one wall further apart than this along it split it into segments
        (``inf``: one segment), m; the map's walls on one line merge only across such gaps
        (:func:`~fusion_center.mapping.features.build_map`'s ``merge_gap``). It must exceed
        the spacing of the stops, whose feet on a wall are its only specular points: 2.5 m
        found more faces with fewer ghosts on room_pillar (stops 0.5-1 m apart) but split
        every wall of corridor_L_sparse into unsupported pieces, so it is off by default;
        ``uwbnet map`` sets it from the stop path's spacing (``map_cmd.stop_wall_gap``).
    min_wall_length : float
        Shortest wall segment mapped (between its extent quantiles), m: a corner's echoes
        seen from stops in line with it also fit a short wall through it.
    overlap_dist, overlap_angle, extend : float
        :func:`~fusion_center.mapping.features.build_map`'s merging of overlapping walls and
        longest wall extension.
    drop_crossed : bool
        Leave out the mapped walls that the path drives through (a segment between the
        transmitter's positions at two consecutive stops crosses the wall, 5 cm in from its
        ends): a real wall is never crossed, and the ghost walls that cross the room (from
        echoes of several landmarks that happen to fit one line) mostly are (negative
        information; beyond the chapter). Off: on room_pillar it halves the ghost walls
        (17 -> 9-12 at the true path) but also drops real faces (10-11 -> 7-8 found),
        whose walls were extended or merged across the room.
    keep_ties : bool
        A group whose wall and point-like hypotheses are confirmed by as many other stops
        keeps both (the fit and association decide) instead of going to the wall. A corner
        seen only from stops in line with it (parallax under ``wall_angle``) confirms a wall
        through it just as well; given to the wall it is then dropped as too short, and the
        corner is lost. Off: along the stop graph's path on room_pillar it made the corners
        worse (seed 0: 7 at 0.114 m -> 9 at 0.191 m mean; seed 1: 8 at 0.167 m -> 9 at
        0.195 m) and seed 1's walls (0.100 -> 0.120 m mean); at the true path it was mixed
        (seed 0: objects 7 -> 6; seed 1: faces 10 -> 11, ghost walls 17 -> 14).
    kind_margin : float
        A point-like landmark becomes a corner or a point only when that model's Cauchy cost
        (half a robust chi-square over its echoes) is lower by more than this; otherwise it
        keeps its kind, which starts as a corner (the hypotheses' label): undecided means the
        two models put the landmark at the same spot within the range noise, so the label
        carries no information either way. Far from the stops the two models differ by less
        than the range noise, and a raw comparison labelled 1 in 6 wrong at 4 m (synthetic,
        three stops). 1 (a chi-square difference of 2): no wrong decision at 1.5-4 m in that
        probe, with points at 2.5 m undecided in 4 of 6 seeds; 15 of 67 and 10 of 61 mapped
        point-like landmarks undecided on room_pillar seeds 0 and 1 at the true path.
    corner_span : float
        Largest angle, about a corner landmark, that its hearing stops may span, rad
        (:meth:`_FixedPathMapper.corner_evidence`: only stops with a few of its pairs count,
        and a stop near the landmark by at most ``corner_position_error`` of swing). A
        concave, right-angled corner returns its double reflection (Fig. 19) only into the
        quadrant between its two walls; a landmark heard from stops spread over more is a
        convex edge or a scatterer heard from around it. It is mapped as a point (at the
        point model's fit) when that model explains it (``corner_point_cost``), and left out
        otherwise (``inf``: off). Along the stop graph's path on room_pillar seeds 0 and 1
        the corners within 10 cm of a true one spanned 26-60 degrees, the convex edges and
        the pillar's multipath up to 222. The test assumes right-angled corners: a corner of
        a room with 135-degree corners is heard over up to 135 degrees.
    corner_rate : float
        Smallest hearing rate of a mapped corner (0: off): the fraction of the acquisitions,
        at the stops that could hear it, that heard it (:meth:`_FixedPathMapper.
        corner_evidence`: stops within its pair-weighted ``corner_reach_quantile`` hearing
        distance and within the arc of its hearing stops, at least a quadrant wide, widened by
        ``corner_sector_margin``). A concave corner is a retro-reflector, heard from every
        stop in its quadrant within range; a multipath image heard from a few stops in
        special positions is not. On room_pillar seeds 0 and 1 (stop graph's path) the
        corners within 10 cm of a true one had 0.033-0.103, the ghosts more than 0.5 m from
        every true corner and edge 0.004-0.017, the convex edges 0.003-0.042
        (docs/mapping.md, "Ghost corners").
    corner_stop_pairs, corner_stop_share : int, float
        A stop counts as hearing a point-like landmark when it has at least this many of its
        pairs and at least this share of the pairs of the landmark's best stop (one stray
        association sets neither the span nor the hearing distance).
    corner_position_error : float
        Error of a landmark's position allowed for in its span, m: the span is reduced by
        ``2 atan(error / d)`` with ``d`` the nearest hearing stop's distance.
    corner_reach_quantile : float
        Quantile, weighted by pairs, of the hearing stops' distances that bounds the stops
        counted in the hearing rate (in (0, 1]).
    corner_sector_margin : float
        Margin on each side of the hearing stops' arc (at least a quadrant) within which
        stops count in the hearing rate, rad.
    corner_point_cost : float
        A corner heard over more than ``corner_span`` goes into the map as a point only when
        the point model's mean Cauchy cost per pair is at most this (the cost of
        :class:`~fusion_center.mapping.smoothing.LeastSquaresPathMapSmoother`, eq. above,
        per pair of two ranges: about 1 for residuals of ``range_sigma``); otherwise it is
        left out (``inf``: always a point). On the held-out warehouse and L hall the convex
        edges so mapped had 0.65-2.5, room_pillar's pillar multipath 3-7.
    corner_junction : float
        A corner under ``corner_rate`` is kept when it lies within this of a junction of two
        mapped walls (their lines meeting at 60 degrees or more, within ``extend`` of both
        segments): where two walls meet the room has a corner, whatever the rate says, m
        (0: off). The separation rule is applied after.
    corner_separation : float
        Of two corners closer than this, the one with fewer pairs (equal pairs: the lower
        hearing rate; then the higher index) is left out (the same corner fitted twice,
        e.g. from two sides at a path that is a little off), m (0: off).
    fitted_kinds : bool
        Corner or point as fitted (the better Cauchy cost of the two models over all the
        landmark's echoes), not by :func:`~fusion_center.mapping.features.build_map`'s
        geometric rule, which makes an object's convex edge between two of its mapped
        faces a corner.
    """

    range_sigma: float = 0.02
    loss_scale: float = 3.0
    min_group_pairs: int = 3
    wall_gate: float = 0.15
    wall_angle: float = np.radians(5.0)
    point_gate: float = 0.15
    assoc_gate: float = 0.15
    assoc_gate_start: float = 0.15
    fov: float = np.radians(60.0)
    min_pairs: int = 8
    min_stops: int = 2
    rounds: int = 4
    drive_distance: float = 0.1
    merge_dist: float = 0.1
    merge_angle: float = np.radians(5.0)
    merge_point_dist: float = 0.1
    refine_path: bool = False
    path_sigma: tuple[float, float] = (0.05, np.radians(1.0))
    extent_quantile: float = 0.05
    wall_gap: float = np.inf
    min_wall_length: float = 0.2
    overlap_dist: float = 0.3
    overlap_angle: float = np.radians(12.0)
    extend: float = 1.0
    kind_margin: float = 1.0
    corner_span: float = np.radians(110.0)
    corner_rate: float = 0.02
    corner_separation: float = 0.3
    corner_junction: float = 0.0
    corner_stop_pairs: int = 2
    corner_stop_share: float = 0.1
    corner_position_error: float = 0.1
    corner_reach_quantile: float = 0.8
    corner_sector_margin: float = np.radians(20.0)
    corner_point_cost: float = 3.0
    fitted_kinds: bool = True
    drop_crossed: bool = False
    keep_ties: bool = False

    def __post_init__(self) -> None:
        positive = {
            "range_sigma": self.range_sigma,
            "loss_scale": self.loss_scale,
            "wall_gate": self.wall_gate,
            "wall_angle": self.wall_angle,
            "point_gate": self.point_gate,
            "assoc_gate": self.assoc_gate,
            "assoc_gate_start": self.assoc_gate_start,
            "fov": self.fov,
            "drive_distance": self.drive_distance,
        }
        for name, v in positive.items():
            if not (np.isfinite(v) and v > 0.0):
                raise ValueError(f"FixedPathConfig.{name} must be > 0, got {v!r}")
        non_negative = {
            "kind_margin": self.kind_margin,
            "merge_dist": self.merge_dist,
            "merge_angle": self.merge_angle,
            "merge_point_dist": self.merge_point_dist,
            "min_wall_length": self.min_wall_length,
            "overlap_dist": self.overlap_dist,
            "overlap_angle": self.overlap_angle,
            "extend": self.extend,
            "corner_rate": self.corner_rate,
            "corner_separation": self.corner_separation,
            "corner_junction": self.corner_junction,
            "corner_stop_share": self.corner_stop_share,
            "corner_position_error": self.corner_position_error,
            "corner_sector_margin": self.corner_sector_margin,
        }
        for name, v in non_negative.items():
            if not (np.isfinite(v) and v >= 0.0):
                raise ValueError(f"FixedPathConfig.{name} must be finite and >= 0, got {v!r}")
        for name in ("refine_path", "fitted_kinds", "drop_crossed", "keep_ties"):
            v = getattr(self, name)
            if not isinstance(v, bool | np.bool_):
                raise ValueError(f"FixedPathConfig.{name} must be True or False, got {v!r}")
        if self.assoc_gate_start < self.assoc_gate:
            raise ValueError(
                "FixedPathConfig.assoc_gate_start must be >= assoc_gate (the gate shrinks), "
                f"got {self.assoc_gate_start!r} < {self.assoc_gate!r}"
            )
        if not 0.0 < self.corner_reach_quantile <= 1.0:
            raise ValueError(
                "FixedPathConfig.corner_reach_quantile must be in (0, 1], "
                f"got {self.corner_reach_quantile!r}"
            )
        if not self.corner_point_cost >= 0.0:
            raise ValueError(
                f"FixedPathConfig.corner_point_cost must be >= 0, got {self.corner_point_cost!r}"
            )
        if not self.corner_span > 0.0:
            raise ValueError(f"FixedPathConfig.corner_span must be > 0, got {self.corner_span!r}")
        if not self.wall_gap > 0.0:
            raise ValueError(f"FixedPathConfig.wall_gap must be > 0, got {self.wall_gap!r}")
        for name in ("min_group_pairs", "min_pairs", "min_stops", "rounds", "corner_stop_pairs"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int | np.integer) or v < 1:
                raise ValueError(f"FixedPathConfig.{name} must be an integer >= 1, got {v!r}")
        sig = np.atleast_1d(np.asarray(self.path_sigma, float))
        if sig.shape != (2,) or not np.all(np.isfinite(sig) & (sig > 0.0)):
            raise ValueError(
                f"FixedPathConfig.path_sigma must be two values > 0, got {self.path_sigma!r}"
            )
        if not 0.0 <= self.extent_quantile < 0.5:
            raise ValueError(
                f"FixedPathConfig.extent_quantile must be in [0, 0.5), got {self.extent_quantile!r}"
            )


@dataclass(frozen=True, slots=True, kw_only=True)
class FixedPathMap:
    """Result of :func:`map_fixed_path`.

    Attributes
    ----------
    map : SlamMap
        Walls, corners and points, in the frame of the path (m).
    poses : ndarray, shape (n, 3)
        The path the map was built at (the refined one with ``refine_path``), m and rad.
    kinds, states, pairs, stops : ndarray
        Every landmark kept after the last round (before the support rule): kind, state
        (``(alpha, d)`` of a wall, ``(x, y)`` otherwise), associated pairs and distinct stops.
    stop_corrections : ndarray, shape (s, 3)
        Rigid correction of every stop (zeros without ``refine_path``).
    undecided : ndarray of bool
        Which of the landmarks (``kinds``) are point-like with corner and point within
        ``kind_margin`` of each other in the last fit (their kind was kept).
    association : ndarray of int, shape (m,)
        Landmark (index into ``kinds``) of every echo pair, in the order of the pairs
        concatenated over the acquisitions; -1: none (empty when no landmark was formed).
    view_span, hearing_rate : ndarray, shape like ``kinds``
        Of every point-like landmark (NaN for walls): the angle about it spanned by its
        hearing stops, less their position-error swing (rad), and the fraction of the
        acquisitions at the stops that could hear it that heard it
        (:meth:`_FixedPathMapper.corner_evidence`).
    screened : ndarray of bool, shape like ``kinds``
        The corners left out of the map by ``corner_rate``, ``corner_separation``, or by
        ``corner_span`` when the point model does not fit them either (``kinds`` and
        ``states`` are as fitted: a corner the map holds as a point is still a corner there,
        at its corner-model state).
    """

    map: SlamMap
    poses: FloatArray
    kinds: IntArray = field(default_factory=lambda: np.zeros(0, np.int64))
    states: FloatArray = field(default_factory=lambda: np.zeros((0, 2)))
    pairs: IntArray = field(default_factory=lambda: np.zeros(0, np.int64))
    stops: IntArray = field(default_factory=lambda: np.zeros(0, np.int64))
    stop_corrections: FloatArray = field(default_factory=lambda: np.zeros((0, 3)))
    undecided: npt.NDArray[np.bool_] = field(default_factory=lambda: np.zeros(0, bool))
    association: IntArray = field(default_factory=lambda: np.zeros(0, np.int64))
    view_span: FloatArray = field(default_factory=lambda: np.zeros(0))
    hearing_rate: FloatArray = field(default_factory=lambda: np.zeros(0))
    screened: npt.NDArray[np.bool_] = field(default_factory=lambda: np.zeros(0, bool))


def _world_array(poses: FloatArray, antennas: FloatArray) -> tuple[FloatArray, FloatArray]:
    """World tx (n, 2) and rx (n, 2, 2) at robot poses (n, 3)."""
    c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
    rot = np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)
    ant = np.einsum("nij,aj->nai", rot, antennas) + poses[:, None, :2]
    return ant[:, 0], ant[:, 1:]


def _group_mean(x: FloatArray, g: IntArray, n: int, trim: float) -> tuple[FloatArray, IntArray]:
    """Per-group mean of points ``x`` (m, 2) without NaN rows, then again without the points
    farther than ``trim`` from it (a track that switched echoes for a few acquisitions)."""
    ok = np.all(np.isfinite(x), 1)
    mean = np.full((n, 2), np.nan)
    cnt = np.zeros(n, np.int64)
    for _ in range(2):
        cnt = np.bincount(g[ok], minlength=n)
        sums = np.stack([np.bincount(g[ok], x[ok, i], minlength=n) for i in range(2)], -1)
        mean = np.where(cnt[:, None] > 0, sums / np.maximum(cnt, 1)[:, None], np.nan)
        near = np.linalg.norm(x - mean[g], axis=1) <= trim
        ok = ok & np.where(np.isfinite(near), near, False)
    return mean, cnt


def _pair_array(p: npt.ArrayLike, i: int) -> FloatArray:
    """One acquisition's echo pairs as an ``(m, 2)`` float array (an empty entry of any
    shape is ``(0, 2)``); anything else is refused, never reshaped."""
    try:
        a = np.asarray(p, float)
    except (TypeError, ValueError):
        raise ValueError(f"pairs[{i}] must be numeric echo pairs of shape (m, 2)") from None
    if a.size == 0:
        return np.zeros((0, 2))
    if a.ndim != 2 or a.shape[1] != 2:
        raise ValueError(f"pairs[{i}] must have shape (m, 2), got {a.shape}")
    return a


def _symmetric(i: IntArray, j: IntArray, n: int) -> tuple[IntArray, IntArray]:
    """The pairs ``(i, j)`` with ``i < j`` in both orders plus every ``(i, i)``, sorted by
    ``i`` (a neighbour list)."""
    a = np.concatenate([i, j, np.arange(n)])
    b = np.concatenate([j, i, np.arange(n)])
    order = np.lexsort((b, a))
    return a[order], b[order]


def _close_pairs(points: list[FloatArray], gate: float) -> tuple[IntArray, IntArray]:
    """Neighbour list (:func:`_symmetric`) of the items within ``gate`` of each other in any
    one of the given point sets (k-d trees, so memory grows with the pairs found)."""
    n = points[0].shape[0]
    ij = np.concatenate(
        [cKDTree(p).query_pairs(gate, output_type="ndarray") for p in points]
        + [np.zeros((0, 2), np.int64)]
    )
    key = np.unique(ij[:, 0] * n + ij[:, 1])
    return _symmetric(key // n, key % n, n)


def _predict(
    kinds: IntArray, states: FloatArray, tx: FloatArray, rx: FloatArray, fov: float, yaw: FloatArray
) -> tuple[FloatArray, npt.NDArray[np.bool_]]:
    """Predicted ranges (..., 2) of landmarks and whether each can echo (in the beam, a wall
    in front of the transmitter), broadcast over leading axes (Fig. 19 models)."""
    smoother = LeastSquaresPathMapSmoother(np.zeros((3, 2)))
    r, ok, d = smoother._predict(kinds, states, tx, rx)
    bore = np.stack([np.cos(yaw), np.sin(yaw)], -1)
    ok = ok & (np.sum(d * bore, -1) >= np.cos(fov))
    return r, ok


def _junctions(walls: FloatArray, reach: float) -> FloatArray:
    """Intersections (k, 2) of the lines of every two wall segments ``[x1, y1, x2, y2]``
    that meet at 60 degrees or more and whose segments both pass within ``reach`` (m) of the
    intersection."""
    p, q = walls[:, :2], walls[:, 2:]
    length = np.maximum(np.linalg.norm(q - p, axis=1), 1e-12)
    u = (q - p) / length[:, None]
    i, j = np.triu_indices(len(walls), 1)
    den = u[i, 0] * u[j, 1] - u[i, 1] * u[j, 0]
    ok = np.abs(den) >= np.sin(np.radians(60.0))
    i, j, den = i[ok], j[ok], den[ok]
    dp = p[j] - p[i]
    t = (dp[:, 0] * u[j, 1] - dp[:, 1] * u[j, 0]) / den
    x = p[i] + t[:, None] * u[i]

    def off(k: IntArray) -> FloatArray:
        # distance of x from segment k
        along = np.clip(np.sum((x - p[k]) * u[k], 1), 0.0, length[k])
        return np.linalg.norm(p[k] + along[:, None] * u[k] - x, axis=1)

    return x[(off(i) <= reach) & (off(j) <= reach)]


def _arc(phi: FloatArray) -> tuple[float, float]:
    """The smallest arc holding the directions ``phi`` (rad): its start (counter-clockwise
    from there) and its width, ``2 pi`` minus the largest gap between sorted directions."""
    a = np.sort(np.mod(phi, 2.0 * np.pi))
    gaps = np.diff(np.r_[a, a[0] + 2.0 * np.pi])
    i = int(np.argmax(gaps))
    return float(a[(i + 1) % a.size]), float(2.0 * np.pi - gaps[i])


def map_fixed_path(
    pairs: list[npt.ArrayLike],
    groups: list[npt.ArrayLike] | None,
    path: npt.ArrayLike,
    antennas: npt.ArrayLike,
    config: FixedPathConfig | None = None,
) -> FixedPathMap:
    """Walls, corners and points from a robot's echo pairs at known poses (module docstring).

    Parameters
    ----------
    pairs : list of array_like, shape (m_i, 2)
        Echo pairs ``(r1, r2)`` of every acquisition, m (the mapper's front end:
        :class:`~fusion_center.mapping.echoes.EnvelopePeakEchoExtractor`,
        :func:`~fusion_center.mapping.echoes.pair_echoes`).
    groups : list of array_like of int, shape (m_i,), optional
        Echo-group id of every pair (:class:`~fusion_center.mapping.grouping.KalmanEchoGrouper`);
        ids need only be unique within a stop (a group never spans a drive);
        ``None``: every pair is its own group, which needs ``min_group_pairs=1`` (with the
        default 3 no group can found a landmark and the map is empty).
    path : array_like, shape (n, 3)
        ``[x, y, yaw]`` of every acquisition (m, rad), any fixed frame (usually the first
        pose's); the map comes out in it.
    antennas : array_like, shape (3, 2)
        tx, rx1, rx2 in the robot frame (x forward, y left), m.
    config : FixedPathConfig, optional

    Returns
    -------
    FixedPathMap
        Empty (no walls, corners or points) when no group's hypothesis is confirmed from
        another stop: always for a path of one stop, whatever ``min_stops``.

    Raises
    ------
    ValueError
        Shapes that do not match, non-finite values or a degenerate array (one line).
    """
    cfg = config or FixedPathConfig()
    try:
        poses = np.asarray(path, float)
    except (TypeError, ValueError):
        raise ValueError("path must be a numeric array of shape (n, 3)") from None
    if poses.ndim != 2 or poses.shape[1] != 3 or poses.shape[0] == 0:
        raise ValueError(f"path must have shape (n, 3) with n >= 1, got {poses.shape}")
    if not np.all(np.isfinite(poses)):
        raise ValueError("path holds non-finite values")
    ant = np.asarray(antennas, float)
    if ant.shape != (3, 2) or not np.all(np.isfinite(ant)):
        raise ValueError(
            f"antennas must be finite tx, rx1, rx2 positions, shape (3, 2), got {ant.shape}"
        )
    if np.linalg.norm(ant[1] - ant[2]) < 1e-6:
        raise ValueError("antennas: the two receivers coincide")
    n = poses.shape[0]
    if pairs is None or isinstance(pairs, str) or not hasattr(pairs, "__len__"):
        raise ValueError("pairs must be a list with one (m_i, 2) array per pose")
    if groups is not None and (isinstance(groups, str) or not hasattr(groups, "__len__")):
        raise ValueError("groups must be None or a list with one (m_i,) array per pose")
    if len(pairs) != n:
        raise ValueError(f"pairs must have one entry per pose ({n}), got {len(pairs)}")
    if groups is not None and len(groups) != n:
        raise ValueError(f"groups must have one entry per pose ({n}), got {len(groups)}")
    zs = [_pair_array(p, i) for i, p in enumerate(pairs)]
    z = np.concatenate([*zs, np.zeros((0, 2))])
    if not np.all(np.isfinite(z)):
        raise ValueError("pairs hold non-finite ranges")
    acq = np.repeat(np.arange(n), [x.shape[0] for x in zs])
    if groups is None:
        gid = np.arange(z.shape[0])
    else:
        gs = [np.asarray(g).reshape(-1) for g in groups]
        if any(g.size != x.shape[0] for g, x in zip(gs, zs, strict=True)):
            raise ValueError("groups must have one id per pair")
        try:
            g_all = np.concatenate([*gs, np.zeros(0)]).astype(float)
        except (TypeError, ValueError):
            raise ValueError("groups must hold integer ids") from None
        if not np.all(np.isfinite(g_all)) or np.any(g_all != np.round(g_all)):
            raise ValueError("groups must hold finite integer ids")
    step = np.r_[0.0, np.hypot(*np.diff(poses[:, :2], axis=0).T)]
    stop_of = np.cumsum(step > cfg.drive_distance).astype(np.int64)
    if groups is not None:
        # a group is one track within one stop: keyed by (stop, id), so ids that restart at
        # every stop (a new grouper per stop) do not merge the groups of different stops
        key = np.column_stack([stop_of[acq], g_all.astype(np.int64)])
        gid = np.unique(key, axis=0, return_inverse=True)[1].reshape(-1)
    empty = FixedPathMap(
        map=SlamMap(), poses=poses.copy(), stop_corrections=np.zeros((stop_of[-1] + 1, 3))
    )
    if z.shape[0] == 0:
        return empty
    mapper = _FixedPathMapper(cfg, ant, poses, z, acq, gid, stop_of)
    return mapper.run()


class _FixedPathMapper:
    """The state of one :func:`map_fixed_path` run."""

    def __init__(
        self,
        cfg: FixedPathConfig,
        ant: FloatArray,
        poses: FloatArray,
        z: FloatArray,
        acq: IntArray,
        gid: IntArray,
        stop_of: IntArray,
    ) -> None:
        self.cfg = cfg
        self.ant = ant
        self.path0 = poses
        self.poses = poses.copy()
        self.z, self.acq, self.gid = z, acq, gid
        self.n_groups = int(gid.max()) + 1
        self.stop_of = stop_of
        self.n_stops = int(stop_of[-1]) + 1
        self.pair_stop = stop_of[acq]
        self.corr = np.zeros((self.n_stops, 3))
        self.undecided = np.zeros(0, bool)
        self.fitter = LeastSquaresPathMapSmoother(
            ant, SmootherConfig(range_sigma=cfg.range_sigma, loss_scale=cfg.loss_scale)
        )
        self.rx_body = ant[1:] - ant[0]
        # the rotation centre of a stop's correction: its mean transmitter position
        self.centre = self.stop_centres(poses)

    def stop_centres(self, poses: FloatArray) -> FloatArray:
        """Mean transmitter position (s, 2) of every stop at the given poses, m."""
        tx, _ = _world_array(poses, self.ant)
        cnt = np.bincount(self.stop_of, minlength=self.n_stops)
        return np.stack(
            [np.bincount(self.stop_of, tx[:, i], minlength=self.n_stops) / cnt for i in range(2)],
            -1,
        )

    # --- hypotheses ---------------------------------------------------------------------------

    def hypotheses(self) -> tuple[IntArray, FloatArray, IntArray]:
        """Kinds, initial states and group support of the landmarks found by cross-stop
        consistency of the groups' hypotheses (steps 1-3 of the module docstring)."""
        cfg = self.cfg
        tx, _ = _world_array(self.poses, self.ant)
        yaw = self.poses[self.acq, 2]
        tx_p = tx[self.acq]
        img = tx_p + rotate(invert_image(self.z, self.rx_body), yaw)
        pt = tx_p + rotate(invert_point(self.z, self.rx_body), yaw)
        g = self.gid
        ng = self.n_groups
        img_g, cnt = _group_mean(img, g, ng, 2 * cfg.point_gate)
        pt_g, _ = _group_mean(pt, g, ng, 2 * cfg.point_gate)
        tx_g, _ = _group_mean(tx_p, g, ng, np.inf)
        stop_g = np.zeros(ng, np.int64)
        stop_g[g] = self.pair_stop  # a group lies within one stop (keyed by stop and id)
        use = (cnt >= cfg.min_group_pairs) & np.all(np.isfinite(img_g), 1)
        use &= np.all(np.isfinite(pt_g), 1)
        idx = np.flatnonzero(use)
        if idx.size == 0:
            return np.zeros(0, np.int64), np.zeros((0, 2)), np.zeros(0, np.int64)
        foot = 0.5 * (tx_g[idx] + img_g[idx])  # wall's foot point, also the corner
        v = img_g[idx] - tx_g[idx]
        nrm = v / np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-9)
        pnt = pt_g[idx]
        st = stop_g[idx]
        wall_nb = self._wall_neighbours(foot, nrm)
        point_nb = _close_pairs([foot, pnt], cfg.point_gate)
        w_sup = self._other_stops(wall_nb, st)
        p_sup = self._other_stops(point_nb, st)
        # a group takes the kind more other stops confirm; a tie goes to the wall, or with
        # ``keep_ties`` keeps both kinds (see the config)
        is_wall = (w_sup >= p_sup) & (w_sup > 0)
        is_pt = ((p_sup >= w_sup) if cfg.keep_ties else (p_sup > w_sup)) & (p_sup > 0)
        size = cnt[idx].astype(float)
        lab_w, lab_p, kinds = self._greedy(size, is_wall, is_pt, wall_nb, point_nb)
        nl = kinds.size
        # every cluster's state: the pair-weighted mean of its members' hypotheses
        on_w, on_p = lab_w >= 0, lab_p >= 0
        lw, ww = lab_w[on_w], size[on_w]
        lp, wp = lab_p[on_p], size[on_p]

        def mean(lab: IntArray, w: FloatArray, x: FloatArray) -> FloatArray:
            tot = np.maximum(np.bincount(lab, w, minlength=nl), 1e-300)
            return (
                np.stack([np.bincount(lab, w * x[:, k], minlength=nl) for k in range(2)], -1)
                / (tot[:, None])
            )

        nn = mean(lw, ww, nrm[on_w])
        alpha = np.arctan2(nn[:, 1], nn[:, 0])
        along = np.stack([np.cos(alpha), np.sin(alpha)], -1)[lw]
        d = mean(lw, ww, np.sum(foot[on_w] * along, 1)[:, None].repeat(2, 1))[:, 0]
        states = np.where(
            (kinds == WALL)[:, None],
            np.column_stack([alpha, d]),
            mean(lp, wp, 0.5 * (foot + pnt)[on_p]),
        )
        support = np.bincount(lw, minlength=nl) + np.bincount(lp, minlength=nl)
        return kinds, states, support.astype(np.int64)

    def _wall_neighbours(self, foot: FloatArray, nrm: FloatArray) -> tuple[IntArray, IntArray]:
        """Every ordered pair ``(i, j)`` (itself included) of groups whose wall hypotheses
        agree: normals within ``wall_angle`` and each foot point within ``wall_gate`` of the
        other's line. Candidates come from a k-d tree on ``(n_x, n_y, s d)`` (``d`` the line's
        offset from the feet's centroid) in the max norm, with ``s`` chosen so that every
        agreeing pair is a candidate: ``|n_i - n_j| <= c = 2 sin(wall_angle / 2)`` and
        ``|d_i - d_j| <= wall_gate + c R`` (``R`` the largest foot distance from the
        centroid); the exact test then runs on the candidates only."""
        cfg = self.cfg
        f = foot - foot.mean(0)
        c = 2.0 * np.sin(0.5 * cfg.wall_angle)
        radius = float(np.max(np.linalg.norm(f, axis=1)))
        d = np.sum(nrm * f, 1)
        scale = c / (cfg.wall_gate + c * radius)
        tree = cKDTree(np.column_stack([nrm, scale * d]))
        ij = tree.query_pairs(c * (1.0 + 1e-9), p=np.inf, output_type="ndarray")
        i, j = ij[:, 0], ij[:, 1]
        ok = np.sum(nrm[i] * nrm[j], 1) >= np.cos(cfg.wall_angle)
        ok &= np.abs(np.sum(nrm[i] * (f[j] - f[i]), 1)) <= cfg.wall_gate
        ok &= np.abs(np.sum(nrm[j] * (f[i] - f[j]), 1)) <= cfg.wall_gate
        return _symmetric(i[ok], j[ok], foot.shape[0])

    def _other_stops(self, nb: tuple[IntArray, IntArray], st: IntArray) -> IntArray:
        """How many stops other than its own hold a neighbour of every group."""
        i, j = nb
        other = st[i] != st[j]
        ns = int(st.max()) + 1
        key = np.unique(i[other] * ns + st[j[other]])  # one per (group, other stop)
        return np.bincount(key // ns, minlength=st.size)

    @staticmethod
    def _greedy(
        size: FloatArray,
        is_wall: npt.NDArray[np.bool_],
        is_pt: npt.NDArray[np.bool_],
        wall_nb: tuple[IntArray, IntArray],
        point_nb: tuple[IntArray, IntArray],
    ) -> tuple[IntArray, IntArray, IntArray]:
        """Wall cluster and point-like cluster of every group (-1: none) and the kind of
        every cluster, greedily, most pairs first: each seed takes the free groups of its
        kind that agree with it (of any stop); a group of both kinds (a tie) seeds or joins
        one cluster of each. The loop runs once per cluster, over the seed's neighbours."""
        ptr = [(np.searchsorted(i, np.arange(size.size + 1)), j) for i, j in (wall_nb, point_nb)]
        labels = [np.full(size.size, -1), np.full(size.size, -1)]
        free = [is_wall.copy(), is_pt.copy()]
        kinds: list[int] = []
        for s in np.argsort(-size):
            for kind in (0, 1):
                if not free[kind][s]:
                    continue
                start, nbr = ptr[kind]
                cand = nbr[start[s] : start[s + 1]]
                members = cand[free[kind][cand]]
                labels[kind][members] = len(kinds)
                labels[kind][s] = len(kinds)
                free[kind][members] = False
                free[kind][s] = False
                kinds.append(WALL if kind == 0 else CORNER)
        return labels[0], labels[1], np.array(kinds, np.int64)

    # --- association and fit ------------------------------------------------------------------

    def associate(self, kinds: IntArray, states: FloatArray, gate: float) -> IntArray:
        """Landmark of every pair (-1: none), whole echo groups at once: each group goes to
        the landmark whose predicted echoes explain its pairs best (clipped squared
        residuals, each range gated at ``gate``, m)."""
        cfg = self.cfg
        m = self.z.shape[0]
        nl = kinds.size
        if nl == 0:
            return np.full(m, -1)
        tx, rx = _world_array(self.poses, self.ant)
        gate2 = (gate / cfg.range_sigma) ** 2
        cost = np.empty((m, nl))
        for a in range(0, m, 1024):
            b = min(a + 1024, m)
            ac = self.acq[a:b]
            r, ok = _predict(
                kinds[None, :],
                states[None, :, :],
                tx[ac, None, :],
                rx[ac, None, :, :],
                cfg.fov,
                self.poses[ac, 2][:, None],
            )
            res = np.abs(self.z[a:b, None, :] - r) / cfg.range_sigma
            inside = ok & np.all(res**2 <= gate2, -1)
            cost[a:b] = np.where(inside, np.minimum(np.sum(res**2, -1), 2 * gate2), np.inf)
        clipped = np.minimum(cost, 2 * gate2)
        group_cost = np.zeros((self.n_groups, nl))
        np.add.at(group_cost, self.gid, clipped)
        best = np.argmin(group_cost, 1)
        lm = best[self.gid]
        # a group no landmark explains better than clutter stays out
        none = group_cost[np.arange(self.n_groups), best] >= 2 * gate2 * np.bincount(
            self.gid, minlength=self.n_groups
        )
        lm = np.where(np.isfinite(cost[np.arange(m), lm]) & ~none[self.gid], lm, -1)
        return lm

    def fit(self, kinds: IntArray, states: FloatArray, lm: IntArray) -> tuple[IntArray, FloatArray]:
        """Fit every landmark to its pairs at the current poses; a point-like landmark
        becomes a corner or a point when that model's Cauchy cost is lower by more than
        ``kind_margin`` (a likelihood-ratio test: the cost is half a robust chi-square),
        and keeps its kind otherwise (``self.undecided``)."""
        cfg = self.cfg
        tx, rx = _world_array(self.poses, self.ant)
        used = lm >= 0
        li, z, ac = lm[used], self.z[used], self.acq[used]
        self.undecided = np.zeros(kinds.size, bool)
        states = states.copy()
        kinds = kinds.copy()
        self.point_states = states.copy()
        self.point_cost = np.full(kinds.size, np.nan)
        self.corner_cost = np.full(kinds.size, np.nan)
        for kind in (WALL, CORNER):
            sel = (kinds == WALL) if kind == WALL else (kinds != WALL)
            idx = np.flatnonzero(sel)
            if idx.size == 0:
                continue
            local = np.full(kinds.size, -1)
            local[idx] = np.arange(idx.size)
            on = sel[li]
            lml = local[li[on]]
            if kind == WALL:
                st, _ = self.fitter.fit_alone(WALL, states[idx], lml, z[on], tx[ac[on]], rx[ac[on]])
                states[idx] = st
                continue
            st_c, c_c = self.fitter.fit_alone(
                CORNER, states[idx], lml, z[on], tx[ac[on]], rx[ac[on]]
            )
            st_p, c_p = self.fitter.fit_alone(
                POINT, states[idx], lml, z[on], tx[ac[on]], rx[ac[on]]
            )
            # a model wins only by kind_margin; otherwise the landmark keeps its kind
            # (hysteresis: no flip between rounds on noise), a corner from the hypotheses
            gain = c_p - c_c
            undecided = np.abs(gain) <= cfg.kind_margin
            corner = np.where(undecided, kinds[idx] == CORNER, gain > 0.0)
            states[idx] = np.where(corner[:, None], st_c, st_p)
            # kept for the map: a corner heard from all around goes in as the point fit
            self.point_states[idx] = st_p
            self.point_cost[idx] = c_p
            self.corner_cost[idx] = c_c
            kinds[idx] = np.where(corner, CORNER, POINT)
            self.undecided = np.zeros(kinds.size, bool)
            self.undecided[idx] = undecided
        return kinds, states

    def support(self, n_lm: int, lm: IntArray) -> tuple[IntArray, IntArray]:
        """Associated pairs and distinct stops of every landmark."""
        used = lm >= 0
        pairs = np.bincount(lm[used], minlength=n_lm)
        if not np.any(used):
            return pairs, np.zeros(n_lm, np.int64)
        key = np.unique(np.column_stack([lm[used], self.pair_stop[used]]), axis=0)
        return pairs, np.bincount(key[:, 0], minlength=n_lm)

    # --- path refinement ----------------------------------------------------------------------

    def corrected_poses(self, corr: FloatArray) -> FloatArray:
        """The given path with every stop's rigid correction about its centre."""
        p = self.path0
        c = corr[self.stop_of]
        ctr = self.centre[self.stop_of]
        # the transmitter rotates about the stop's centre; the robot origin moves with it
        tx, _ = _world_array(p, self.ant)
        new_tx = ctr + rotate(tx - ctr, c[:, 2]) + c[:, :2]
        yaw = p[:, 2] + c[:, 2]
        origin = new_tx - rotate(np.broadcast_to(self.ant[0], (p.shape[0], 2)), yaw)
        return np.column_stack([origin, yaw])

    def refine(
        self, kinds: IntArray, states: FloatArray, lm: IntArray, iterations: int = 6
    ) -> FloatArray:
        """Joint Gauss-Newton over every stop's rigid correction and every landmark (bundle
        adjustment at the associations ``lm``): Cauchy-weighted echoes (iteratively
        reweighted), a Gaussian prior ``path_sigma`` on the corrections, the first stop
        held. The normal equations are dense (3 per stop + 2 per landmark: a few hundred
        unknowns); the Jacobian comes from central differences, vectorised over all pairs
        (a pair depends on one stop and one landmark only). Returns the landmark states;
        the corrections and poses are updated in place."""
        cfg = self.cfg
        used = lm >= 0
        li, z, ac = lm[used], self.z[used], self.acq[used]
        m = z.shape[0]
        if m == 0:
            return states
        stp = self.stop_of[ac]
        ns, nl = self.n_stops, kinds.size
        n_pose = 3 * (ns - 1)
        n_all = n_pose + 2 * nl
        prior = 1.0 / np.array([cfg.path_sigma[0], cfg.path_sigma[0], cfg.path_sigma[1]]) ** 2
        c2 = cfg.loss_scale**2
        h = np.array([1e-4, 1e-4, 1e-5])
        # unknowns touched by each pair: its stop's 3 (a dummy past the end for the first
        # stop, which is held) and its landmark's 2
        cols = np.empty((m, 5), np.int64)
        cols[:, :3] = np.where(stp[:, None] > 0, 3 * (stp[:, None] - 1) + np.arange(3), n_all)
        cols[:, 3:] = n_pose + 2 * li[:, None] + np.arange(2)
        st = states.copy()

        def ranges(corr: FloatArray, st_: FloatArray) -> FloatArray:
            p = self.corrected_poses(corr)[ac]
            tx, rx = _world_array(p, self.ant)
            r, _ = _predict(kinds[li], st_[li], tx, rx, np.pi, p[:, 2])
            return r

        for _ in range(iterations):
            r0 = ranges(self.corr, st)
            res = (z - r0) / cfg.range_sigma  # (m, 2)
            w = 1.0 / (1.0 + res**2 / c2)
            jac = np.zeros((m, 2, 5))
            for j in range(3):
                d = np.zeros(3)
                d[j] = h[j]
                jac[:, :, j] = (ranges(self.corr + d, st) - ranges(self.corr - d, st)) / (2 * h[j])
            for j in range(2):
                d = np.zeros(2)
                d[j] = 1e-5
                jac[:, :, 3 + j] = (ranges(self.corr, st + d) - ranges(self.corr, st - d)) / 2e-5
            jac /= cfg.range_sigma
            big = np.zeros((n_all + 1, n_all + 1))
            grad = np.zeros(n_all + 1)
            np.add.at(
                big,
                (cols[:, :, None], cols[:, None, :]),
                np.einsum("mj,mjk,mjl->mkl", w, jac, jac),
            )
            np.add.at(grad, cols, np.einsum("mj,mjk,mj->mk", w, jac, res))
            big, grad = big[:n_all, :n_all], grad[:n_all]
            free = self.corr[1:].reshape(-1)
            big[np.arange(n_pose), np.arange(n_pose)] += np.tile(prior, ns - 1)
            grad[:n_pose] -= np.tile(prior, ns - 1) * free
            # a landmark seen from one pose only is not determined along its echo's circle:
            # a little damping keeps the system regular
            diag = np.arange(n_pose, n_all)
            big[diag, diag] += 1e-3 * big[diag, diag] + 1e-6
            delta = np.linalg.solve(big, grad)
            self.corr[1:] += delta[:n_pose].reshape(-1, 3)
            step = delta[n_pose:].reshape(-1, 2)
            # a landmark step of more than 0.3 m (or rad) is a poor linearisation
            norm = np.linalg.norm(step, axis=1, keepdims=True)
            st += step * np.minimum(1.0, 0.3 / np.maximum(norm, 1e-12))
        self.poses = self.corrected_poses(self.corr)
        return st

    # --- the run ------------------------------------------------------------------------------

    def empty(self) -> FixedPathMap:
        """The map without landmarks (no group was consistent across stops)."""
        return FixedPathMap(
            map=SlamMap(), poses=self.out_poses(), stop_corrections=self.corr.copy()
        )

    def out_poses(self) -> FloatArray:
        """The path with yaw wrapped to [-pi, pi) (the refinement adds to the given yaw)."""
        p = self.poses.copy()
        p[:, 2] = _wrap(p[:, 2])
        return p

    def run(self) -> FixedPathMap:
        cfg = self.cfg
        kinds, states, _ = self.hypotheses()
        if kinds.size == 0:
            # echoes, but no hypothesis another stop confirms (one stop, or groups too small)
            return self.empty()
        lm = np.full(self.z.shape[0], -1)
        ratio = cfg.assoc_gate / cfg.assoc_gate_start
        for rnd in range(cfg.rounds):
            if kinds.size == 0:
                break
            gate = cfg.assoc_gate_start * ratio ** (rnd / max(cfg.rounds - 1, 1))
            lm = self.associate(kinds, states, gate)
            kinds, states = self.fit(kinds, states, lm)
            if cfg.refine_path and self.n_stops > 1:
                # only landmarks that would be mapped pull the stops (a ghost seen from one
                # stop explains clutter, and at the wrong pose it holds a stop there)
                pairs, stops = self.support(kinds.size, lm)
                strong = (pairs >= cfg.min_pairs) & (stops >= cfg.min_stops)
                states = self.refine(kinds, states, np.where(strong[np.maximum(lm, 0)], lm, -1))
            if rnd + 1 < cfg.rounds:
                pairs, _ = self.support(kinds.size, lm)
                keep = pairs > 0
                kinds, states = kinds[keep], states[keep]
                kinds, states = merge_duplicates(
                    kinds,
                    states,
                    pairs[keep],
                    wall_dist=cfg.merge_dist,
                    wall_angle=cfg.merge_angle,
                    point_dist=cfg.merge_point_dist,
                )
        if kinds.size == 0:
            return self.empty()
        lm = self.associate(kinds, states, cfg.assoc_gate)
        kinds, states = self.fit(kinds, states, lm)
        pairs, stops = self.support(kinds.size, lm)
        span, rate = self.corner_evidence(kinds, states, lm)
        # the map's kinds only: ``kinds`` stay as fitted (the stop bundle adjustment refits
        # the landmarks with their fitted models)
        map_kinds, map_states, drop, low = self.screen_corners(
            kinds, states, pairs, stops, span, rate
        )
        mapped = (pairs >= cfg.min_pairs) & (stops >= cfg.min_stops) & (map_kinds == CORNER)
        screened = drop | low | self.separate(mapped & ~low, map_states, pairs, rate)

        def build(keep_point: npt.NDArray[np.bool_]) -> SlamMap:
            return build_map(
                self.landmark_set(map_kinds, map_states, lm, pairs, stops, keep_point),
                merge_gap=cfg.wall_gap,
                overlap_dist=cfg.overlap_dist,
                overlap_angle=cfg.overlap_angle,
                extend=cfg.extend,
                fitted_kinds=cfg.fitted_kinds,
            )

        the_map = build(~screened)
        if cfg.corner_junction > 0.0 and np.any(screened) and len(the_map.walls) >= 2:
            # a corner left out for its rate comes back where two mapped walls meet, and the
            # separation rule is applied again (a corner that comes back may be a duplicate)
            x = _junctions(the_map.walls, cfg.extend)
            if len(x) and np.any(low):
                near = np.linalg.norm(map_states[:, None] - x[None], axis=-1).min(1)
                back = low & (near <= cfg.corner_junction)
                if np.any(back):
                    low &= ~back
                    screened = drop | low | self.separate(mapped & ~low, map_states, pairs, rate)
                    the_map = build(~screened)
        if cfg.drop_crossed and len(the_map.walls) and self.n_stops > 1:
            keep = ~self.crossed(the_map.walls)
            the_map = SlamMap(
                walls=the_map.walls[keep], corners=the_map.corners, points=the_map.points
            )
        return FixedPathMap(
            map=the_map,
            poses=self.out_poses(),
            kinds=kinds,
            # a wall's alpha wrapped to [-pi, pi), as the smoother's
            states=np.where(
                (kinds == WALL)[:, None],
                np.column_stack([_wrap(states[:, 0]), states[:, 1]]),
                states,
            ),
            pairs=pairs.astype(np.int64),
            stops=stops.astype(np.int64),
            stop_corrections=self.corr.copy(),
            undecided=self.undecided.copy(),
            association=lm.astype(np.int64),
            view_span=span,
            hearing_rate=rate,
            screened=screened,
        )

    def corner_evidence(
        self, kinds: IntArray, states: FloatArray, lm: IntArray
    ) -> tuple[FloatArray, FloatArray]:
        r"""View span and hearing rate of every point-like landmark (NaN for walls).

        Only the stops that heard the landmark in earnest count: the *hearing stops*
        :math:`H_k`, those with at least ``corner_stop_pairs`` of its pairs and at least
        ``corner_stop_share`` of its best stop's (one stray association from a far stop
        says nothing about where the landmark is heard from). With :math:`c_s` a stop's mean
        transmitter position, :math:`d_s = \lVert c_s - \ell_k \rVert` and
        :math:`\phi_s` the direction of :math:`c_s - \ell_k`:

        .. math::

            \mathrm{span}_k = 2\pi - \max \mathrm{gap}\{\phi_s : s \in H_k,
            d_s \ge d_\mathrm{near}\}, \qquad
            \mathrm{rate}_k = \frac{\sum_{s \in D_k} a_{ks}}{\sum_{s \in D_k} A_s},

        rad, where :math:`d_\mathrm{near}` is ``corner_near`` (from a stop next to the
        landmark a small error in its position swings the direction: those stops are left out
        of the span; NaN when no hearing stop is farther), :math:`a_{ks}` the acquisitions of
        stop :math:`s` with a pair of the landmark, :math:`A_s` the stop's acquisitions, and
        :math:`D_k` the stops that could hear it: no farther than the pair-weighted
        ``corner_reach_quantile`` quantile of :math:`d_s` over :math:`H_k`, and within the
        smallest arc of directions holding :math:`\{\phi_s : s \in H_k\}`, widened by
        ``corner_sector_margin`` on each side (the other leg of an L-shaped room, or the
        far side of a hall, cannot hear the corner and would dilute the rate).

        Beyond the chapter: the chapter's double-reflection model (Fig. 19) says where a
        corner's echo comes from, not who hears it; the view-span test is its visibility
        region (a retro-reflector within its two walls' quadrant), the rate a detection
        frequency test in the spirit of a track's existence score (Mullane et al., Random
        finite sets for robot mapping and SLAM, 2011, detection probability per view).
        """
        cfg = self.cfg
        n, n_s = kinds.size, self.n_stops
        span = np.full(n, np.nan)
        rate = np.full(n, np.nan)
        used = lm >= 0
        cand = np.flatnonzero(kinds != WALL)
        if cand.size == 0 or not np.any(used):
            return span, rate
        ctr = self.stop_centres(self.poses)
        acq_per_stop = np.bincount(self.stop_of, minlength=n_s)
        cnt = np.bincount(lm[used] * n_s + self.pair_stop[used], minlength=n * n_s).reshape(n, n_s)
        # acquisitions, not pairs: two pairs of one look are one hearing
        la = np.unique(np.column_stack([lm[used], self.acq[used]]), axis=0)
        heard_acq = np.bincount(la[:, 0] * n_s + self.stop_of[la[:, 1]], minlength=n * n_s).reshape(
            n, n_s
        )
        need = np.maximum(cfg.corner_stop_pairs, cfg.corner_stop_share * cnt.max(1))
        for k in cand:  # a loop over the point-like landmarks (a few dozen)
            s = np.flatnonzero(cnt[k] >= need[k])
            if s.size == 0:
                continue
            v = ctr - states[k]
            dist = np.linalg.norm(v, axis=1)
            phi = np.arctan2(v[:, 1], v[:, 0])
            start, width = _arc(phi[s])
            # a small error in the landmark's position swings the direction to a near stop:
            # the span is measured as if that stop's direction were off by the most it can be
            span[k] = max(width - 2.0 * np.arctan(cfg.corner_position_error / dist[s].min()), 0.0)
            # the corner's quadrant at least: a ghost heard along one line of sight gets no
            # narrower sector than a corner
            half = max(width, 0.5 * np.pi) / 2.0 + cfg.corner_sector_margin
            in_sector = np.abs(_wrap(phi - start - width / 2.0)) <= half
            order = np.argsort(dist[s])
            w = np.cumsum(cnt[k, s[order]]) / cnt[k, s].sum()
            reach = dist[s[order]][np.searchsorted(w, cfg.corner_reach_quantile - 1e-12)]
            d = in_sector & (dist <= reach + 1e-9)
            rate[k] = heard_acq[k, d].sum() / acq_per_stop[d].sum()
        return span, rate

    def screen_corners(
        self,
        kinds: IntArray,
        states: FloatArray,
        pairs: IntArray,
        stops: IntArray,
        span: FloatArray,
        rate: FloatArray,
    ) -> tuple[IntArray, FloatArray, npt.NDArray[np.bool_], npt.NDArray[np.bool_]]:
        """The map's kinds and states, and which corners to leave out.

        A corner heard over more than ``corner_span`` (:meth:`corner_evidence`) is a convex
        edge or a scatterer heard from around it: it goes into the map as a point, at its
        point-model fit (Fig. 19's single reflection), when that model explains its pairs
        (mean Cauchy cost per pair at most ``corner_point_cost``), and is left out
        otherwise (the third output). A corner with a hearing rate under ``corner_rate`` is
        left out (the fourth); :meth:`separate` then leaves out the weaker of two close
        corners."""
        cfg = self.cfg
        kinds = kinds.copy()
        states = states.copy()
        wide = (kinds == CORNER) & (span > cfg.corner_span)
        per_pair = self.point_cost / np.maximum(pairs, 1)
        as_point = wide & (per_pair <= cfg.corner_point_cost)
        kinds[wide] = POINT
        states[as_point] = self.point_states[as_point]
        mapped = (pairs >= cfg.min_pairs) & (stops >= cfg.min_stops)
        dropped = mapped & wide & ~as_point
        low = mapped & (kinds == CORNER) & (rate < cfg.corner_rate)
        return kinds, states, dropped, low

    def separate(
        self,
        corner: npt.NDArray[np.bool_],
        states: FloatArray,
        pairs: IntArray,
        rate: FloatArray,
    ) -> npt.NDArray[np.bool_]:
        """Which of the ``corner`` landmarks lie within ``corner_separation`` of a better
        one: the corners are taken by pairs, most first, ties by hearing rate, highest
        first, then by index; each is left out if a corner taken before it is that close
        (the same corner fitted twice)."""
        out = np.zeros(corner.size, bool)
        if not self.cfg.corner_separation > 0.0:
            return out
        idx = np.flatnonzero(corner)
        kept: list[int] = []
        for k in idx[np.lexsort((-np.nan_to_num(rate[idx]), -pairs[idx]))]:
            if kept and np.linalg.norm(states[kept] - states[k], axis=1).min() < (
                self.cfg.corner_separation
            ):
                out[k] = True
            else:
                kept.append(int(k))
        return out

    def crossed(self, walls: FloatArray) -> npt.NDArray[np.bool_]:
        """Which wall segments ``[x1, y1, x2, y2]`` (w, 4) a drive between consecutive stops
        crosses (the transmitter's mean positions; the walls shortened by 5 cm at each end)."""
        ctr = self.stop_centres(self.poses)
        a, b = ctr[:-1], ctr[1:]  # drives (d, 2)
        p, q = walls[:, :2], walls[:, 2:]
        e = q - p
        length = np.maximum(np.linalg.norm(e, axis=1, keepdims=True), 1e-9)
        shrink = np.minimum(0.05, 0.5 * length) * e / length
        p, q = p + shrink, q - shrink

        def side(o: FloatArray, u: FloatArray, v: FloatArray) -> FloatArray:
            # sign of the cross product (u - o) x (v - o), broadcast (w, d)
            return (u[..., 0] - o[..., 0]) * (v[..., 1] - o[..., 1]) - (u[..., 1] - o[..., 1]) * (
                v[..., 0] - o[..., 0]
            )

        pw, qw = p[:, None, :], q[:, None, :]
        ad, bd = a[None, :, :], b[None, :, :]
        cross = (side(pw, qw, ad) * side(pw, qw, bd) < 0) & (
            side(ad, bd, pw) * side(ad, bd, qw) < 0
        )
        return np.any(cross, axis=1)

    def landmark_set(
        self,
        kinds: IntArray,
        states: FloatArray,
        lm: IntArray,
        pairs: IntArray,
        stops: IntArray,
        keep_point: npt.NDArray[np.bool_] | None = None,
    ) -> LandmarkSet:
        """The landmarks with enough support. A wall's specular points (the feet of the
        transmitter's perpendiculars at its pairs' poses) are split where consecutive ones
        along the line are more than ``wall_gap`` apart: each run is a wall segment of its
        own (two collinear faces, or a face and echoes far along its line that another
        landmark made), with its own support; its extent spans the ``extent_quantile``
        quantiles of its specular points. ``keep_point`` (optional) leaves out the point-like
        landmarks where it is False."""
        cfg = self.cfg
        ok = (pairs >= cfg.min_pairs) & (stops >= cfg.min_stops)
        wall_st = np.zeros((0, 2))
        wall_ext = np.zeros((0, 2))
        wall_hits = np.zeros(0)
        on = (lm >= 0) & (kinds[np.maximum(lm, 0)] == WALL) & ok[np.maximum(lm, 0)]
        if np.any(on):
            tx, _ = _world_array(self.poses[self.acq[on]], self.ant)
            li = lm[on]
            stop = self.pair_stop[on]
            w = states[li]
            nrm = np.stack([np.cos(w[:, 0]), np.sin(w[:, 0])], -1)
            foot = tx + (w[:, 1] - np.sum(nrm * tx, -1))[:, None] * nrm
            t = wall_tangent(w, foot)
            order = np.lexsort((t, li))
            li, t, stop = li[order], t[order], stop[order]
            new_seg = np.r_[True, (np.diff(li) != 0) | (np.diff(t) > cfg.wall_gap)]
            seg = np.cumsum(new_seg) - 1
            ns = int(seg[-1]) + 1
            start = np.flatnonzero(new_seg)
            count = np.bincount(seg, minlength=ns)
            seg_stops = np.bincount(
                np.unique(np.column_stack([seg, stop]), axis=0)[:, 0], minlength=ns
            )
            q = cfg.extent_quantile
            lo = start + np.floor(q * (count - 1)).astype(int)
            hi = start + np.ceil((1.0 - q) * (count - 1)).astype(int)
            keep = (count >= cfg.min_pairs) & (seg_stops >= cfg.min_stops)
            keep &= t[hi] - t[lo] >= cfg.min_wall_length
            wall_st = states[li[start[keep]]]
            wall_ext = np.column_stack([t[lo[keep]], t[hi[keep]]])
            wall_hits = count[keep].astype(float)
        pt = ok & (kinds != WALL)
        if keep_point is not None:
            pt &= keep_point
        return LandmarkSet(
            walls=wall_st,
            wall_extent=wall_ext,
            wall_hits=wall_hits,
            points=states[pt],
            point_is_corner=kinds[pt] == CORNER,
            point_hits=pairs[pt].astype(float),
        )
