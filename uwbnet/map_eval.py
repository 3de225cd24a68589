"""Score a SLAM map (map.json) against a scenario's geometry and the recorded true poses.

Used by ``uwbnet map ... --eval SCENARIO``. Truth is taken from the scenario file (room outline,
objects) and moved into the frame of the robot's first true pose, the frame of map.json.

Figures (metres, degrees):

* walls: a mapped wall matches a true face (room wall or object side) whose line is within
  15 degrees and 0.5 m of it and which it overlaps; for every true face with a match, the
  closest mapped wall gives ``position`` (distance of its midpoint from the true line) and
  ``orientation`` (angle between them); ``unmatched`` counts mapped walls that match no face
  (ghosts: multipath, back faces of thick walls beyond 0.5 m) and ``outline_coverage`` is the
  fraction of the room outline's length covered by matched walls.
  ``unsupported_m`` is the length of mapped wall farther than 0.2 m from every true face
  (walls invented through openings, or placed off by the path's error).
* corners: concave corners of the truth (room corners, object sides meeting a room wall; not
  the reflex vertex of an L-shaped room, which is an edge below); for
  each, the nearest mapped corner within 0.5 m; ``false`` counts the mapped corners farther
  than 0.5 m from every true corner.
* ``walls.unsupported_aligned_m``, ``corners.false_aligned`` and ``corners.aligned_m`` (the
  corner errors' statistics; with a trajectory and true poses) are the same after the best
  rigid fit of the path to the truth is applied to the map:
  what is left besides one rotation and shift of the whole map, e.g. a heading error made at
  the first stop.
* points: convex edges of the objects (their vertical edges away from the room walls) and the
  room's reflex vertices (``edges``: the nearest mapped point within 0.5 m); for each
  object, the nearest mapped point to its outline (``found`` within 15 cm).
* trajectory: RMSE of the position and of the heading over all acquisitions, and the mean
  position and heading error per stop (``per_stop_m``, ``per_stop_yaw_deg``: a stop is a run of
  acquisitions at one true position, as the robot turns on the spot), the heading error a stop
  gains while turning (``turn_drift_deg``) and the RMSE left after the best rigid fit of the
  whole path (``aligned_rmse_m``: what remains besides one rotation and shift). With a
  dead-reckoning trajectory (the odometry integrated alone), ``dead_reckoning`` holds the
  same figures for it: the baseline the filter must beat.
"""

from __future__ import annotations

import itertools
import math
from typing import Any

import numpy as np

_MAX_STOPS = 200


def _to_frame(xy: np.ndarray, origin: np.ndarray) -> np.ndarray:
    c, s = math.cos(origin[2]), math.sin(origin[2])
    d = np.asarray(xy, float) - origin[:2]
    return np.column_stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]])


def truth_geometry(scenario: Any) -> dict[str, Any]:
    """Faces (segments), concave corners, convex edges and object outlines, world frame."""
    outline = np.array(scenario.room.outline, float) if scenario.room else np.zeros((0, 2))
    room_segs = [np.r_[a, b] for a, b in itertools.pairwise(outline)]

    def on_room_wall(p: np.ndarray) -> bool:
        for s in room_segs:
            a, b = s[:2], s[2:]
            e = b - a
            t = np.clip(np.dot(p - a, e) / np.dot(e, e), 0, 1)
            if np.linalg.norm(a + t * e - p) < 1e-6:
                return True
        return False

    # An outline vertex turning the way the outline winds is a concave corner seen from
    # inside (a double-reflection corner, Fig. 19); a reflex vertex (the inner vertex of an
    # L) faces the room as a convex edge, a diffraction point like an object's edge.
    ring = outline[:-1]
    if len(ring) >= 3:
        area = np.sum(ring[:, 0] * np.roll(ring[:, 1], -1) - np.roll(ring[:, 0], -1) * ring[:, 1])
        ein, eout = ring - np.roll(ring, 1, 0), np.roll(ring, -1, 0) - ring
        turn = ein[:, 0] * eout[:, 1] - ein[:, 1] * eout[:, 0]
        reflex = turn * area < 0
    else:
        reflex = np.zeros(len(ring), bool)
    faces, objects = list(room_segs), []
    corners, edges = list(ring[~reflex]), list(ring[reflex])
    for o in scenario.objects:
        fp = np.array(o.footprint, float)
        objects.append((o.id, fp))
        for a, b in itertools.pairwise(fp):
            mid = 0.5 * (a + b)
            if not on_room_wall(mid):
                faces.append(np.r_[a, b])
        for v in fp[:-1]:
            (corners if on_room_wall(v) else edges).append(v)
    for w in scenario.walls:
        faces.append(np.r_[w.start, w.end])
    return {
        "faces": np.array(faces).reshape(-1, 4),
        "room": np.array(room_segs).reshape(-1, 4),
        "corners": np.array(corners).reshape(-1, 2),
        "edges": np.array(edges).reshape(-1, 2),
        "objects": objects,
    }


def _seg_point_dist(seg: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Distance of points p (k, 2) from segments seg (w, 4): (k, w)."""
    a, b = seg[:, :2], seg[:, 2:]
    e = b - a
    t = np.clip(np.einsum("kwi,wi->kw", p[:, None, :] - a[None], e) / np.sum(e * e, 1), 0, 1)
    q = a[None] + t[..., None] * e[None]
    return np.linalg.norm(q - p[:, None, :], axis=-1)


def _unsupported_length(walls: np.ndarray, faces: np.ndarray, tol: float = 0.2) -> float:
    """Length (m) of the segments ``walls`` (w, 4) farther than ``tol`` from every segment
    of ``faces``, sampled every 2 cm."""
    if not len(walls):
        return 0.0
    length = np.linalg.norm(walls[:, 2:] - walls[:, :2], axis=1)
    n = np.maximum(2, np.ceil(length / 0.02).astype(int))
    which = np.repeat(np.arange(len(walls)), n)
    frac = np.concatenate([np.linspace(0.0, 1.0, k) for k in n])  # a loop over walls
    pts = walls[which, :2] + frac[:, None] * (walls[which, 2:] - walls[which, :2])
    far = _seg_point_dist(faces, pts).min(1) > tol
    return float(np.sum(np.bincount(which, far, len(walls)) / n * length))


def _rigid_fit(traj: np.ndarray, truth_traj: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The best rigid fit (Kabsch) of the ``[t, x, y, yaw]`` path to the true one at the same
    times: rotation matrix ``r`` and shift ``s`` with ``x @ r + s`` the fitted positions."""
    idx = np.clip(np.searchsorted(truth_traj[:, 0], traj[:, 0] - 1e-9), 0, len(truth_traj) - 1)
    a, b = traj[:, 1:3], truth_traj[idx, 1:3]
    ca, cb = a - a.mean(0), b - b.mean(0)
    h = ca.T @ cb
    rot = math.atan2(h[0, 1] - h[1, 0], h[0, 0] + h[1, 1])
    c, s = math.cos(rot), math.sin(rot)
    r = np.array([[c, s], [-s, c]])
    return r, b.mean(0) - a.mean(0) @ r


def _false_corners(mapped: np.ndarray, true: np.ndarray, gate: float = 0.5) -> int:
    """Mapped corners farther than ``gate`` (m) from every true corner."""
    if not len(mapped):
        return 0
    if not len(true):
        return len(mapped)
    return int((np.linalg.norm(mapped[:, None] - true[None], axis=-1).min(1) > gate).sum())


def _corner_errors(mapped: np.ndarray, corners: np.ndarray, reach: float = 0.5) -> list[float]:
    """For each true corner (k, 2), the distance (m) to the nearest ``mapped`` corner (m, 2)
    when within ``reach``; corners with none that near are left out (not found). Also the
    edges' errors against the mapped points."""
    if not len(mapped) or not len(corners):
        return []
    d = np.linalg.norm(np.asarray(corners)[:, None] - np.asarray(mapped)[None], axis=2).min(1)
    return [float(v) for v in d[d < reach]]


def _stats(x: list[float]) -> dict[str, float | int]:
    if not x:
        return {"n": 0}
    a = np.abs(np.array(x))
    return {
        "n": int(a.size),
        "mean": round(float(a.mean()), 3),
        "median": round(float(np.median(a)), 3),
        "max": round(float(a.max()), 3),
    }


def evaluate_map(
    doc: dict[str, Any],
    scenario: Any,
    truth_traj: np.ndarray | None,
    first_pose: np.ndarray,
    dead_reckoning: np.ndarray | None = None,
) -> dict[str, Any]:
    """Errors of ``doc`` (map.json) against ``scenario`` (see the module docstring).

    Parameters
    ----------
    truth_traj : ndarray, shape (k, 4), optional
        True ``[t, x, y, yaw]`` in the first-pose frame.
    first_pose : ndarray, shape (3,)
        World ``[x, y, yaw]`` of the robot's first pose.
    dead_reckoning : ndarray, shape (k, 4), optional
        ``[t, x, y, yaw]`` of the odometry integrated alone, first-pose frame.
    """
    g = truth_geometry(scenario)
    faces = np.hstack(
        [_to_frame(g["faces"][:, :2], first_pose), _to_frame(g["faces"][:, 2:], first_pose)]
    )
    room = np.hstack(
        [_to_frame(g["room"][:, :2], first_pose), _to_frame(g["room"][:, 2:], first_pose)]
    )
    corners = _to_frame(g["corners"], first_pose)
    edges = _to_frame(g["edges"], first_pose)
    out: dict[str, Any] = {}
    walls = np.array(doc["walls"], float).reshape(-1, 4)
    fe = faces[:, 2:] - faces[:, :2]
    fa = np.arctan2(fe[:, 1], fe[:, 0])
    fn = np.column_stack([-np.sin(fa), np.cos(fa)])
    flen = np.linalg.norm(fe, axis=1)
    # match[w, f]: mapped wall w lies along true face f (15 deg, 0.5 m, overlapping)
    off = np.full((len(walls), len(faces)), np.inf)
    dang = np.zeros((len(walls), len(faces)))
    covered = np.zeros(len(faces))
    for i, w in enumerate(walls):
        e = w[2:] - w[:2]
        a = math.atan2(e[1], e[0])
        dang[i] = np.abs((fa - a + np.pi / 2) % np.pi - np.pi / 2)
        mid = 0.5 * (w[:2] + w[2:])
        o = np.abs(np.sum((mid - faces[:, :2]) * fn, 1))
        t = np.sum((mid - faces[:, :2]) * fe, 1) / flen
        ok = (dang[i] < np.radians(15)) & (t > -0.5) & (t < flen + 0.5) & (o < 0.5)
        off[i] = np.where(ok, o, np.inf)
        if np.any(ok):
            f = int(np.argmin(off[i]))
            t1 = np.dot(w[:2] - faces[f, :2], fe[f]) / flen[f]
            t2 = np.dot(w[2:] - faces[f, :2], fe[f]) / flen[f]
            lo, hi = sorted((t1, t2))
            covered[f] += max(0.0, min(hi, flen[f]) - max(lo, 0.0))
    pos_err, ang_err = [], []
    best_of_face = np.argmin(off, axis=0) if len(walls) else np.zeros(0, int)
    for f in range(len(faces)):
        if len(walls) and np.isfinite(off[best_of_face[f], f]):
            pos_err.append(float(off[best_of_face[f], f]))
            ang_err.append(float(np.degrees(dang[best_of_face[f], f])))
    matched = np.isfinite(off).any(axis=1) if len(walls) else np.zeros(0, bool)
    n_room = len(room)  # the outline's faces come first in ``faces``
    out["walls"] = {
        "mapped": len(walls),
        "unmatched": int((~matched).sum()),
        "true_faces": len(faces),
        "faces_found": len(pos_err),
        "position_m": _stats(pos_err),
        "orientation_deg": _stats(ang_err),
        "outline_coverage": round(
            float(np.minimum(covered[:n_room], flen[:n_room]).sum() / flen[:n_room].sum()), 3
        ),
    }
    mc = np.array(doc["corners"], float).reshape(-1, 2)
    out["corners"] = {
        "true": len(corners),
        "mapped": len(mc),
        **_stats(_corner_errors(mc, corners)),
    }
    out["walls"]["unsupported_m"] = round(_unsupported_length(walls, faces), 2)
    out["corners"]["false"] = _false_corners(mc, corners)
    traj = np.array(doc["trajectory"], float).reshape(-1, 4)
    if truth_traj is not None and len(traj):
        r, shift = _rigid_fit(traj, truth_traj)
        fitted = np.hstack([walls[:, :2] @ r + shift, walls[:, 2:] @ r + shift])
        out["walls"]["unsupported_aligned_m"] = round(_unsupported_length(fitted, faces), 2)
        out["corners"]["false_aligned"] = _false_corners(mc @ r + shift, corners)
        out["corners"]["aligned_m"] = _stats(_corner_errors(mc @ r + shift, corners))
    mp = np.array(doc["points"], float).reshape(-1, 2)
    e_err = _corner_errors(mp, np.asarray(edges, float).reshape(-1, 2))  # nearest point
    out["edges"] = {"true": len(edges), "mapped_points": len(mp), **_stats(e_err)}
    per_obj = {}
    for oid, fp in g["objects"]:
        fp_f = _to_frame(fp, first_pose)
        segs = np.hstack([fp_f[:-1], fp_f[1:]])
        d = float(_seg_point_dist(segs, mp).min()) if len(mp) else float("inf")
        per_obj[oid] = round(d, 3)
    out["objects"] = {
        "nearest_point_m": per_obj,
        "found_within_0.15": int(sum(v <= 0.15 for v in per_obj.values())),
        "total": len(per_obj),
    }
    if truth_traj is not None and len(traj):
        out["trajectory"] = trajectory_errors(traj, truth_traj)
        if dead_reckoning is not None and len(dead_reckoning):
            out["dead_reckoning"] = trajectory_errors(dead_reckoning, truth_traj)
    return out


def trajectory_errors(traj: np.ndarray, truth_traj: np.ndarray) -> dict[str, Any]:
    """Position and heading errors of ``[t, x, y, yaw]`` rows against the truth (same frame).

    Returns RMSE, maximum and final position error (m), heading RMSE (degrees), the RMSE
    after the best rigid fit of the path to the truth (``aligned_rmse_m``; the path's rotation
    against the truth, the inverse of the fit's, is ``aligned_rotation_deg``: the part of the
    error that is one rotation of the whole path, with the sign of the heading error that made
    it, e.g. at the first stop), and per
    stop (consecutive acquisitions whose true position moves by less than 1 cm) the mean
    position error (m), the mean absolute heading error (degrees) and the heading error
    gained during the stop's turn (``per_stop_turn_drift_deg``, last minus first
    acquisition; ``turn_drift_deg`` is its mean absolute value over the stops of at least
    two acquisitions, None if there are none), when there are at most 200 stops.
    """
    idx = np.clip(np.searchsorted(truth_traj[:, 0], traj[:, 0] - 1e-9), 0, len(truth_traj) - 1)
    tt = truth_traj[idx]
    dp = np.linalg.norm(traj[:, 1:3] - tt[:, 1:3], axis=1)
    dy = np.degrees((traj[:, 3] - tt[:, 3] + np.pi) % (2 * np.pi) - np.pi)
    moved = np.r_[False, np.linalg.norm(np.diff(tt[:, 1:3], axis=0), axis=1) > 0.01]
    stop = np.cumsum(moved)
    n = np.bincount(stop)
    out: dict[str, Any] = {
        "rmse_m": round(float(np.sqrt(np.mean(dp**2))), 3),
        "max_m": round(float(dp.max()), 3),
        "final_m": round(float(dp[-1]), 3),
        "yaw_rmse_deg": round(float(np.sqrt(np.mean(dy**2))), 2),
    }
    # the path's shape against its frame: the best rigid fit (Kabsch) removes a rotation and
    # shift of the whole path, e.g. a heading error made in the first stop that rotates
    # every later pose about the start
    a, b = traj[:, 1:3], tt[:, 1:3]
    ca, cb = a - a.mean(0), b - b.mean(0)
    h = ca.T @ cb
    rot = math.atan2(h[0, 1] - h[1, 0], h[0, 0] + h[1, 1])
    c, s = math.cos(rot), math.sin(rot)
    fitted = ca @ np.array([[c, s], [-s, c]]) + b.mean(0)
    out["aligned_rmse_m"] = round(float(np.sqrt(np.mean(np.sum((fitted - b) ** 2, 1)))), 3)
    out["aligned_rotation_deg"] = round(-math.degrees(rot), 2) + 0.0  # the path's (no -0.0)
    if n.size <= _MAX_STOPS:  # a robot that drives all the time has no stops to list
        out["per_stop_m"] = np.round(np.bincount(stop, dp) / n, 3).tolist()
        out["per_stop_yaw_deg"] = np.round(np.bincount(stop, np.abs(dy)) / n, 2).tolist()
        # heading error gained while turning on the spot (last minus first acquisition of
        # each stop); the rest of a stop's error was there when it began (the drive to it)
        first = np.r_[0, np.flatnonzero(moved)]
        last = np.r_[first[1:] - 1, len(dy) - 1]
        turn = (dy[last] - dy[first] + 180.0) % 360.0 - 180.0
        turned = last > first  # a one-acquisition "stop" (driving) has no turn to drift in
        out["turn_drift_deg"] = (
            round(float(np.mean(np.abs(turn[turned]))), 2) if turned.any() else None
        )
        out["per_stop_turn_drift_deg"] = (np.round(turn, 2) + 0.0).tolist()
    return out
