"""Resolution and ghost level of the ambiguity function at one reference point (Section 5).

Pure numpy. Resolution is the 3 dB main-lobe width (``20 log10 |chi| = -3 dB``) along the two
principal axes of the main lobe; the ghost level is the highest ``|chi|`` outside the main lobe
over an evaluation area, in dB relative to the peak (peak-to-ghost / peak-sidelobe level).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy.ndimage import maximum_filter

from .ambiguity import SPEED_OF_LIGHT, Band, NetworkGeometry, ambiguity, grid_points

__all__ = [
    "Area",
    "PointQuality",
    "assess_point",
    "ghost_level",
    "mainlobe_widths",
    "principal_axes",
]

FloatArray = npt.NDArray[np.float64]

#: Amplitude of the 3 dB contour, 10 ** (-3 / 20).
_HALF_POWER = 10.0 ** (-3.0 / 20.0)


@dataclass(frozen=True, slots=True, kw_only=True)
class Area:
    """A rectangular evaluation area and the grid on it.

    Parameters
    ----------
    x_min, y_min, x_max, y_max : float
        Corners, world frame, m.
    nx, ny : int
        Grid points along x and y (the AF is evaluated on this grid for ghost search).
    """

    x_min: float
    y_min: float
    x_max: float
    y_max: float
    nx: int = 200
    ny: int = 200

    def __post_init__(self) -> None:
        if not (self.x_max > self.x_min and self.y_max > self.y_min):
            raise ValueError("area: need x_min < x_max and y_min < y_max")
        if self.nx < 2 or self.ny < 2:
            raise ValueError("area: need at least 2 x 2 grid points")

    @property
    def x(self) -> FloatArray:
        """Grid x coordinates, m, shape (nx,)."""
        return np.linspace(self.x_min, self.x_max, self.nx)

    @property
    def y(self) -> FloatArray:
        """Grid y coordinates, m, shape (ny,)."""
        return np.linspace(self.y_min, self.y_max, self.ny)

    @property
    def step(self) -> tuple[float, float]:
        """Grid spacing (dx, dy), m."""
        return (
            (self.x_max - self.x_min) / (self.nx - 1),
            (self.y_max - self.y_min) / (self.ny - 1),
        )

    def points(self) -> FloatArray:
        """Grid points, shape (ny * nx, 2), image order."""
        return grid_points(self.x, self.y)

    def with_grid(self, nx: int, ny: int) -> Area:
        """The same area on another grid."""
        return Area(
            x_min=self.x_min, y_min=self.y_min, x_max=self.x_max, y_max=self.y_max, nx=nx, ny=ny
        )


@dataclass(frozen=True, slots=True, kw_only=True, eq=False)
class PointQuality:
    """Resolution and ghost level of the AF of one reference point.

    Attributes
    ----------
    reference : ndarray, shape (2,), m
    widths : ndarray, shape (2,), m
        3 dB main-lobe widths along ``axes[0]`` (the wider) and ``axes[1]`` (the narrower).
    axes : ndarray, shape (2, 2)
        Unit principal axes of the main lobe, one per row, world frame.
    ghost_db : float
        Highest ``20 log10 |chi|`` outside the main lobe in the area, dB (<= 0).
    ghost_position : ndarray, shape (2,), m
        Where that ghost is.
    """

    reference: FloatArray
    widths: FloatArray
    axes: FloatArray
    ghost_db: float
    ghost_position: FloatArray

    @property
    def resolution(self) -> float:
        """Mean of the two main-lobe widths, m."""
        return float(np.mean(self.widths))


def principal_axes(
    geometry: NetworkGeometry, band: Band, reference: npt.ArrayLike
) -> tuple[FloatArray, FloatArray]:
    """Principal axes of the main lobe and their quadratic-model 3 dB widths.

    Near the peak the far-field AF is ``chi(Delta) = E[exp(j k . Delta)]`` over the links'
    wave vectors ``k = 2 pi f / c * s_l`` (:meth:`NetworkGeometry.sum_direction`) and the band,
    so ``|chi|^2 ~ 1 - Delta^T C Delta`` with ``C`` the covariance of the wave vectors. Its
    eigenvectors are the principal axes: the spread of the look directions (the angular
    rotation the tracks and the receivers give) and the bandwidth set the eigenvalues.

    Returns
    -------
    axes : ndarray, shape (2, 2)
        Unit axes as rows, the wider main-lobe direction first.
    widths : ndarray, shape (2,), m
        Quadratic-model full widths at ``|chi|^2 = 1/2`` (a starting scale; see
        :func:`mainlobe_widths` for the measured ones).
    """
    vals, vecs = np.linalg.eigh(_wavevector_covariance(geometry, band, reference))
    # eigh sorts ascending: the smaller eigenvalue is the wider lobe, listed first.
    return vecs.T.copy(), 2.0 * np.sqrt(0.5 / np.maximum(vals, 1e-12))


def _wavevector_covariance(
    geometry: NetworkGeometry, band: Band, reference: npt.ArrayLike
) -> FloatArray:
    """Covariance of the links' wave vectors ``2 pi f / c * s_l`` over links and band, 1/m^2."""
    s = geometry.sum_direction(reference)
    scale = (2.0 * np.pi / SPEED_OF_LIGHT) ** 2
    second = scale * band.mean_square_frequency * (s.T @ s) / len(s)
    mean = (2.0 * np.pi * band.center / SPEED_OF_LIGHT) * s.mean(axis=0)
    return second - np.outer(mean, mean)


def mainlobe_widths(
    geometry: NetworkGeometry,
    band: Band,
    reference: npt.ArrayLike,
    axes: FloatArray | None = None,
    *,
    samples: int = 241,
) -> tuple[FloatArray, FloatArray]:
    """Measured 3 dB main-lobe widths of the exact AF along the principal axes.

    Samples ``|chi|`` on both sides of the peak along each axis and interpolates the first
    crossing of -3 dB on each side; the width is the distance between the two crossings.

    Returns
    -------
    widths : ndarray, shape (2,), m
    axes : ndarray, shape (2, 2)
    """
    p0 = np.asarray(reference, dtype=np.float64)
    if axes is None:
        axes, _ = principal_axes(geometry, band, p0)
    axes = np.asarray(axes, dtype=np.float64)
    cov = _wavevector_covariance(geometry, band, p0)
    curvature = np.maximum(np.einsum("ij,jk,ik->i", axes, cov, axes), 1e-12)
    # Search to 3x the quadratic model's half width (at most 10 m), then once more to 1.5x
    # the measured half width, so that ~100 samples fall across the lobe.
    half = np.minimum(3.0 * np.sqrt(0.5 / curvature), 10.0)
    widths = np.empty(2)
    for i in range(2):
        for _ in range(2):
            side = _crossings(geometry, band, p0, axes[i], half[i], samples)
            widths[i] = side.sum()
            if side.max() >= half[i]:
                break  # no crossing within the search: keep the search limit
            half[i] = 1.5 * side.max()
    return widths, axes


def _crossings(
    geometry: NetworkGeometry,
    band: Band,
    p0: FloatArray,
    axis: FloatArray,
    half: float,
    samples: int,
) -> FloatArray:
    """Distances from ``p0`` to the first -3 dB crossing in the ``+axis`` and ``-axis``
    directions (linear interpolation; ``half`` where none is found), m."""
    r = np.linspace(0.0, half, samples)[1:]
    line = np.concatenate([p0 + r[:, None] * axis, p0 - r[:, None] * axis])
    mag = np.abs(ambiguity(geometry, band, p0, line)).reshape(2, -1)
    side = np.full(2, half)
    for j in range(2):
        below = np.nonzero(mag[j] < _HALF_POWER)[0]
        if below.size == 0:
            continue
        n = below[0]
        m_prev, r_prev = (1.0, 0.0) if n == 0 else (mag[j, n - 1], r[n - 1])
        frac = (m_prev - _HALF_POWER) / max(m_prev - mag[j, n], 1e-12)
        side[j] = r_prev + frac * (r[n] - r_prev)
    return side


def ghost_level(
    geometry: NetworkGeometry,
    band: Band,
    reference: npt.ArrayLike,
    area: Area,
    widths: FloatArray,
    axes: FloatArray,
    *,
    mainlobe_factor: float = 2.0,
    refine: int = 6,
) -> tuple[float, FloatArray, FloatArray]:
    """Highest AF level outside the main lobe over ``area`` (the worst ghost), dB.

    The main lobe is the ellipse with semi-axes ``mainlobe_factor * widths`` along ``axes``
    (a sinc lobe's first null is 1.13 3-dB widths from its peak). The AF is evaluated on the
    area's grid and on a fine window (quarter-width steps, 6 main-lobe radii) around the
    reference, where the close-in sidelobes are; the ``refine`` highest local maxima of the
    grid and the two highest of the window outside the main lobe are then refined by two
    finer local grid searches, because a grid coarser than the lobes under-reads peaks.

    Returns
    -------
    ghost_db : float
        ``20 log10 max |chi|`` outside the main lobe (``-inf`` if nothing lies outside).
    position : ndarray, shape (2,), m
    image : ndarray, float64, shape (ny, nx)
        ``|chi|`` on the area grid.
    """
    p0 = np.asarray(reference, dtype=np.float64)
    pts = area.points()
    image = np.abs(ambiguity(geometry, band, p0, pts)).reshape(area.ny, area.nx)
    semi = mainlobe_factor * np.maximum(widths, 1e-6)

    def outside(p: FloatArray) -> npt.NDArray[np.bool_]:
        local = (p - p0) @ axes.T
        return np.sum((local / semi) ** 2, axis=-1) > 1.0

    mask = outside(pts).reshape(area.ny, area.nx)
    peaks = (image == maximum_filter(image, size=3, mode="nearest")) & mask
    flat = np.flatnonzero(peaks)
    dx, dy = area.step
    top = flat[np.argsort(image.ravel()[flat])[::-1][:refine]]
    seeds = [(pts[i], np.array([dx, dy])) for i in top]
    # The close-in sidelobes next to the main lobe are narrower than a coarse area grid:
    # search a fine window around the reference too (quarter-width steps).
    fine = float(np.min(widths)) / 4.0
    half = mainlobe_factor * float(np.max(widths)) * 3.0
    if fine > 0 and half > 0:
        n = min(int(2 * half / fine) + 1, 201)
        axis = np.linspace(-half, half, n)
        win = p0 + grid_points(axis, axis)
        win = win[outside(win)]
        if win.size:
            mag = np.abs(ambiguity(geometry, band, p0, win))
            step = axis[1] - axis[0]
            seeds += [(win[i], np.array([step, step])) for i in np.argsort(mag)[::-1][:2]]
    if not seeds:
        return -np.inf, p0.copy(), image
    level, where = -1.0, p0.copy()
    offsets = np.linspace(-1.0, 1.0, 9)
    for c, span in seeds:
        for _ in range(2):
            cand = c + grid_points(offsets * span[0], offsets * span[1])
            cand = cand[outside(cand)]
            if cand.size == 0:
                break
            mag = np.abs(ambiguity(geometry, band, p0, cand))
            c = cand[int(np.argmax(mag))]
            span = span / 4.0
            if mag.max() > level:
                level, where = float(mag.max()), c
    return 20.0 * np.log10(max(level, 1e-12)), where, image


def assess_point(
    geometry: NetworkGeometry,
    band: Band,
    reference: npt.ArrayLike,
    area: Area,
    *,
    mainlobe_factor: float = 2.0,
    refine: int = 6,
) -> PointQuality:
    """Resolution (3 dB widths along the principal axes) and ghost level of one point."""
    p0 = np.asarray(reference, dtype=np.float64)
    widths, axes = mainlobe_widths(geometry, band, p0)
    ghost_db, where, _ = ghost_level(
        geometry, band, p0, area, widths, axes, mainlobe_factor=mainlobe_factor, refine=refine
    )
    return PointQuality(
        reference=p0, widths=widths, axes=axes, ghost_db=ghost_db, ghost_position=where
    )
