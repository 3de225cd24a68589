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
    """

    walls: FloatArray = field(default_factory=lambda: np.zeros((0, 4)))
    corners: FloatArray = field(default_factory=lambda: np.zeros((0, 2)))
    points: FloatArray = field(default_factory=lambda: np.zeros((0, 2)))


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


def _cross2(a: FloatArray, b: FloatArray) -> FloatArray:
    """z component of the 2-D cross product ``a x b`` (broadcast over leading axes)."""
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def _segments_cross(p: FloatArray, q: FloatArray, a: FloatArray, b: FloatArray) -> FloatArray:
    """Whether segments ``p-q`` (c, 2) properly cross segments ``a-b`` (m, 2): (c, m)."""
    p, q = p[:, None, :], q[:, None, :]
    a, b = a[None], b[None]
    return (_cross2(q - p, a - p) * _cross2(q - p, b - p) < 0) & (
        _cross2(b - a, p - a) * _cross2(b - a, q - a) < 0
    )


def _point_segment_distance(x: FloatArray, p: FloatArray, q: FloatArray) -> FloatArray:
    """Distance of points ``x`` (m, 2) from segments ``p-q`` (c, 2): (c, m)."""
    e = q - p
    ee = np.maximum(np.sum(e * e, 1), 1e-12)
    t = np.clip(np.einsum("cmi,ci->cm", x[None] - p[:, None], e) / ee[:, None], 0.0, 1.0)
    return np.linalg.norm(p[:, None] + t[..., None] * e[:, None] - x[None], axis=-1)


def free_side(
    walls: FloatArray, path: FloatArray, margin: float = 0.5
) -> tuple[FloatArray, npt.NDArray[np.intp]]:
    """Unit normals of wall segments pointing to the side the robot saw them from, and the
    pose it saw each from.

    A wall's echo comes from the foot of the perpendicular from the array, so the poses that
    saw it project onto its extent (within ``margin``, m); the nearest of those (else the
    nearest pose) is taken as the observer and gives the side. ``walls`` (w, 4)
    ``[x1, y1, x2, y2]`` and ``path`` (k, 2) robot positions, one frame (m). Returns the
    normals (w, 2; a zero row where the observer lies on the wall's line: side undecided)
    and the observers' indices into ``path`` (w,).
    """
    p, q = walls[:, :2], walls[:, 2:]
    length = np.maximum(np.linalg.norm(q - p, axis=1), 1e-12)
    u = (q - p) / length[:, None]
    n = np.stack([-u[:, 1], u[:, 0]], -1)
    rel = path[None, :, :] - p[:, None, :]  # (w, k, 2)
    t = np.einsum("wki,wi->wk", rel, u)
    s = np.einsum("wki,wi->wk", rel, n)
    along = (t >= -margin) & (t <= length[:, None] + margin)
    dist = np.hypot(np.maximum(np.maximum(-t, t - length[:, None]), 0.0), s)
    key = np.where(along, np.abs(s), np.inf)
    # walls no pose projects onto: the pose nearest the segment
    seen_from = np.where(np.isfinite(key.min(1)), key.argmin(1), dist.argmin(1))
    side = np.sign(s[np.arange(len(walls)), seen_from])
    return n * side[:, None], seen_from


def close_outline(
    the_map: SlamMap,
    path: npt.ArrayLike,
    *,
    reach: float = 2.5,
    overshoot: float = 0.3,
    min_angle: float = np.radians(75.0),
    confirm: float = 0.5,
    clearance: float = 0.3,
) -> SlamMap:
    """Close the outline: extend mapped walls that meet to their intersection (the corner
    the room must have there) and add the concave corners this implies.

    A robot that stops far from a room's corners sees each wall only near the feet of its
    perpendiculars (the specular points), so the mapped extents stop short of the corners.
    Two mapped walls ``i``, ``j`` are closed at the intersection ``X`` of their lines when

    * their lines meet at ``min_angle`` (rad) or more (at 60 degrees a ghost face at 71
      degrees closed with a box's face on room_pillar);
    * ``X`` lies beyond (or at most ``overshoot`` m inside) one end of each, at most
      ``reach`` m beyond it;
    * each wall approaches ``X`` from the same side of the other as the robot saw that one
      from (:func:`free_side`): both from the free side is a concave (room) corner, both
      from behind a convex one (the inner corner of an L, a pillar's edge); mixed is no
      corner;
    * neither extension crosses the robot's path or another mapped wall, nor passes within
      ``clearance`` m of a robot position (the robot drove or stood there);
    * no mapped wall lies between ``X`` and the poses the two walls were seen from (two
      multipath ghosts beyond a room wall can meet at right angles).

    Each wall end takes at most one closure, the shortest extensions first (those with a
    mapped corner within ``confirm`` m of ``X``, the double reflection that confirms it,
    before all others). The ends move to ``X`` (extended, or trimmed where they overshot).
    A concave closure adds ``X`` to the corners unless a mapped corner lies within
    ``confirm`` m; a convex one adds nothing (an edge, which echoes as a point).

    Beyond the chapter (geometric post-processing of the map, as :func:`build_map`'s wall
    extension); docs/mapping.md "Closing the outline".

    Parameters
    ----------
    the_map : SlamMap
    path : array_like, shape (k, 2)
        Robot positions in the map's frame (m), in driving order.

    Returns
    -------
    SlamMap
        Walls with moved ends (same order), corners with the implied ones appended, points
        unchanged.
    """
    if not (reach > 0.0 and overshoot >= 0.0 and 0.0 < min_angle <= np.pi / 2):
        raise ValueError("close_outline needs reach > 0, overshoot >= 0, 0 < min_angle <= pi/2")
    walls = np.asarray(the_map.walls, float).reshape(-1, 4)
    xy = np.asarray(path, float).reshape(-1, 2)
    if len(walls) < 2 or len(xy) == 0:
        return the_map
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
    ok = (np.abs(den) >= np.sin(min_angle)) & (beyond <= reach) & (beyond >= -overshoot)
    ok &= ok.T
    concave = (approach < 0) & (approach.T < 0)
    convex = (approach > 0) & (approach.T > 0)
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
    moving = np.linalg.norm(np.diff(xy, axis=0), axis=1) > 1e-3
    a_path, b_path = xy[:-1][moving], xy[1:][moving]
    blocked = _segments_cross(starts, stops, a_path, b_path).any(1)
    blocked |= (_point_segment_distance(xy, starts, stops) < clearance).any(1)
    # another mapped wall across an extension (its own two walls are not: they meet at X)
    through = _segments_cross(starts, stops, p, q)
    pair = np.r_[np.arange(ii.size), np.arange(ii.size)]
    through[pair, np.r_[ii, ii]] = False
    through[pair, np.r_[jj, jj]] = False
    blocked |= through.any(1)
    # X in sight of the poses that saw the two walls: a corner behind another mapped wall
    # is one of two ghosts (multipath images beyond a room wall) meeting
    eyes = xy[np.r_[seen_from[ii], seen_from[jj]]]
    toward = stops - eyes
    # (ending 5 cm short of X: a third wall through X is not in the way)
    short = stops - 0.05 * toward / np.maximum(np.linalg.norm(toward, axis=1), 0.1)[:, None]
    sight = _segments_cross(eyes, short, p, q)
    sight[pair, np.r_[ii, ii]] = False
    sight[pair, np.r_[jj, jj]] = False
    blocked |= sight.any(1)
    blocked = blocked[: ii.size] | blocked[ii.size :]
    cost = np.maximum(beyond[ii, jj], 0.0) + np.maximum(beyond[jj, ii], 0.0)
    order = np.lexsort((cost, ~near_corner))
    taken: set[tuple[int, bool]] = set()
    out = walls.copy()
    new_corners = []
    for c in order:  # a handful of candidates
        if blocked[c]:
            continue
        i, j = int(ii[c]), int(jj[c])
        ei, ej = (i, bool(end[i, j])), (j, bool(end[j, i]))
        if ei in taken or ej in taken:
            continue
        taken |= {ei, ej}
        for w, at_end in (ei, ej):
            if at_end:
                out[w, 2:] = x[c]
            else:
                out[w, :2] = x[c]
        if concave[i, j] and not near_corner[c]:
            new_corners.append(x[c])
    corners = np.vstack([mapped_corners, np.array(new_corners).reshape(-1, 2)])
    return SlamMap(walls=out, corners=corners, points=the_map.points)
