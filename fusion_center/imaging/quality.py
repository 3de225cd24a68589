"""Image quality figures: peak position errors and an artefact measure.

* :func:`peak_errors`: for known point targets, the distance from each target to the image
  maximum within ``radius`` of it (m).
* :func:`surface_errors`: for known reflecting objects (polygons), the distance from the image
  maximum near each object to the object's outline (m): a wall or cabinet is imaged on its
  surface, not at its centre.
* :func:`artefact_ratio`: the share of image energy (sum of squared pixel values) farther than
  ``radius`` from every known surface: 0 for a perfect image, lower is cleaner. It compares
  methods on the same scene (the CoLOR chapter compares migration and cross-correlated images
  by their artefacts).
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from fusion_center.imaging.migration import Grid

Polygon = Sequence[Sequence[float]]


def _pixels(grid: Grid) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    xs, ys = grid.xy()
    X, Y = np.meshgrid(xs, ys)
    return X, Y


def segment_distance(
    X: npt.NDArray[np.float64], Y: npt.NDArray[np.float64], polygons: Sequence[Polygon]
) -> npt.NDArray[np.float64]:
    """Distance (m) of every point to the nearest edge of any polygon (closed or open)."""
    best = np.full(X.shape, np.inf)
    for poly in polygons:
        p = np.asarray(poly, float)
        for a, b in itertools.pairwise(p):
            e = b - a
            L2 = float(e @ e)
            if L2 == 0:
                continue
            t = np.clip(((X - a[0]) * e[0] + (Y - a[1]) * e[1]) / L2, 0.0, 1.0)
            d = np.hypot(X - a[0] - t * e[0], Y - a[1] - t * e[1])
            np.minimum(best, d, out=best)
    return best


def peak_errors(
    img: npt.NDArray[np.floating], grid: Grid, targets: npt.ArrayLike, radius: float = 0.5
) -> npt.NDArray[np.float64]:
    """Distance (m) from each target (K, 2) to the maximum of ``|img|`` within ``radius``.

    NaN where no pixel lies within ``radius``.
    """
    X, Y = _pixels(grid)
    a = np.abs(img)
    out = []
    for tx, ty in np.asarray(targets, float).reshape(-1, 2):
        near = np.hypot(X - tx, Y - ty) <= radius
        if not near.any():
            out.append(np.nan)
            continue
        k = np.argmax(np.where(near, a, -np.inf))
        out.append(float(np.hypot(X.flat[k] - tx, Y.flat[k] - ty)))
    return np.array(out)


def surface_errors(
    img: npt.NDArray[np.floating], grid: Grid, polygons: Sequence[Polygon], radius: float = 0.4
) -> npt.NDArray[np.float64]:
    """Distance (m) from the maximum of ``|img|`` within ``radius`` of each polygon's outline
    (outside or on it) to that outline."""
    X, Y = _pixels(grid)
    a = np.abs(img)
    out = []
    for poly in polygons:
        d = segment_distance(X, Y, [poly])
        near = d <= radius
        if not near.any():
            out.append(np.nan)
            continue
        k = np.argmax(np.where(near, a, -np.inf))
        out.append(float(d.flat[k]))
    return np.array(out)


def artefact_ratio(
    img: npt.NDArray[np.floating], grid: Grid, polygons: Sequence[Polygon], radius: float = 0.25
) -> float:
    """Share of image energy farther than ``radius`` (m) from every polygon edge, in [0, 1]."""
    X, Y = _pixels(grid)
    e = np.asarray(img, float) ** 2
    total = e.sum()
    if total == 0:
        return 0.0
    far = segment_distance(X, Y, polygons) > radius
    return float(e[far].sum() / total)
