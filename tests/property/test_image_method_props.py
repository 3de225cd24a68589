"""Property test: the pruned, vectorised image method finds exactly the specular paths that an
exhaustive scalar search over every face sequence finds, in random metal rooms."""

from __future__ import annotations

import itertools
import math

import numpy as np
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from sim_nodes.channel.materials import Material
from sim_nodes.channel.raytrace import LOS, REFLECTED, AntennaArray, trace
from sim_nodes.channel.room import FaceSpec, Room, vertical_face
from sim_nodes.radar import C

Vec = tuple[float, float, float]


def sub(a: Vec, b: Vec) -> Vec:
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


def dot(a: Vec, b: Vec) -> float:
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def cross(a: Vec, b: Vec) -> Vec:
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


class BruteFace:
    """A face as plain vertex tuples: plane from its normal, inside test by edge cross products."""

    def __init__(self, spec: FaceSpec) -> None:
        self.v = [tuple(map(float, p)) for p in spec.vertices]
        n = tuple(map(float, spec.normal))
        norm = math.sqrt(dot(n, n))
        self.n = (n[0] / norm, n[1] / norm, n[2] / norm)
        self.d = dot(self.n, self.v[0])
        self.two = spec.two_sided

    def inside(self, x: Vec, tol: float) -> bool:
        signs = [
            dot(cross(sub(b, a), sub(x, a)), self.n)
            for a, b in zip(self.v, self.v[1:] + self.v[:1], strict=True)
        ]
        return all(s >= -tol for s in signs) or all(s <= tol for s in signs)

    def mirror(self, p: Vec) -> Vec:
        s = dot(self.n, p) - self.d
        return (p[0] - 2 * s * self.n[0], p[1] - 2 * s * self.n[1], p[2] - 2 * s * self.n[2])

    def crossing(self, p: Vec, q: Vec) -> tuple[float, Vec] | None:
        dq = sub(q, p)
        den = dot(self.n, dq)
        if abs(den) < 1e-12:
            return None
        u = (self.d - dot(self.n, p)) / den
        return u, (p[0] + u * dq[0], p[1] + u * dq[1], p[2] + u * dq[2])


def brute_force(faces: list[BruteFace], tx: Vec, rx: Vec, max_order: int) -> set:
    """Every (sequence, length) of unblocked specular paths, by exhaustive enumeration."""
    found = set()
    n_f = len(faces)
    for k in range(max_order + 1):
        for seq in itertools.product(range(n_f), repeat=k):
            if any(a == b for a, b in itertools.pairwise(seq)):
                continue
            imgs = [tx]
            for f in seq:
                imgs.append(faces[f].mirror(imgs[-1]))
            pts, target, ok = [], rx, True
            for m in range(k - 1, -1, -1):
                hit = faces[seq[m]].crossing(imgs[m + 1], target)
                if hit is None or not 1e-9 < hit[0] < 1 - 1e-9:
                    ok = False
                    break
                if not faces[seq[m]].inside(hit[1], 1e-9):
                    ok = False
                    break
                target = hit[1]
                pts.insert(0, target)
            if not ok:
                continue
            chain = [tx, *pts, rx]
            blocked = False
            for j in range(k + 1):
                own = {seq[j - 1]} if j >= 1 else set()
                own |= {seq[j]} if j < k else set()
                for f in range(n_f):
                    if f in own:
                        continue
                    hit = faces[f].crossing(chain[j], chain[j + 1])
                    if hit and 1e-9 < hit[0] < 1 - 1e-9 and faces[f].inside(hit[1], -1e-9):
                        blocked = True
                        break
                if blocked:
                    break
            if not blocked:
                length = sum(math.dist(a, b) for a, b in itertools.pairwise(chain))
                found.add((seq, round(length, 6)))
    return found


@st.composite
def rooms(draw: st.DrawFn) -> tuple[list[FaceSpec], Vec, Vec]:
    n = draw(st.integers(3, 5))
    angles = sorted(draw(st.lists(st.floats(0, 2 * math.pi), min_size=n, max_size=n)))
    if min(b - a for a, b in itertools.pairwise([*angles, angles[0] + 2 * math.pi])) < 0.4:
        angles = [2 * math.pi * i / n + 0.1 * draw(st.floats(-1, 1)) for i in range(n)]
    rx_, ry_ = draw(st.floats(3.0, 6.0)), draw(st.floats(2.5, 5.0))
    poly = [(rx_ * math.cos(a), ry_ * math.sin(a)) for a in angles]  # convex (on an ellipse)
    height = draw(st.floats(2.5, 4.0))
    faces = []
    for a, b in zip(poly, poly[1:] + poly[:1], strict=True):
        e = (b[0] - a[0], b[1] - a[1])
        vert, nrm = vertical_face(a, b, 0.0, height, [-e[1], e[0]])
        faces.append(
            FaceSpec(vertices=vert, normal=nrm, material=0, two_sided=False, kind=0, name="w")
        )
    xy = np.array(poly)
    for z, s in ((0.0, 1.0), (height, -1.0)):
        vert = np.concatenate([xy, np.full((n, 1), z)], axis=1)
        faces.append(
            FaceSpec(
                vertices=vert,
                normal=np.array([0, 0, s]),
                material=0,
                two_sided=False,
                kind=1,
                name="fc",
            )
        )
    # Optionally a box (4 sides and a top) near the centre.
    if draw(st.booleans()):
        cx, cy = draw(st.floats(-0.8, 0.8)), draw(st.floats(-0.8, 0.8))
        w, d, top = draw(st.floats(0.3, 0.8)), draw(st.floats(0.3, 0.8)), draw(st.floats(0.5, 2))
        sq = [(cx - w, cy - d), (cx + w, cy - d), (cx + w, cy + d), (cx - w, cy + d)]
        for a, b in zip(sq, sq[1:] + sq[:1], strict=True):
            e = (b[0] - a[0], b[1] - a[1])
            vert, nrm = vertical_face(a, b, 0.0, top, [e[1], -e[0]])
            faces.append(
                FaceSpec(vertices=vert, normal=nrm, material=0, two_sided=False, kind=3, name="box")
            )
        vert = np.array([[*p, top] for p in sq])
        faces.append(
            FaceSpec(
                vertices=vert,
                normal=np.array([0, 0, 1.0]),
                material=0,
                two_sided=False,
                kind=3,
                name="box",
            )
        )
        box = (cx - w, cx + w, cy - d, cy + d)
    else:
        box = None
    # Optionally a free-standing two-sided screen (a wall segment reflecting on both sides).
    if draw(st.booleans()):
        sx, sy = draw(st.floats(-1.5, 1.5)), draw(st.floats(-1.5, 1.5))
        ang, half_len = draw(st.floats(0, math.pi)), draw(st.floats(0.3, 1.0))
        a = (sx - half_len * math.cos(ang), sy - half_len * math.sin(ang))
        b = (sx + half_len * math.cos(ang), sy + half_len * math.sin(ang))
        vert, nrm = vertical_face(
            a, b, 0.0, draw(st.floats(1.0, height)), [-math.sin(ang), math.cos(ang)]
        )
        faces.append(
            FaceSpec(vertices=vert, normal=nrm, material=0, two_sided=True, kind=0, name="screen")
        )

    cx0, cy0 = float(np.mean(xy[:, 0])), float(np.mean(xy[:, 1]))

    def inside(x: float, y: float) -> bool:
        # Convex, counter-clockwise outline: left of every edge by a 0.2 m margin.
        return all(
            ((b[0] - a[0]) * (y - a[1]) - (b[1] - a[1]) * (x - a[0])) / math.dist(a, b) > 0.2
            for a, b in zip(poly, poly[1:] + poly[:1], strict=True)
        )

    def point() -> Vec:
        x, y = draw(st.floats(-rx_, rx_)), draw(st.floats(-ry_, ry_))
        for _ in range(60):  # pull towards the centroid until inside the room
            if inside(x, y):
                break
            x, y = cx0 + 0.7 * (x - cx0), cy0 + 0.7 * (y - cy0)
        assume(inside(x, y))  # a sliver of a room has no inside with the margin
        assume(not (box and box[0] - 0.2 < x < box[1] + 0.2 and box[2] - 0.2 < y < box[3] + 0.2))
        return (x, y, draw(st.floats(0.3, height - 0.3)))

    return faces, point(), point()


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(rooms())
def test_image_method_matches_exhaustive_search(case: tuple[list[FaceSpec], Vec, Vec]) -> None:
    faces, tx, rx = case
    assume(math.dist(tx, rx) > 0.3)
    room = Room.build(faces, (Material(metal=True),))
    expected = brute_force([BruteFace(f) for f in faces], tx, rx, max_order=3)
    paths, _ = trace(
        room,
        AntennaArray(position=np.array([tx]), yaw=np.zeros(1)),
        AntennaArray(position=np.array([rx]), yaw=np.zeros(1)),
        [9e9],
        max_order=3,
        diffraction=False,
    )
    assert set(np.unique(paths.kind)) <= {LOS, REFLECTED}
    got = {
        (tuple(int(f) for f in row[: int(o)]), round(float(C * d), 6))
        for row, o, d in zip(paths.faces, paths.order, paths.delay, strict=True)
    }
    assert got == expected
    assert len(got) == paths.count  # no duplicates
