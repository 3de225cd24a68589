"""Snapshot position estimators from node-to-anchor ranges (Section 4 of the CoLOR chapter).

Pure numpy: anchors and ranges in, a :class:`PositionFix` (position, covariance, flags) out.
All three estimators work in the horizontal plane: the caller gives horizontal ranges (a 3-D
range with the known height difference removed, :func:`horizontal_ranges`).

Every estimator reports a covariance that is honest for its solution, and a flagged failure
instead of a silent wrong fix when the geometry cannot determine the position: fewer than
three anchors, collinear anchors (the mirror image of the position fits the ranges equally
well) or a numerically singular normal matrix.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]

#: Relative size of the smallest singular value of the centred anchor matrix below which the
#: anchors count as collinear (a 5 cm offset over a 10 m line is 0.005).
COLLINEAR_TOLERANCE = 1e-3


@dataclass(frozen=True, slots=True, kw_only=True, eq=False)
class PositionFix:
    """One position estimate.

    Attributes
    ----------
    position : ndarray, float64, shape (2,)
        World x, y, m (NaN when no estimate could be formed at all).
    cov : ndarray, float64, shape (2, 2)
        Covariance of ``position``, m² (infinite diagonal when unknown).
    ok : bool
        False when the fix is a flagged failure (see ``reason``); its position must not be
        used as a measurement without a prior that resolves the ambiguity.
    reason : str
        Empty when ``ok``; otherwise why the geometry does not determine the position.
    residual_rms : float
        RMS of the range residuals at the solution, m.
    """

    position: FloatArray
    cov: FloatArray
    ok: bool
    reason: str = ""
    residual_rms: float = float("nan")


def failed_fix(reason: str, position: FloatArray | None = None) -> PositionFix:
    """A flagged failure with an infinite covariance."""
    pos = np.full(2, np.nan) if position is None else np.asarray(position, float)
    return PositionFix(position=pos, cov=np.diag([np.inf, np.inf]), ok=False, reason=reason)


def horizontal_ranges(ranges: FloatArray, dz: FloatArray) -> FloatArray:
    """Horizontal distances from 3-D ranges and known height differences, m.

    A range shorter than its height difference (noise) is clipped to zero horizontal distance.
    """
    return np.sqrt(np.maximum(np.asarray(ranges, float) ** 2 - np.asarray(dz, float) ** 2, 0.0))


def geometry_problem(anchors: FloatArray) -> str:
    """Why a set of 2-D anchors cannot give an unambiguous fix ('' if it can)."""
    a = np.asarray(anchors, float)
    if a.shape[0] < 3:
        return f"{a.shape[0]} anchors: a 2-D fix needs at least 3"
    centred = a - a.mean(axis=0)
    s = np.linalg.svd(centred, compute_uv=False)
    if s[0] <= 0.0 or s[-1] / s[0] < COLLINEAR_TOLERANCE:
        return "collinear anchors: the mirror image fits the ranges as well"
    return ""


def _condition(normal: FloatArray) -> float:
    """Condition number of a symmetric positive semi-definite normal matrix (closed form for
    2 x 2, the hot case of every fix: an SVD costs more than the rest of a Gauss-Newton
    step)."""
    if normal.shape != (2, 2):
        return float(np.linalg.cond(normal))
    half = 0.5 * (normal[0, 0] + normal[1, 1])
    root = math.sqrt(
        max(half * half - (normal[0, 0] * normal[1, 1] - normal[0, 1] * normal[1, 0]), 0.0)
    )
    low = half - root
    return float("inf") if low <= 0.0 else (half + root) / low


def _solve_weighted(
    design: FloatArray, rhs: FloatArray, weight: FloatArray, *, equilibrate: bool = False
) -> tuple[FloatArray, FloatArray] | None:
    """Weighted least squares ``argmin (rhs - design x)' W (rhs - design x)`` with its
    covariance ``(design' W design)^-1``; None when the normal matrix is singular.

    With ``equilibrate`` the normal matrix is scaled to a unit diagonal first (Jacobi
    scaling, ``D N D`` with ``D = diag(N)^-1/2``), so that singularity is judged on the
    geometry, not on the unknowns' units or on weights that differ by 10^7 (millimetre LOS
    ranges beside de-weighted NLOS ones); the solution is the same."""
    normal = design.T @ (weight[:, None] * design)
    if not np.all(np.isfinite(normal)):
        return None
    g = design.T @ (weight * rhs)
    if not equilibrate:
        if _condition(normal) > 1e12:
            return None
        x = np.linalg.solve(normal, g)
        cov = np.linalg.solve(normal, np.eye(normal.shape[0]))
        return x, 0.5 * (cov + cov.T)
    diag = np.diag(normal)
    if np.any(diag <= 0.0):
        return None
    d = 1.0 / np.sqrt(diag)
    dd = np.outer(d, d)
    if _condition(normal * dd) > 1e12:
        return None
    x = d * np.linalg.solve(normal * dd, d * g)
    cov = dd * np.linalg.solve(normal * dd, np.eye(normal.shape[0]))
    return x, 0.5 * (cov + cov.T)


def _residual_rms(anchors: FloatArray, ranges: FloatArray, x: FloatArray) -> float:
    return float(np.sqrt(np.mean((np.linalg.norm(anchors - x, axis=1) - ranges) ** 2)))


class Locator(ABC):
    """A snapshot position estimator: ``locate(anchors, ranges, std) -> PositionFix``."""

    @abstractmethod
    def locate(
        self,
        anchors: FloatArray,
        ranges: FloatArray,
        std: FloatArray,
        initial: FloatArray | None = None,
    ) -> PositionFix:
        """Estimate a 2-D position.

        Parameters
        ----------
        anchors : ndarray, float64, shape (k, 2)
            Anchor positions, world x, y, m.
        ranges : ndarray, float64, shape (k,)
            Horizontal distances to the anchors, m.
        std : ndarray, float64, shape (k,)
            Standard deviation of each range, m (large for a de-weighted NLOS anchor).
        initial : ndarray, shape (2,), optional
            A starting point / prior position (used by the iterative estimator).
        """

    def _check(
        self, anchors: FloatArray, ranges: FloatArray, std: FloatArray
    ) -> tuple[FloatArray, FloatArray, FloatArray, str]:
        a = np.asarray(anchors, float).reshape(-1, 2)
        r = np.asarray(ranges, float).ravel()
        s = np.asarray(std, float).ravel()
        if not (a.shape[0] == r.size == s.size):
            raise ValueError("anchors, ranges and std differ in length")
        good = np.isfinite(r) & np.isfinite(s) & (s > 0) & np.all(np.isfinite(a), axis=1)
        a, r, s = a[good], r[good], s[good]
        return a, r, s, geometry_problem(a)


class LinearLeastSquaresLocator(Locator):
    """Linear least squares on range differences to a reference anchor.

    Subtracting the squared range equation of the reference anchor (the most precise one)
    from the others removes the quadratic term:

    .. math:: 2 (a_i - a_1)^T x = \\|a_i\\|^2 - \\|a_1\\|^2 - r_i^2 + r_1^2

    solved by weighted least squares; the weights and the covariance come from the
    linearised noise of the right-hand side, :math:`\\delta b_i = -2 r_i n_i + 2 r_1 n_1`
    (the linear LS estimator of Section 4 of the CoLOR chapter, with its covariance).
    """

    def locate(self, anchors, ranges, std, initial=None):
        a, r, s, problem = self._check(anchors, ranges, std)
        if problem:
            return failed_fix(problem)
        ref = int(np.argmin(s))
        others = np.arange(a.shape[0]) != ref
        design = 2.0 * (a[others] - a[ref])
        rhs = np.sum(a[others] ** 2, axis=1) - np.sum(a[ref] ** 2) - r[others] ** 2 + r[ref] ** 2
        # the reference's noise is common to every row: a full covariance, whitened by solve
        jac = 2.0 * np.maximum(r, 1e-3)
        cov_b = np.diag((jac[others] * s[others]) ** 2) + (jac[ref] * s[ref]) ** 2
        chol = np.linalg.cholesky(cov_b)
        wd = np.linalg.solve(chol, design)
        wb = np.linalg.solve(chol, rhs)
        sol = _solve_weighted(wd, wb, np.ones(wb.size))
        if sol is None:
            return failed_fix("singular geometry")
        x, cov = sol
        return PositionFix(position=x, cov=cov, ok=True, residual_rms=_residual_rms(a, r, x))


class TaylorSeriesLocator(Locator):
    """Taylor-series (Gauss-Newton) weighted least squares on the ranges.

    Iterates :math:`x \\leftarrow x + (J^T W J)^{-1} J^T W (r - d(x))` with
    :math:`J_i = (x - a_i)^T / d_i`, :math:`W = \\mathrm{diag}(1/\\sigma_i^2)`, from ``initial``
    or the linear LS fix; covariance :math:`(J^T W J)^{-1}` at the solution (the Taylor-series
    estimator of Section 4 of the CoLOR chapter).

    Parameters
    ----------
    max_iterations : int
    tolerance : float
        Step length at which the iteration stops, m.
    """

    def __init__(self, max_iterations: int = 20, tolerance: float = 1e-4) -> None:
        self.max_iterations = max_iterations
        self.tolerance = tolerance
        self._init = LinearLeastSquaresLocator()

    def locate(self, anchors, ranges, std, initial=None):
        a, r, s, problem = self._check(anchors, ranges, std)
        if problem and (initial is None or a.shape[0] < 2):
            return failed_fix(problem)
        starts = []
        if initial is not None and np.all(np.isfinite(initial)):
            starts.append(np.asarray(initial, float))
        first = self._init.locate(a, r, s)
        if first.ok:
            starts.append(first.position)
        if not starts:
            return first
        # from the prior and from the linear fix: a prior on the wrong side of a line of
        # anchors would otherwise keep the mirror branch; the lower weighted cost wins
        best = self.best_of(a, r, s, starts)
        if best is None:
            return failed_fix("Gauss-Newton diverged")
        x, cov, _ = best
        rms = _residual_rms(a, r, x)
        # with fewer than 3 anchors or collinear ones, a prior chose the branch: the covariance
        # is the local one, and the fix is flagged so that only a tracker with that prior uses it
        return PositionFix(position=x, cov=cov, ok=not problem, reason=problem, residual_rms=rms)

    def best_of(
        self, a: FloatArray, r: FloatArray, s: FloatArray, starts: list[FloatArray]
    ) -> tuple[FloatArray, FloatArray, float] | None:
        """Gauss-Newton from each start: the ``(x, cov, weighted cost)`` of lowest cost, or
        None when every run was singular."""
        best = None
        for x0 in starts:
            res = self._iterate(a, r, s, x0)
            if res is not None and (best is None or res[2] < best[2]):
                best = res
        return best

    def from_start(
        self, anchors: FloatArray, ranges: FloatArray, std: FloatArray, start: FloatArray
    ) -> tuple[FloatArray, FloatArray, float] | None:
        """Gauss-Newton from ``start`` alone: the local solution (2,), its covariance (2, 2)
        and its weighted cost :math:`\\sum_i ((d_i - r_i) / \\sigma_i)^2`, or None."""
        return self._iterate(
            np.asarray(anchors, float),
            np.asarray(ranges, float),
            np.asarray(std, float),
            np.asarray(start, float),
        )

    def _iterate(
        self, a: FloatArray, r: FloatArray, s: FloatArray, x0: FloatArray
    ) -> tuple[FloatArray, FloatArray, float] | None:
        """Gauss-Newton from ``x0``: ``(x, cov, weighted cost)`` or None if singular."""
        x = x0.copy()
        w = 1.0 / s**2
        cov = None
        for _ in range(self.max_iterations):
            diff = x - a
            d = np.maximum(np.linalg.norm(diff, axis=1), 1e-6)
            sol = _solve_weighted(diff / d[:, None], r - d, w)
            if sol is None:
                return None
            step, cov = sol
            x = x + step
            if np.linalg.norm(step) < self.tolerance:
                break
        if cov is None or not np.all(np.isfinite(x)):
            return None
        cost = float(np.sum(w * (np.linalg.norm(x - a, axis=1) - r) ** 2))
        return x, cov, cost


class ApproximateMlLocator(Locator):
    """Approximate maximum likelihood: the two-step weighted LS of Chan and Ho.

    The chapter's approximate ML estimator replaces the ML cost by one that is linear in
    :math:`\\theta = [x, y, R]`, :math:`R = \\|x\\|^2`, using :math:`r_i^2 - d_i^2 \\approx
    2 d_i n_i`: step 1 solves :math:`2 a_i^T x - R = \\|a_i\\|^2 - r_i^2` with weights
    :math:`1/(4 r_i^2 \\sigma_i^2)`; step 2 imposes :math:`R = x^2 + y^2` by a second weighted
    LS on :math:`[x^2, y^2]`. It attains the CRLB at small noise (Chan and Ho, IEEE Trans. SP
    42(8), 1994, the ToA form). Coordinates are shifted so that the position is far from the
    axes (the square root's sign is then that of step 1). Both steps are solved with Jacobi
    scaling (:func:`_solve_weighted`): millimetre LOS ranges beside de-weighted NLOS ones
    (weights 10^7 apart) made step 1 look singular in 40 % of the lab_nlos rounds.

    Gauss-Newton iterated to convergence from the two-step solution (and, when tracking, from
    the prior: the lower weighted cost wins) then gives the ML solution of the ranges and
    its covariance. Beyond the chapter: the two-step solution is efficient only at small
    noise on every range; with two millimetre LOS ranges and two NLOS ones at 1.5 m it is
    centimetres off, and the single polishing step used until stop 19 left 1-3 cm there
    (lab_nlos approximate ML 9-14 mm tracked; now 0.44-0.49 mm, the Taylor fix's).
    """

    def __init__(self) -> None:
        self._polish = TaylorSeriesLocator()

    def locate(self, anchors, ranges, std, initial=None):
        a, r, s, problem = self._check(anchors, ranges, std)
        if problem:
            return failed_fix(problem)
        origin = a.min(axis=0) - (np.ptp(a, axis=0).max() + r.max() + 1.0)
        b = a - origin
        design = np.column_stack([2.0 * b, -np.ones(b.shape[0])])
        rhs = np.sum(b**2, axis=1) - r**2
        w1 = 1.0 / (4.0 * np.maximum(r, 1e-3) ** 2 * s**2)
        sol = _solve_weighted(design, rhs, w1, equilibrate=True)
        if sol is None:
            return failed_fix("singular geometry")
        theta, cov1 = sol
        if np.any(theta[:2] <= 0):
            return self._refine(a, r, s, theta[:2] + origin, initial)
        jac2 = np.diag([2.0 * theta[0], 2.0 * theta[1], 1.0])
        h = np.array([theta[0] ** 2, theta[1] ** 2, theta[2]])
        g2 = np.array([[1.0, 0.0], [0.0, 1.0], [1.0, 1.0]])
        cov_h = jac2 @ cov1 @ jac2
        chol = np.linalg.cholesky(cov_h + 1e-18 * np.eye(3))
        sol2 = _solve_weighted(
            np.linalg.solve(chol, g2), np.linalg.solve(chol, h), np.ones(3), equilibrate=True
        )
        if sol2 is None:
            return failed_fix("singular geometry in step 2")
        z, _ = sol2
        x = np.sqrt(np.maximum(z, 0.0)) + origin
        return self._refine(a, r, s, x, initial)

    def _refine(
        self, a: FloatArray, r: FloatArray, s: FloatArray, x0: FloatArray, initial
    ) -> PositionFix:
        """Gauss-Newton to convergence from the two-step solution ``x0`` and, when tracking,
        from the prior ``initial``; the lower weighted cost wins (the ML solution of the
        ranges, with its covariance at it)."""
        starts = [x0]
        if initial is not None and np.all(np.isfinite(initial)):
            starts.append(np.asarray(initial, float))
        best = self._polish.best_of(a, r, s, starts)
        if best is None:
            return failed_fix("Gauss-Newton diverged")
        x, cov, _ = best
        return PositionFix(position=x, cov=cov, ok=True, residual_rms=_residual_rms(a, r, x))


LOCATORS: dict[str, type[Locator]] = {
    "lls": LinearLeastSquaresLocator,
    "taylor": TaylorSeriesLocator,
    "aml": ApproximateMlLocator,
}
"""Estimator class of each name (``uwbnet localize --method``)."""
