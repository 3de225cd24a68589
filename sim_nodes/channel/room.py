"""3-D room geometry for the ray tracer: planar convex faces and vertical wedges (pure numpy).

A room is a set of F planar convex polygons ("faces") in world coordinates (x east, y north,
z up, m):

* walls given as segments are one two-sided face on their mid-plane (the thickness enters
  only through the material's transmission and excess delay);
* the room outline gives one-sided faces on its inner surface, normal pointing into the room;
* floor and ceiling are one-sided horizontal faces (absent in a 2-D room, whose walls then
  are the only reflectors);
* a solid (pillar, cabinet, table) is a vertical prism over a convex footprint: one-sided
  side faces and a top and bottom, normals pointing out.

A face is stored in its own plane frame (origin, two in-plane unit axes) with the inward
half-planes of its polygon edges, so that containment tests are a few dot products that
vectorise over points and faces. Vertical convex edges of solids and the free ends of walls
are the wedges used for diffraction.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from sim_nodes.channel.materials import Material

#: Face kinds (for path interaction labels and analysis).
WALL, FLOOR, CEILING, SOLID = 0, 1, 2, 3

_EPS = 1e-9


@dataclass(frozen=True, slots=True, kw_only=True)
class FaceSpec:
    """One face before packing: vertices (V, 3) in order (any orientation), and its data."""

    vertices: npt.NDArray[np.float64]
    normal: npt.NDArray[np.float64]
    material: int
    two_sided: bool
    kind: int
    name: str


@dataclass(frozen=True, slots=True, kw_only=True)
class Room:
    """F faces and E vertical wedges, packed for vectorised tests.

    Attributes
    ----------
    normal : ndarray, float64, shape (F, 3)
        Unit normals (the reflecting side for one-sided faces).
    offset : ndarray, float64, shape (F,)
        Plane offsets: ``normal . x = offset`` on the face, m.
    origin, axis_u, axis_v : ndarray, float64, shape (F, 3)
        Plane frame: ``x = origin + s axis_u + t axis_v``.
    edge_normal : ndarray, float64, shape (F, V, 2)
        Inward unit normals of the polygon edges in (s, t) (padded with zeros).
    edge_offset : ndarray, float64, shape (F, V)
        ``inside <=> edge_normal . (s, t) >= edge_offset`` for every edge (padding: -1).
    two_sided : ndarray, bool, shape (F,)
    material : ndarray, int, shape (F,)
        Index into ``materials``.
    kind : ndarray, int, shape (F,)
        WALL, FLOOR, CEILING or SOLID.
    names : tuple of str
        Scenario element each face comes from (for messages and path labels).
    materials : tuple of Material
    wedge_xy : ndarray, float64, shape (E, 2)
        Positions of the vertical wedges in x, y, m.
    wedge_z : ndarray, float64, shape (E, 2)
        Bottom and top of each wedge, m.
    vertices : ndarray, float64, shape (F, V, 3)
        Polygon vertices (padded by repeating the first).
    edge_plane : ndarray, float64, shape (F, V, 3)
        The edge half-planes lifted to world coordinates: for a point in the face's plane,
        ``m . (s, t) >= c  <=>  edge_plane . x >= edge_level`` (one product per edge).
    edge_level : ndarray, float64, shape (F, V)
    """

    normal: npt.NDArray[np.float64]
    offset: npt.NDArray[np.float64]
    origin: npt.NDArray[np.float64]
    axis_u: npt.NDArray[np.float64]
    axis_v: npt.NDArray[np.float64]
    edge_normal: npt.NDArray[np.float64]
    edge_offset: npt.NDArray[np.float64]
    two_sided: npt.NDArray[np.bool_]
    material: npt.NDArray[np.int64]
    kind: npt.NDArray[np.int64]
    names: tuple[str, ...]
    materials: tuple[Material, ...]
    wedge_xy: npt.NDArray[np.float64]
    wedge_z: npt.NDArray[np.float64]
    vertices: npt.NDArray[np.float64]
    edge_plane: npt.NDArray[np.float64]
    edge_level: npt.NDArray[np.float64]

    @property
    def n_faces(self) -> int:
        """Number of faces F."""
        return int(self.normal.shape[0])

    @property
    def transmission(self) -> npt.NDArray[np.float64]:
        """One-way amplitude transmission factor of each face, shape (F,)."""
        return np.array([0.0 if m.metal else m.transmission for m in self.materials])[self.material]

    @property
    def excess(self) -> npt.NDArray[np.float64]:
        """Excess path length of crossing each face, m, shape (F,)."""
        return np.array([m.excess for m in self.materials])[self.material]

    @classmethod
    def build(
        cls,
        faces: list[FaceSpec],
        materials: tuple[Material, ...],
        wedges: list[tuple[float, float, float, float]] | None = None,
    ) -> Room:
        """Pack face specifications (convex polygons) and wedges ``(x, y, z0, z1)``."""
        n_f = len(faces)
        v_max = max((f.vertices.shape[0] for f in faces), default=3)
        normal = np.zeros((n_f, 3))
        origin = np.zeros((n_f, 3))
        axis_u = np.zeros((n_f, 3))
        axis_v = np.zeros((n_f, 3))
        edge_normal = np.zeros((n_f, v_max, 2))
        edge_offset = np.full((n_f, v_max), -1.0)
        vertices = np.zeros((n_f, v_max, 3))
        for i, face in enumerate(faces):
            vert = np.asarray(face.vertices, float)
            pad = np.arange(v_max)
            vertices[i] = vert[np.where(pad < len(vert), pad, 0)]
            n = np.asarray(face.normal, float)
            n = n / np.linalg.norm(n)
            u = vert[1] - vert[0]
            u = u / np.linalg.norm(u)
            v = np.cross(n, u)
            st = np.stack([(vert - vert[0]) @ u, (vert - vert[0]) @ v], axis=1)
            # Orient the polygon counter-clockwise in (s, t) so that edge normals point in.
            area = np.sum(st[:, 0] * np.roll(st[:, 1], -1) - np.roll(st[:, 0], -1) * st[:, 1])
            if area < 0:
                st = st[::-1]
            e = np.roll(st, -1, axis=0) - st
            m = np.stack([-e[:, 1], e[:, 0]], axis=1)
            m /= np.linalg.norm(m, axis=1, keepdims=True)
            normal[i], origin[i], axis_u[i], axis_v[i] = n, vert[0], u, v
            edge_normal[i, : len(st)] = m
            edge_offset[i, : len(st)] = np.sum(m * st, axis=1)
        wedges = wedges or []
        plane = (
            edge_normal[..., :1] * axis_u[:, None, :] + edge_normal[..., 1:] * axis_v[:, None, :]
        )
        level = edge_offset + np.einsum("fvk,fk->fv", plane, origin)
        return cls(
            normal=normal,
            offset=np.sum(normal * origin, axis=1),
            origin=origin,
            axis_u=axis_u,
            axis_v=axis_v,
            edge_normal=edge_normal,
            edge_offset=edge_offset,
            two_sided=np.array([f.two_sided for f in faces], bool),
            material=np.array([f.material for f in faces], np.int64),
            kind=np.array([f.kind for f in faces], np.int64),
            names=tuple(f.name for f in faces),
            materials=materials,
            wedge_xy=np.array([w[:2] for w in wedges], float).reshape(-1, 2),
            wedge_z=np.array([w[2:] for w in wedges], float).reshape(-1, 2),
            vertices=vertices,
            edge_plane=plane,
            edge_level=level,
        )

    def contains(self, face: np.ndarray, points: np.ndarray, tol: float = 1e-9) -> np.ndarray:
        """Whether points (in the plane of their face) lie inside the face polygon.

        Parameters
        ----------
        face : ndarray, int, shape (...)
        points : ndarray, float64, shape (..., 3)

        Returns
        -------
        ndarray, bool, shape (...)
        """
        # Edge half-planes lifted to 3-D (edge_plane . x >= edge_level): one product per edge.
        lhs = np.einsum("...vk,...k->...v", self.edge_plane[face], points)
        return np.all(lhs >= self.edge_level[face] - tol, axis=-1)

    def in_plane_axes(self, face: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """In-plane unit axes of faces, each shape (..., 3)."""
        return self.axis_u[face], self.axis_v[face]


def vertical_face(
    a: npt.ArrayLike, b: npt.ArrayLike, z0: float, z1: float, normal_xy: npt.ArrayLike
) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (4, 3) and unit normal (3,) of a vertical rectangle over segment a-b."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    vert = np.array([[*a, z0], [*b, z0], [*b, z1], [*a, z1]])
    n = np.array([*np.asarray(normal_xy, float), 0.0])
    return vert, n / np.linalg.norm(n)


def mirror_points(points: np.ndarray, normal: np.ndarray, offset: np.ndarray) -> np.ndarray:
    """Mirror points in planes ``normal . x = offset``.

    .. math:: x' = x - 2 (n \\cdot x - d) n

    Parameters
    ----------
    points, normal : ndarray, shape (..., 3)
    offset : ndarray, shape (...)
    """
    side = np.sum(points * normal, axis=-1) - offset
    return points - 2 * side[..., None] * normal


def plane_dot(points: np.ndarray, normals: np.ndarray) -> npt.NDArray[np.float64]:
    """``points @ normals.T`` for 3-vectors, shape (L, F), without BLAS.

    Three broadcast multiply-adds: a (L x 3) (3 x F) product is too thin for BLAS, whose
    threads then only spin and steal CPU from the other worker process.
    """
    return (
        points[:, 0, None] * normals[None, :, 0]
        + points[:, 1, None] * normals[None, :, 1]
        + points[:, 2, None] * normals[None, :, 2]
    )


def segment_face_hits(
    room: Room, p: np.ndarray, q: np.ndarray, tol: float = _EPS
) -> npt.NDArray[np.bool_]:
    """Which faces each segment ``p -> q`` crosses strictly between its ends.

    Parameters
    ----------
    room : Room
    p, q : ndarray, float64, shape (L, 3)

    Returns
    -------
    ndarray, bool, shape (L, F)
    """
    if room.n_faces == 0 or p.shape[0] == 0:
        return np.zeros((p.shape[0], room.n_faces), bool)
    d = q - p
    den = plane_dot(d, room.normal)  # (L, F)
    num = room.offset[None, :] - plane_dot(p, room.normal)
    with np.errstate(divide="ignore", invalid="ignore"):
        u = num / den
        hit = (np.abs(den) > 1e-12) & (u > tol) & (u < 1 - tol)
    idx_l, idx_f = np.nonzero(hit)
    if idx_l.size:
        x = p[idx_l] + u[idx_l, idx_f, None] * d[idx_l]
        hit[idx_l, idx_f] = room.contains(idx_f, x, tol=-1e-9)
    return hit
