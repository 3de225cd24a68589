"""Map features from the landmarks of the best particle: walls with extent, corners, edges.

The filter keeps wall, corner and point hypotheses for each landmark; the echo model tells a
wall from a point-like landmark once the robot has driven (the specular point moves along a
wall), but a corner (double reflection, ``T' = 2c - tx``) and a point scatterer differ only by
``|a|^2 / 4 d`` in range (``a`` half the baseline, ``d`` the distance: about 2 cm at 3 m for
the 1 m array). Corner and edge are therefore classified from the map geometry as well: a
point-like landmark where two mapped walls meet at an angle (within ``tol`` of both lines)
is a corner, any other is a point (edge, small object), and a wall is extended along its line
to the corners and wall junctions next to its observed ends. This geometric step goes beyond
the chapter's likelihood-only classification; it is documented in docs/mapping.md.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from fusion_center.mapping.models import wall_segment, wall_tangent

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True, slots=True, kw_only=True)
class LandmarkSet:
    """Confirmed landmarks of one particle.

    Attributes
    ----------
    walls : ndarray, shape (w, 2)
        ``(alpha, d)`` of the landmarks classified as walls.
    wall_extent : ndarray, shape (w, 2)
        Observed tangential extent ``(t_min, t_max)``, m.
    wall_hits : ndarray, shape (w,)
    points : ndarray, shape (k, 2)
        Positions of point-like landmarks (corner or point hypothesis, the likelier), m.
    point_is_corner : ndarray, bool, shape (k,)
        The echo likelihood's vote (corner over point).
    point_hits : ndarray, shape (k,)
    """

    walls: FloatArray
    wall_extent: FloatArray
    wall_hits: FloatArray
    points: FloatArray
    point_is_corner: npt.NDArray[np.bool_]
    point_hits: FloatArray


@dataclass(frozen=True, slots=True, kw_only=True)
class SlamMap:
    """The map of the best particle, in the frame of the robot's first pose.

    Attributes
    ----------
    walls : ndarray, shape (w, 4)
        Segments ``[x1, y1, x2, y2]``, m.
    corners, points : ndarray, shape (k, 2)
        Positions, m.
    end_walls : ndarray of int, shape (e,)
        Indices into ``walls`` of corridor end walls heard from one stop
        (:func:`corridor_end_walls`); :func:`close_outline` may extend the side walls to
        them farther (``end_reach``).
    """

    walls: FloatArray = field(default_factory=lambda: np.zeros((0, 4)))
    corners: FloatArray = field(default_factory=lambda: np.zeros((0, 2)))
    points: FloatArray = field(default_factory=lambda: np.zeros((0, 2)))
    end_walls: npt.NDArray[np.intp] = field(default_factory=lambda: np.zeros(0, np.intp))


def _normal(alpha: FloatArray) -> FloatArray:
    return np.stack([np.cos(alpha), np.sin(alpha)], -1)


def merge_walls(
    walls: FloatArray,
    extent: FloatArray,
    hits: FloatArray,
    *,
    dist: float,
    angle: float,
    overlap_dist: float = 0.0,
    overlap_angle: float = 0.0,
    max_gap: float = np.inf,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Merge walls on the same line (normals within ``angle``, offsets within ``dist``), and
    overlapping walls on nearly the same line (within ``overlap_angle`` and
    ``overlap_dist``, their extents overlapping along the line: one face seen from poses a
    little apart).

    Walls on the same line merge only where the gap between their extents along it is at
    most ``max_gap`` (m; ``inf``: whatever the gap): two faces on one line with a doorway
    or another object between them stay two.

    Merged lines are the hit-weighted mean of the walls on the same line (the overlapping
    copies add their extent and hits, not their line: the best supported wall's line
    stands); extents are the union.
    """
    order = np.argsort(-hits)
    used = np.zeros(len(walls), bool)
    out_w, out_e, out_h = [], [], []
    n = _normal(walls[:, 0]) if len(walls) else np.zeros((0, 2))
    tang_all = np.stack([-n[:, 1], n[:, 0]], -1)
    ends = np.stack(
        [
            walls[:, 1:2] * n + extent[:, :1] * tang_all,
            walls[:, 1:2] * n + extent[:, 1:] * tang_all,
        ],
        1,
    )  # (w, 2, 2) end points
    for i in order:
        if used[i]:
            continue
        cos_ij = n @ n[i]
        t = ends @ tang_all[i]  # (w, 2) end points along wall i
        s = ends @ n[i] - walls[i, 1]  # (w, 2) their signed distances from its line
        # on the same line: wall j's end points within ``dist`` of wall i's line (the
        # offsets' difference is that distance only for parallel lines; at an angle it grows
        # with the distance from the map origin, so the map's frame decided merges)
        same = (~used) & (cos_ij >= np.cos(angle)) & (np.abs(s).max(1) <= dist)
        if np.isfinite(max_gap):
            gap_along = np.maximum(t.min(1) - extent[i, 1], extent[i, 0] - t.max(1))
            same &= gap_along <= max_gap
        # a wall is always on its own line: at dist = 0 rounding put its own ends off it
        # (an empty group, then NaN lines)
        same[i] = True
        near = same.copy()
        if overlap_dist > 0.0:
            # Wall j's distance from wall i's line where the two overlap along it
            lo = np.maximum(t.min(1), extent[i, 0])
            hi = np.minimum(t.max(1), extent[i, 1])
            overlap = hi > lo
            span = t[:, 1] - t[:, 0]
            slope = np.divide(s[:, 1] - s[:, 0], span, out=np.zeros(len(t)), where=span != 0.0)
            gap = np.maximum(
                np.abs(s[:, 0] + (lo - t[:, 0]) * slope), np.abs(s[:, 0] + (hi - t[:, 0]) * slope)
            )
            same |= (~used) & (cos_ij >= np.cos(overlap_angle)) & (gap <= overlap_dist) & overlap
        used |= same
        # the line is the mean of the walls on the same line only: an overlapping copy a
        # little apart is a duplicate placed from a pose that was off, and averaging it in
        # moved the merged face (room_pillar seed 1, smoothed: faces 0.141 -> 0.128 m mean)
        w = hits[near] / hits[near].sum()
        nn = w @ n[near]
        a = np.arctan2(nn[1], nn[0])
        d = float(w @ walls[near, 1])
        # extents re-expressed along the merged line's tangent
        feet = walls[same, 1:2] * n[same]
        tang = np.stack([-n[same, 1], n[same, 0]], -1)
        lo = feet + extent[same, :1] * tang
        hi = feet + extent[same, 1:] * tang
        ts = wall_tangent(np.array([a, d]), np.vstack([lo, hi]))
        out_w.append([a, d])
        out_e.append([ts.min(), ts.max()])
        out_h.append(hits[same].sum())
    return np.array(out_w).reshape(-1, 2), np.array(out_e).reshape(-1, 2), np.array(out_h)


def build_map(
    lm: LandmarkSet,
    *,
    tol: float = 0.2,
    extend: float = 2.0,
    merge_dist: float = 0.1,
    merge_angle: float = np.radians(6.0),
    overlap_dist: float = 0.0,
    overlap_angle: float = 0.0,
    fitted_kinds: bool = False,
    merge_gap: float = np.inf,
) -> SlamMap:
    """Walls (segments), corners and points from a particle's landmarks.

    Parameters
    ----------
    lm : LandmarkSet
    tol : float
        Distance of a point-like landmark from two wall lines for it to be their corner, m.
    extend : float
        Longest extension of a wall end to a corner or wall junction on its line, m.
    merge_dist, merge_angle : float
        Walls closer than this (m, rad) are one wall.
    overlap_dist, overlap_angle : float
        Overlapping walls closer than this (m, rad) are one wall (0: off).
    merge_gap : float
        Walls on one line merge only across gaps up to this along it, m (``merge_walls``'s
        ``max_gap``).
    fitted_kinds : bool
        Take corner or point from ``lm.point_is_corner`` for every point-like landmark, not
        from the walls around it: for landmarks whose kind was fitted to echoes from several
        stops (:mod:`fusion_center.mapping.fixed_path`), where the geometric rule made the
        convex edges of objects, at the junction of two of their mapped faces, corners.

    Returns
    -------
    SlamMap
    """
    walls, extent, _ = merge_walls(
        lm.walls,
        lm.wall_extent,
        lm.wall_hits,
        dist=merge_dist,
        angle=merge_angle,
        overlap_dist=overlap_dist,
        overlap_angle=overlap_angle,
        max_gap=merge_gap,
    )
    n = _normal(walls[:, 0]) if len(walls) else np.zeros((0, 2))
    pts = lm.points
    # distance of every point-like landmark from every wall line, and its tangent coordinate
    if len(walls) and len(pts):
        off = np.abs(pts @ n.T - walls[:, 1][None, :])  # (k, w)
        tang = pts @ np.stack([-n[:, 1], n[:, 0]], -1).T  # (k, w)
    else:
        off = np.full((len(pts), len(walls)), np.inf)
        tang = np.zeros((len(pts), len(walls)))
    near = off <= tol
    corner = np.zeros(len(pts), bool)
    for k in range(0 if fitted_kinds else len(pts)):
        idx = np.flatnonzero(near[k])
        if idx.size >= 2:
            cosines = np.abs(n[idx] @ n[idx].T)
            corner[k] = bool(np.any(cosines < np.cos(np.radians(45.0))))
        elif idx.size == 0:
            corner[k] = False
        else:
            corner[k] = bool(lm.point_is_corner[k])
    if fitted_kinds:
        corner = np.asarray(lm.point_is_corner, bool).copy()
    # extend wall ends to corners on their line, then to junctions with other walls
    ext = extent.copy()
    for w in range(len(walls)):
        ends = [tang[k, w] for k in np.flatnonzero(corner & near[:, w])]
        for v in range(len(walls)):
            cross = n[w, 0] * n[v, 1] - n[w, 1] * n[v, 0]
            if v == w or abs(cross) < np.sin(np.radians(45.0)):
                continue
            x = np.linalg.solve(np.array([n[w], n[v]]), np.array([walls[w, 1], walls[v, 1]]))
            t_w = wall_tangent(walls[w], x)
            t_v = wall_tangent(walls[v], x)
            if ext[v, 0] - extend <= t_v <= ext[v, 1] + extend:
                ends.append(float(t_w))
        for t in ends:
            if ext[w, 0] - extend <= t < ext[w, 0]:
                ext[w, 0] = t
            elif ext[w, 1] < t <= ext[w, 1] + extend:
                ext[w, 1] = t
    segs = wall_segment(walls, ext[:, 0], ext[:, 1]) if len(walls) else np.zeros((0, 4))
    return SlamMap(walls=segs, corners=pts[corner], points=pts[~corner])


def corridor_end_walls(
    walls: npt.ArrayLike,
    reflection: npt.ArrayLike,
    observer: npt.ArrayLike,
    *,
    max_angle: float = np.radians(20.0),
    tolerance: float = 0.3,
    across_corridor: bool = True,
) -> FloatArray:
    """End walls of corridors from landmarks heard from one stop only.

    From one position a wall and a corner (or a point) give the same echoes: the image of
    the transmitter is fixed while the robot turns on the spot (Fig. 19 of the CoLOR chapter:
    a wall's image ``2 f - tx`` with ``f`` the foot of the perpendicular, a corner's
    ``2 c - tx``), so a landmark heard from one stop is a reflection point ``f`` whose kind
    the echoes cannot tell. Between two mapped near-parallel walls (a corridor) it is taken
    for the corridor's END WALL through ``f``, perpendicular to the corridor (the side walls'
    mean direction; ``across_corridor`` False: to its bearing from the stop). Both corners
    of a corridor's end lie on the end line as well as the end wall's foot, but only the
    foot's bearing is the end's normal: a corner heard 3.3 m or more down a 2.4 m corridor is
    within 20 degrees of its axis, and the line perpendicular to its bearing was an end wall
    turned by up to 20 degrees (corridor_L_sparse with drive starts, seed 6: a wall matching
    no face). It is taken when:

    * two mapped walls run within ``max_angle`` of the bearing and of each other, the stop
      lies between their lines and ``f`` too (on the stop's side of each);
    * neither side wall is mapped more than ``tolerance`` past the end line (a wall there
      would have hidden them; an object in the corridor is no end wall);
    * no mapped wall crosses the line of sight from the stop to ``f``;
    * a corner there would need walls through ``f`` across the corridor, and none is mapped
      (no mapped wall within ``tolerance`` of ``f``, which also skips an end already mapped).

    The end wall spans the gap between the two side lines; of several candidates in one
    corridor and direction the nearest along the corridor stands (the smallest ``f . t``,
    ``t`` the side wall's tangent pointing that way, whichever stop heard it: a longer echo
    down a corridor is a multipath image beyond its end). Beyond the chapter (a geometric
    rule on the map, as :func:`build_map`'s classification of corners; docs/mapping.md
    "Corridor end walls").

    Parameters
    ----------
    walls : array_like, shape (w, 4)
        Mapped segments ``[x1, y1, x2, y2]``, m.
    reflection : array_like, shape (k, 2)
        Reflection points of the single-stop landmarks (a wall's foot of the perpendicular
        from the stop, a corner's or point's position), m, the walls' frame.
    observer : array_like, shape (k, 2)
        The stop each was heard from, m.
    max_angle : float
        Largest angle between the bearing and a side wall, and between the side walls, rad.
    tolerance : float
        Side walls may run this far past the end line, and a mapped wall this close to the
        reflection point makes it no new end wall, m.
    across_corridor : bool
        The end line is perpendicular to the corridor's axis (else to the bearing).

    Returns
    -------
    ndarray, shape (e, 4)
        The end walls' segments, m.
    """
    w = np.asarray(walls, float).reshape(-1, 4)
    f = np.asarray(reflection, float).reshape(-1, 2)
    o = np.asarray(observer, float).reshape(-1, 2)
    if f.shape != o.shape:
        raise ValueError("corridor_end_walls: reflection and observer need one row each")
    if not (0.0 < max_angle < np.pi / 2) or not tolerance >= 0.0:
        raise ValueError("corridor_end_walls: max_angle or tolerance out of range")
    ok = np.isfinite(f).all(1) & np.isfinite(o).all(1)
    f, o = f[ok], o[ok]
    if len(w) < 2 or len(f) == 0:
        return np.zeros((0, 4))
    p, q = w[:, :2], w[:, 2:]
    length = np.maximum(np.linalg.norm(q - p, axis=1), 1e-12)
    u = (q - p) / length[:, None]
    nrm = np.stack([-u[:, 1], u[:, 0]], -1)
    best: dict[tuple[int, int, int], tuple[float, FloatArray]] = {}
    cos_max = np.cos(max_angle)
    for k in range(len(f)):  # a handful of single-stop landmarks
        dist = float(np.linalg.norm(f[k] - o[k]))
        if dist < 1e-6:
            continue
        b = (f[k] - o[k]) / dist
        side_o = np.sum((o[k] - p) * nrm, 1)
        side_f = np.sum((f[k] - p) * nrm, 1)
        along = np.abs(u @ b) >= cos_max
        # the reflection point on the stop's side of the wall (not beyond it)
        cand = np.flatnonzero(along & (side_o * side_f > 0.0))
        if cand.size < 2:
            continue
        if np.any(_point_segment_distance(f[k][None], p, q) < tolerance):
            continue
        if np.any(_segments_cross(o[k][None], f[k][None], p, q)):
            continue
        # the nearest wall on each side of the stop (the corridor's sides)
        toward = nrm[cand] * np.sign(side_o[cand])[:, None]  # normal towards the stop
        left = cand[toward @ np.array([-b[1], b[0]]) < 0.0]
        right = cand[toward @ np.array([-b[1], b[0]]) > 0.0]
        if left.size == 0 or right.size == 0:
            continue
        i = int(left[np.argmin(np.abs(side_o[left]))])
        j = int(right[np.argmin(np.abs(side_o[right]))])
        if abs(float(u[i] @ u[j])) < cos_max:
            continue
        # the end line's normal: the bearing, or the corridor's axis (the side walls' mean
        # direction, pointing down the corridor like the bearing)
        e = b
        if across_corridor:
            axis = u[i] + np.sign(float(u[i] @ u[j])) * u[j]
            e = axis / np.linalg.norm(axis) * np.sign(float(axis @ b))
        # end points: the end line (through f, normal e) meets the two side lines
        ends = []
        for s in (i, j):
            den = float(u[s] @ e)
            ends.append(p[s] + (float((f[k] - p[s]) @ e) / den) * u[s])
        # neither side wall mapped past the end line
        reach_past = np.sum((np.vstack([p[[i, j]], q[[i, j]]]) - f[k]) * e, 1)
        if np.any(reach_past > tolerance):
            continue
        # one end per corridor and direction (the direction against a fixed side's tangent):
        # the nearest along that direction, wherever the stop that heard it stood
        sign = int(np.sign(float(u[min(i, j)] @ b)))
        key = (min(i, j), max(i, j), sign)
        along_k = sign * float(u[min(i, j)] @ f[k])
        if key not in best or along_k < best[key][0]:
            best[key] = (along_k, np.r_[ends[0], ends[1]])
    return np.array([v[1] for v in best.values()], float).reshape(-1, 4)


def _cross2(a: FloatArray, b: FloatArray) -> FloatArray:
    """z component of the 2-D cross product ``a x b`` (broadcast over leading axes)."""
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def _segments_cross(p: FloatArray, q: FloatArray, a: FloatArray, b: FloatArray) -> FloatArray:
    """Whether segments ``p-q`` properly cross segments ``a-b`` (broadcast, ``[..., 2]``)."""
    return (_cross2(q - p, a - p) * _cross2(q - p, b - p) < 0) & (
        _cross2(b - a, p - a) * _cross2(b - a, q - a) < 0
    )


def _point_segment_distance(x: FloatArray, p: FloatArray, q: FloatArray) -> FloatArray:
    """Distance of points ``x`` from segments ``p-q`` (broadcast, ``[..., 2]``)."""
    e = q - p
    ee = np.maximum(np.sum(e * e, -1), 1e-12)
    t = np.clip(np.sum((x - p) * e, -1) / ee, 0.0, 1.0)
    return np.linalg.norm(p + t[..., None] * e - x, axis=-1)


def _near_pairs(
    points: FloatArray, centres: FloatArray, radii: FloatArray
) -> tuple[npt.NDArray[np.intp], npt.NDArray[np.intp]]:
    """Index pairs ``(centre, point)`` with the point within ``radii[centre]`` of the centre
    (k-d tree, scipy.spatial.cKDTree): the tests below then cost the pairs in range, not
    centres x points."""
    from scipy.spatial import cKDTree

    if len(points) == 0 or len(centres) == 0:
        return np.zeros(0, np.intp), np.zeros(0, np.intp)
    found = cKDTree(points).query_ball_point(centres, radii, return_sorted=False)
    counts = np.fromiter((len(f) for f in found), np.intp, len(found))
    flat = np.fromiter((k for f in found for k in f), np.intp, int(counts.sum()))
    return np.repeat(np.arange(len(centres)), counts), flat


def _distinct_positions(xy: FloatArray, cell: float = 0.02) -> FloatArray:
    """One robot position per ``cell`` (m) square: a stop's turn on the spot is one position.
    The first pose of each cell is kept (not the cell's centre), so distances stay exact."""
    _, first = np.unique(np.floor(xy / cell).astype(np.int64), axis=0, return_index=True)
    return xy[np.sort(first)]


def free_side(
    walls: FloatArray, path: FloatArray, body: float = 0.2
) -> tuple[FloatArray, npt.NDArray[np.intp]]:
    """Unit normals of wall segments pointing to the side the robot saw them from, and the
    pose it saw each from.

    A wall's echo comes from the foot of the perpendicular from the array (the specular
    point, Fig. 19 of the CoLOR chapter), so the poses that saw it project onto its extent;
    the nearest of those, farther than ``body`` from its line, is taken as the observer and
    gives the side. Poses beyond the wall's ends (a robot passing its end on the way through a
    doorway) and poses on its line (within the robot's body of it) do not vote. A wall no pose
    projects onto takes the nearest pose off its line.

    Parameters
    ----------
    walls : ndarray, shape (w, 4)
        Segments ``[x1, y1, x2, y2]``, m.
    path : ndarray, shape (k, 2)
        Robot positions, m, the walls' frame.
    body : float
        Poses closer than this to a wall's line (m; the robot's radius) do not decide its
        side.

    Returns
    -------
    normals : ndarray, shape (w, 2)
        Unit normals towards the observer; a zero row where no pose is off the wall's line
        (side undecided).
    observer : ndarray of int, shape (w,)
        Index into ``path`` of each wall's observer (0 where undecided).
    """
    p, q = walls[:, :2], walls[:, 2:]
    length = np.maximum(np.linalg.norm(q - p, axis=1), 1e-12)
    u = (q - p) / length[:, None]
    n = np.stack([-u[:, 1], u[:, 0]], -1)
    normals = np.zeros_like(p)
    seen_from = np.zeros(len(walls), np.intp)
    for b in range(0, len(walls), 32):  # blocks of walls: memory 32 x k
        w = slice(b, b + 32)
        rel = path[None, :, :] - p[w, None, :]
        t = np.einsum("wki,wi->wk", rel, u[w])
        s = np.einsum("wki,wi->wk", rel, n[w])
        off = np.abs(s) >= body
        along = off & (t >= 0.0) & (t <= length[w, None])
        dist = np.hypot(np.maximum(np.maximum(-t, t - length[w, None]), 0.0), s)
        key = np.where(along, np.abs(s), np.inf)
        fallback = np.where(off, dist, np.inf)
        obs = np.where(np.isfinite(key.min(1)), key.argmin(1), fallback.argmin(1))
        decided = np.isfinite(fallback.min(1))
        side = np.sign(s[np.arange(len(obs)), obs]) * decided
        normals[w] = n[w] * side[:, None]
        seen_from[w] = np.where(decided, obs, 0)
    return normals, seen_from


def close_outline(
    the_map: SlamMap,
    path: npt.ArrayLike,
    *,
    reach: float = 2.5,
    overshoot: float = 0.3,
    min_angle: float = np.radians(75.0),
    confirm: float = 0.5,
    clearance: float = 0.3,
    witness_range: float = 5.0,
    witness_gap: float = 0.3,
    witness_hide: float = 0.3,
    convex_reach: float = 3.0,
    convex_trim: float = 2.0,
    end_reach: float = 6.0,
) -> SlamMap:
    """Close the outline: extend mapped walls that meet to their intersection (the corner
    the room must have there) and add the concave corners this implies.

    A robot that stops far from a room's corners sees each wall only near the feet of its
    perpendiculars (the specular points), so the mapped extents stop short of the corners.
    Two mapped walls ``i``, ``j`` are closed at the intersection ``X`` of their lines when

    * their lines meet at ``min_angle`` or more (at 60 degrees a ghost face at 71 degrees
      closed with a box's face on room_pillar);
    * ``X`` lies beyond (or at most ``overshoot`` inside) one end of each, at most ``reach``
      beyond it; for a convex corner at most ``convex_reach`` beyond or ``convex_trim``
      inside (see below); for a concave corner with a corridor end wall
      (``the_map.end_walls``) at most ``end_reach`` beyond;
    * each wall approaches ``X`` from the same side of the other as the robot saw that one
      from (:func:`free_side`): both from the free side is a concave (room) corner, both
      from behind a convex one (the inner corner of an L, a pillar's edge); mixed is no
      corner;
    * neither extension crosses the robot's path or another mapped wall, nor passes within
      ``clearance`` of a robot position (the robot drove or stood there);
    * no robot position saw an extension's line at normal incidence and heard nothing
      there: a position (on the free side, within ``witness_range``) whose foot of the
      perpendicular lies on the extension more than ``witness_gap`` past the wall's mapped
      end, with no mapped wall in between or at that foot and no mapped corner or point
      within ``witness_hide`` of its line of sight (an object in front of the wall whose
      face was not mapped: a cabinet's edges), would have received the specular echo
      (Fig. 19) of the wall had it been there, so the gap is an opening (a doorway, the
      space between an object and a wall);
    * no mapped wall lies between ``X`` and the poses the two walls were seen from (two
      multipath ghosts beyond a room wall can meet at right angles).

    A wall of a convex corner that runs past ``X`` runs into the free space the robot saw
    the other wall across, where no wall stands: it is the echo of the corner's edge taken
    for the wall (corridor_L_sparse: the second leg's inner wall mapped 0.6-1.2 m into the
    first leg from the stop facing the edge), so it is trimmed back to ``X`` up to
    ``convex_trim``, keeping at least ``2 overshoot`` of it. A concave corner's wall that
    runs past ``X`` may be a room wall going on past an object's face, so its trim stays at
    ``overshoot``. A trim (``X`` inside a wall, never more than half of it from the nearer
    end) is checked by the geometry alone: the angle, the approach sides, these bounds and
    the line of sight from the poses to ``X`` (the last point below); the path, clearance
    and witness tests look at extensions only, and a trimmed wall has none.

    Each wall end takes at most one closure, the shortest extensions first (those with a
    mapped corner within ``confirm`` of ``X``, the double reflection that confirms it,
    before all others). The ends move to ``X`` (extended, or trimmed where they overshot).
    A concave closure adds ``X`` to the corners unless a mapped corner lies within
    ``confirm``; a convex one adds nothing (an edge, which echoes as a point).

    The robot's positions are first reduced to one per 2 cm square (a stop's turn on the
    spot is one position) and the position tests run on the pairs within range (k-d tree),
    so the cost grows with candidates x positions in range, not x poses.

    Beyond the chapter (geometric post-processing of the map, as :func:`build_map`'s wall
    extension; the negative-evidence test is the free-space reasoning of occupancy mapping,
    Thrun, Burgard and Fox, Probabilistic Robotics, ch. 9); docs/mapping.md "Closing the
    outline".

    Parameters
    ----------
    the_map : SlamMap
        The map to close (walls, corners, points in one frame, m).
    path : array_like, shape (k, 2)
        Robot positions in the map's frame (m), in driving order.
    reach : float
        Largest extension of a wall beyond its mapped end, m (default 2.5).
    overshoot : float
        Largest trim of a wall whose end lies past ``X``, m (default 0.3); walls no longer
        than twice this are not trimmed, and a convex trim leaves at least twice this.
    min_angle : float
        Smallest angle between the two lines, rad (default 75 degrees).
    confirm : float
        A mapped corner within this of ``X`` confirms the closure, m (default 0.5).
    clearance : float
        Smallest distance of an extension from every robot position, m (default 0.3).
    witness_range : float
        Farthest a robot position sees a wall at normal incidence, m (default 5, the
        mapper's bistatic ``max_range`` of 10 m halved).
    witness_gap : float
        Feet of the perpendicular closer than this to the mapped end do not count, m
        (default 0.3: the end of a wall's observed extent is where such feet stop).
    witness_hide : float
        A mapped corner or point this close to a position's line of sight to the foot hides
        the foot from it, m (default 0.3).
    convex_reach : float
        Largest extension to a convex corner, m (default 3.0: the L's inner corner lies 2.4-
        2.5 m beyond the first leg's mapped inner wall on corridor_L_sparse).
    convex_trim : float
        Largest trim of a wall running past a convex corner, m (default 2.0; at most half
        the wall, and ``2 overshoot`` of it stays).
    end_reach : float
        Largest extension of a side wall to a corridor end wall (``the_map.end_walls``,
        :func:`corridor_end_walls`) at a concave corner, m (default 6.0: the end wall is
        heard from one stop at most ``max_range`` / 2 = 5-5.5 m away, and the side walls are
        mapped up to about that stop's feet; corridor_L_sparse: 5.2 m).

    Returns
    -------
    SlamMap
        Walls with moved ends (same order), corners with the implied ones appended, points
        unchanged.

    Raises
    ------
    ValueError
        A parameter out of range, a path or walls not of shape (k, 2) / (w, 4), or
        ``end_walls`` not integer indices of the walls.
    """
    for name, value, ok_ in (
        ("reach", reach, reach > 0.0),
        ("overshoot", overshoot, overshoot >= 0.0),
        ("min_angle", min_angle, 0.0 < min_angle <= np.pi / 2),
        ("confirm", confirm, confirm >= 0.0),
        ("clearance", clearance, clearance >= 0.0),
        ("witness_range", witness_range, witness_range >= 0.0),
        ("witness_gap", witness_gap, witness_gap >= 0.0),
        ("witness_hide", witness_hide, witness_hide >= 0.0),
        ("convex_reach", convex_reach, convex_reach > 0.0),
        ("convex_trim", convex_trim, convex_trim >= 0.0),
        ("end_reach", end_reach, end_reach > 0.0),
    ):
        if not ok_:  # NaN fails too
            raise ValueError(f"close_outline: {name} out of range (got {value})")
    walls = np.asarray(the_map.walls, float)
    xy = np.asarray(path, float)
    if walls.size == 0:
        walls = walls.reshape(0, 4)
    if xy.size == 0:
        xy = xy.reshape(0, 2)
    if walls.ndim != 2 or walls.shape[1] != 4:
        raise ValueError(f"close_outline: walls must be (w, 4) segments, got {walls.shape}")
    if xy.ndim != 2 or xy.shape[1] != 2:
        raise ValueError(f"close_outline: path must be (k, 2) positions, got {xy.shape}")
    ends_idx = np.asarray(the_map.end_walls).reshape(-1)
    if ends_idx.size and (
        not np.issubdtype(ends_idx.dtype, np.integer)
        or ends_idx.min() < 0
        or ends_idx.max() >= len(walls)
    ):
        raise ValueError(
            f"close_outline: end_walls must index the {len(walls)} walls, got {ends_idx.tolist()}"
        )
    xy = xy[np.isfinite(xy).all(1)]
    if len(walls) < 2 or len(xy) == 0:
        return the_map
    # consecutive poses that moved (the path's segments), then one position per 2 cm square
    moving = np.linalg.norm(np.diff(xy, axis=0), axis=1) > 1e-3
    a_path, b_path = xy[:-1][moving], xy[1:][moving]
    xy = _distinct_positions(xy)
    p, q = walls[:, :2], walls[:, 2:]
    length = np.linalg.norm(q - p, axis=1)
    u = (q - p) / np.maximum(length, 1e-12)[:, None]
    nf, seen_from = free_side(walls, xy)
    # intersection X = p_i + a_ij u_i = p_j + a_ji u_j of every pair of lines
    den = _cross2(u[:, None, :], u[None, :, :])  # (w, w), sin of the angle between
    dp = p[None, :, :] - p[:, None, :]  # p_j - p_i
    with np.errstate(divide="ignore", invalid="ignore"):
        a = _cross2(dp, u[None, :, :]) / den  # along wall i
    beyond = np.maximum(a - length[:, None], -a)  # > 0 past an end, < 0 inside
    end = a > 0.5 * length[:, None]  # the end next to X: True = (x2, y2)
    d = np.where(end[..., None], u[:, None, :], -u[:, None, :])  # wall i's way to X
    approach = np.einsum("ijk,jk->ij", d, nf)  # < 0: i comes from j's free side
    concave = (approach < 0) & (approach.T < 0)
    convex = (approach > 0) & (approach.T > 0)
    # a convex corner's walls may reach farther and be trimmed more: past X a wall of a
    # convex corner would stand in the free space the other wall was seen across
    limit = np.where(convex, convex_reach, reach)
    # a confirmed corridor end wall (heard straight down between its side walls) closes
    # with them farther: nothing else could have been heard of the side walls past the stop
    is_end = np.zeros(len(walls), bool)
    is_end[ends_idx] = True
    limit = np.where(concave & (is_end[:, None] | is_end[None, :]), end_reach, limit)
    trim = np.where(convex, convex_trim, overshoot)
    ok = (np.abs(den) >= np.sin(min_angle)) & (beyond <= limit) & (beyond >= -trim)
    # a trim only on walls longer than two overshoots (X inside a wall is at most half its
    # length from the nearer end, so a trim never takes more than half), and a convex trim,
    # up to convex_trim, leaves at least that much of the wall: the echoes heard of the wall
    # are more than the edge's where half a short wall would go
    ok &= (beyond >= 0.0) | (length[:, None] > 2.0 * overshoot)
    ok &= (beyond >= 0.0) | ~convex | (length[:, None] + beyond >= 2.0 * overshoot)
    ok &= ok.T
    ok &= (concave | convex) & np.triu(np.ones_like(ok), 1)
    ok &= (np.abs(nf).sum(1) > 0)[:, None] & (np.abs(nf).sum(1) > 0)[None, :]
    ii, jj = np.nonzero(ok)
    if ii.size == 0:
        return the_map
    x = p[ii] + a[ii, jj][:, None] * u[ii]
    mapped_corners = np.asarray(the_map.corners, float).reshape(-1, 2)
    if len(mapped_corners):
        near_corner = np.linalg.norm(x[:, None] - mapped_corners[None], axis=-1).min(1) <= confirm
    else:
        near_corner = np.zeros(len(x), bool)
    # the extensions (from the wall's end to X; none where X is inside: a trim) must be
    # free; they start 5 cm out, so that a wall that ends on this one's end is not across
    ends_i = np.where(end[ii, jj][:, None], q[ii], p[ii])
    ends_j = np.where(end[jj, ii][:, None], q[jj], p[jj])
    outside = np.r_[beyond[ii, jj], beyond[jj, ii]] > 0.0
    stops = np.vstack([x, x])
    starts = np.where(outside[:, None], np.vstack([ends_i, ends_j]), stops)
    span = stops - starts
    span_len = np.linalg.norm(span, axis=1)
    starts = starts + span * (np.minimum(0.05, span_len) / np.maximum(span_len, 1e-12))[:, None]
    mid, half = 0.5 * (starts + stops), 0.5 * np.linalg.norm(stops - starts, axis=1)
    blocked = np.zeros(len(starts), bool)
    if len(a_path):
        seg_half = 0.5 * np.linalg.norm(b_path - a_path, axis=1).max()
        c, k = _near_pairs(0.5 * (a_path + b_path), mid, half + seg_half + 1e-9)
        np.logical_or.at(blocked, c, _segments_cross(starts[c], stops[c], a_path[k], b_path[k]))
    c, k = _near_pairs(xy, mid, half + clearance)
    np.logical_or.at(blocked, c, _point_segment_distance(xy[k], starts[c], stops[c]) < clearance)
    # another mapped wall across an extension (its own two walls are not: they meet at X)
    pair = np.r_[np.arange(ii.size), np.arange(ii.size)]
    own = np.c_[np.r_[ii, jj], np.r_[jj, ii]]  # (2c, 2): the extended wall, its partner
    through = _segments_cross(starts[:, None], stops[:, None], p[None], q[None])
    through[pair, own[:, 0]] = through[pair, own[:, 1]] = False
    blocked |= through.any(1)
    # X in sight of the poses that saw the two walls: a corner behind another mapped wall
    # is one of two ghosts (multipath images beyond a room wall) meeting
    eyes = xy[np.r_[seen_from[ii], seen_from[jj]]]
    toward = stops - eyes
    # (ending 5 cm short of X: a third wall through X is not in the way)
    short = stops - 0.05 * toward / np.maximum(np.linalg.norm(toward, axis=1), 0.1)[:, None]
    sight = _segments_cross(eyes[:, None], short[:, None], p[None], q[None])
    sight[pair, own[:, 0]] = sight[pair, own[:, 1]] = False
    blocked |= sight.any(1)
    # negative evidence: a position whose specular point on the extension's line lies on the
    # extension (past the mapped end by witness_gap), on the side the wall was seen from and
    # within range, with nothing mapped in between or there, would have echoed the wall
    w_ext = own[:, 0]
    unit = span / np.maximum(span_len, 1e-12)[:, None]
    # (only for the candidates still open: the pairs x walls below are the largest cost)
    live = ~np.tile(blocked[: ii.size] | blocked[ii.size :], 2) & outside
    c, k = _near_pairs(xy, mid, np.where(live, half + witness_range, 0.0))
    keep = live[c]
    c, k = c[keep], k[keep]
    rel = xy[k] - (stops[c] - unit[c] * span_len[c, None])  # from the wall's mapped end
    t = np.sum(rel * unit[c], 1)
    s = np.sum(rel * nf[w_ext[c]], 1)  # > 0 on the side the wall was seen from
    seen = outside[c] & (t > witness_gap) & (t < span_len[c]) & (s > 0.0) & (s < witness_range)
    c, k, foot = c[seen], k[seen], xy[k[seen]] - s[seen, None] * nf[w_ext[c[seen]]]
    eye_to = foot + (xy[k] - foot) * (0.05 / np.maximum(s[seen], 0.05))[:, None]
    # mapped corners and points (edges, objects' sides seen end-on) near the line of sight
    # or the foot: an object in the way or an echo from there
    echoes = np.vstack([mapped_corners, np.asarray(the_map.points, float).reshape(-1, 2)])
    hidden = np.zeros(len(c), bool)
    for b in range(0, len(c), 4096):  # blocks of (extension, position) pairs x walls
        cb, kb, fb = c[b : b + 4096], k[b : b + 4096], foot[b : b + 4096]
        cross = _segments_cross(xy[kb, None], eye_to[b : b + 4096, None], p[None], q[None])
        there = _point_segment_distance(fb[:, None], p[None], q[None]) < 0.1
        mine = np.arange(len(walls))[None] == own[cb, 0, None]
        mine |= np.arange(len(walls))[None] == own[cb, 1, None]
        hidden[b : b + 4096] = ((cross | there) & ~mine).any(1)
        if len(echoes):
            near = _point_segment_distance(echoes[None], xy[kb, None], fb[:, None]) < witness_hide
            hidden[b : b + 4096] |= near.any(1)
    np.logical_or.at(blocked, c, ~hidden)
    blocked = blocked[: ii.size] | blocked[ii.size :]
    cost = np.maximum(beyond[ii, jj], 0.0) + np.maximum(beyond[jj, ii], 0.0)
    order = np.lexsort((cost, ~near_corner))
    taken: set[tuple[int, bool]] = set()
    out = walls.copy()
    new_corners = []
    for c_ in order:  # a handful of candidates
        if blocked[c_]:
            continue
        i, j = int(ii[c_]), int(jj[c_])
        ei, ej = (i, bool(end[i, j])), (j, bool(end[j, i]))
        if ei in taken or ej in taken:
            continue
        taken |= {ei, ej}
        for w, at_end in (ei, ej):
            if at_end:
                out[w, 2:] = x[c_]
            else:
                out[w, :2] = x[c_]
        if concave[i, j] and not near_corner[c_]:
            new_corners.append(x[c_])
    corners = np.vstack([mapped_corners, np.array(new_corners).reshape(-1, 2)])
    return SlamMap(walls=out, corners=corners, points=the_map.points, end_walls=the_map.end_walls)
