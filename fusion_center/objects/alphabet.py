"""The reference alphabet of Section 7.7: twelve polygonal cross-sections (data).

Each entry is a counter-clockwise polygon (metres, not closed) centred near the origin: the
footprint of a vertical prism. The set mixes what the chapter's recognition experiment used
(squares, rectangles, triangles, L and T shapes, six-corner objects), with sizes chosen like
furniture-scale test objects (0.2-0.55 m).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

ALPHABET_VERTICES: dict[str, list[tuple[float, float]]] = {
    "square_30": [(-0.15, -0.15), (0.15, -0.15), (0.15, 0.15), (-0.15, 0.15)],
    "square_45": [(-0.225, -0.225), (0.225, -0.225), (0.225, 0.225), (-0.225, 0.225)],
    "rect_30x45": [(-0.225, -0.15), (0.225, -0.15), (0.225, 0.15), (-0.225, 0.15)],
    "rect_20x50": [(-0.25, -0.1), (0.25, -0.1), (0.25, 0.1), (-0.25, 0.1)],
    "triangle_eq45": [(-0.225, -0.13), (0.225, -0.13), (0.0, 0.2597)],
    "triangle_right": [(-0.2, -0.15), (0.25, -0.15), (-0.2, 0.2)],
    "triangle_iso": [(-0.15, -0.2), (0.15, -0.2), (0.0, 0.3)],
    "L_45": [(-0.225, -0.225), (0.225, -0.225), (0.225, -0.025), (-0.025, -0.025),
             (-0.025, 0.225), (-0.225, 0.225)],
    "L_50x30": [(-0.25, -0.15), (0.25, -0.15), (0.25, 0.0), (-0.1, 0.0), (-0.1, 0.15),
                (-0.25, 0.15)],
    "T_50": [(-0.1, -0.25), (0.1, -0.25), (0.1, 0.05), (0.25, 0.05), (0.25, 0.25),
             (-0.25, 0.25), (-0.25, 0.05), (-0.1, 0.05)],
    "hexagon_25": [(0.25 * np.cos(a), 0.25 * np.sin(a)) for a in np.arange(6) * np.pi / 3],
    "hexagon_long": [(-0.275, 0.0), (-0.15, -0.15), (0.15, -0.15), (0.275, 0.0), (0.15, 0.15),
                     (-0.15, 0.15)],
}  # fmt: skip


def alphabet() -> dict[str, npt.NDArray[np.float64]]:
    """The alphabet as arrays: name -> vertices, float64, shape (V, 2), m, CCW, centred on
    the centroid of the polygon's area."""
    out = {}
    for name, pts in ALPHABET_VERTICES.items():
        v = np.asarray(pts, float)
        out[name] = v - polygon_centroid(v)
    return out


def polygon_centroid(vertices: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """Area centroid of a simple polygon (V, 2), m."""
    x, y = vertices[:, 0], vertices[:, 1]
    xn, yn = np.roll(x, -1), np.roll(y, -1)
    cross = x * yn - xn * y
    area = cross.sum() / 2
    return np.array([((x + xn) * cross).sum(), ((y + yn) * cross).sum()]) / (6 * area)


def place(
    vertices: npt.NDArray[np.float64], rotation: float, offset: npt.ArrayLike
) -> npt.NDArray[np.float64]:
    """The polygon rotated by ``rotation`` (rad, about its origin) and shifted by ``offset`` (m)."""
    c, s = np.cos(rotation), np.sin(rotation)
    return vertices @ np.array([[c, s], [-s, c]]) + np.asarray(offset, float)
