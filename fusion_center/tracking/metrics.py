"""Multi-target tracking metrics: OSPA, GOSPA and a track-evaluation summary.

References
----------
Schuhmacher, Vo & Vo (2008), "A consistent metric for performance evaluation of
multi-object filters", IEEE Trans. Signal Process. 56(8) (OSPA).
Rahmathullah, García-Fernández & Svensson (2017), "Generalized optimal sub-pattern
assignment metric", FUSION 2017 (GOSPA).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import numpy.typing as npt
from scipy.optimize import linear_sum_assignment

__all__ = ["evaluate", "gospa", "ospa"]

FloatArray = npt.NDArray[np.float64]


def _as_points(X: npt.ArrayLike) -> FloatArray:
    a = np.asarray(X, dtype=np.float64)
    if a.ndim == 2:
        return a
    if a.size == 0:
        return a.reshape(0, 2)
    return a.reshape(1, -1) if a.ndim == 1 else a.reshape(a.shape[0], -1)


def _distances(X: FloatArray, Y: FloatArray) -> FloatArray:
    return np.sqrt(((X[:, None, :] - Y[None, :, :]) ** 2).sum(axis=-1))


def ospa(X: npt.ArrayLike, Y: npt.ArrayLike, c: float = 1.0, p: float = 1.0) -> float:
    """OSPA distance of order ``p`` with cut-off ``c`` (Schuhmacher et al. 2008, eq. (3)).

    .. math::

        \\bar d_p^{(c)}(X, Y) = \\left(\\frac{1}{n}\\left(\\min_{\\pi \\in \\Pi_n}
        \\sum_{i=1}^{m} d^{(c)}(x_i, y_{\\pi(i)})^p + c^p (n - m)\\right)\\right)^{1/p},
        \\qquad d^{(c)} = \\min(c, \\lVert x - y \\rVert),\\ m \\le n

    Parameters
    ----------
    X, Y : array_like, shape (m, d) and (n, d)
        Point sets (e.g. positions, m).
    c : float
        Cut-off, same unit as the points.
    p : float
        Order, ``>= 1``.

    Returns
    -------
    float
        0 when both sets are empty; ``c`` when exactly one is.
    """
    X, Y = _as_points(X), _as_points(Y)
    m, n = X.shape[0], Y.shape[0]
    if m == 0 and n == 0:
        return 0.0
    if m == 0 or n == 0:
        return float(c)
    if m > n:
        X, Y, m, n = Y, X, n, m
    D = np.minimum(_distances(X, Y), c) ** p
    rows, cols = linear_sum_assignment(D)
    total = D[rows, cols].sum() + c**p * (n - m)
    return float((total / n) ** (1.0 / p))


def gospa(
    X: npt.ArrayLike, Y: npt.ArrayLike, c: float = 1.0, p: float = 1.0, alpha: float = 2.0
) -> tuple[float, float, float, float]:
    """GOSPA distance (Rahmathullah et al. 2017, eq. (1)) and, for ``alpha = 2``, its parts.

    .. math::

        d_p^{(c,\\alpha)}(X, Y) = \\left(\\min_{\\pi}\\sum_{i=1}^{m}
        d^{(c)}(x_i, y_{\\pi(i)})^p + \\frac{c^p}{\\alpha}(n - m)\\right)^{1/p},\\ m \\le n

    With ``alpha = 2`` this equals (their Proposition 1)

    .. math::

        \\left(\\sum_{(i,j) \\in \\gamma} d(x_i, y_j)^p + \\frac{c^p}{2}(|X| - |\\gamma|)
        + \\frac{c^p}{2}(|Y| - |\\gamma|)\\right)^{1/p}

    over assignments ``γ`` of pairs closer than ``c``: localisation, missed and false parts.

    Parameters
    ----------
    X : array_like, shape (m, d)
        Truth.
    Y : array_like, shape (n, d)
        Estimates.
    c, p, alpha : float
        Cut-off, order (``>= 1``) and cardinality-mismatch exponent (``0 < alpha <= 2``).

    Returns
    -------
    total : float
        ``d_p^{(c, alpha)}``.
    localisation, missed, false : float
        The three summands *before* the ``1/p`` root (``total**p`` is their sum). For
        ``alpha != 2`` pairs farther than ``c`` count as localisation at ``c^p``.
    """
    X, Y = _as_points(X), _as_points(Y)
    m, n = X.shape[0], Y.shape[0]
    half = c**p / alpha
    if m == 0 or n == 0:
        missed, false = half * m, half * n
        return float((missed + false) ** (1.0 / p)), 0.0, float(missed), float(false)
    d = _distances(X, Y)
    D = np.minimum(d, c) ** p
    rows, cols = linear_sum_assignment(D)
    dp = D[rows, cols]
    if alpha == 2.0:
        real = d[rows, cols] < c
        n_pairs = int(real.sum())
        localisation = float(dp[real].sum())
    else:
        n_pairs = rows.size
        localisation = float(dp.sum())
    missed = half * (m - n_pairs)
    false = half * (n - n_pairs)
    total = localisation + missed + false
    return float(total ** (1.0 / p)), localisation, float(missed), float(false)


def _interpolate_truth(
    truth: Sequence[tuple[float, npt.ArrayLike, npt.ArrayLike]], t: float
) -> tuple[npt.NDArray[np.int64], FloatArray] | None:
    """Truth at ``t``: linear interpolation between the bracketing truth samples."""
    times = np.array([s[0] for s in truth], dtype=np.float64)
    if t < times[0] or t > times[-1]:
        return None
    i = int(np.searchsorted(times, t, side="right")) - 1
    ids0 = np.asarray(truth[i][1], dtype=np.int64)
    xy0 = _as_points(truth[i][2])
    if times[i] == t or i + 1 >= len(truth):
        return ids0, xy0
    ids1 = np.asarray(truth[i + 1][1], dtype=np.int64)
    xy1 = _as_points(truth[i + 1][2])
    common, i0, i1 = np.intersect1d(ids0, ids1, assume_unique=True, return_indices=True)
    a = (t - times[i]) / (times[i + 1] - times[i])
    return common, (1.0 - a) * xy0[i0] + a * xy1[i1]


def _correspond(
    ids: npt.NDArray[np.int64],
    est_ids: npt.NDArray[np.int64],
    d: FloatArray,
    last_id: dict[int, int],
    c: float,
) -> list[tuple[int, int, float]]:
    """Truth-track correspondences of one update, CLEAR-MOT style.

    A truth target keeps last update's track while that track is present and within ``c``
    (so two people crossing inside the noise do not count as swaps); the remaining targets
    and tracks are paired by minimum total distance, pairs closer than ``c`` only.
    """
    keep_r, keep_c = [], []
    col_of = {int(e): j for j, e in enumerate(est_ids.tolist())}
    for r, tid in enumerate(ids.tolist()):
        j = col_of.get(last_id.get(tid, -1), -1) if tid in last_id else -1
        if j >= 0 and j not in keep_c and d[r, j] < c:
            keep_r.append(r)
            keep_c.append(j)
    free_r = np.setdiff1d(np.arange(d.shape[0]), keep_r)
    free_c = np.setdiff1d(np.arange(d.shape[1]), keep_c)
    rows, cols = list(keep_r), list(keep_c)
    if free_r.size and free_c.size:
        sub = d[np.ix_(free_r, free_c)]
        rr, cc = linear_sum_assignment(sub)
        ok = sub[rr, cc] < c
        rows += free_r[rr[ok]].tolist()
        cols += free_c[cc[ok]].tolist()
    return [(int(ids[r]), int(est_ids[j]), float(d[r, j])) for r, j in zip(rows, cols, strict=True)]


def evaluate(
    truth: Sequence[tuple[float, npt.ArrayLike, npt.ArrayLike]],
    tracks: Sequence[tuple[float, npt.ArrayLike, npt.ArrayLike]],
    c: float = 1.0,
    skip: float = 0.0,
) -> dict[str, float | int | dict[str, float] | None]:
    """Evaluate a tracker's output against the truth.

    Parameters
    ----------
    truth : sequence of (t, ids (m,), xy (m, 2))
        Truth samples, increasing in ``t``; positions are linearly interpolated in time to
        each evaluation time, per id, for ids present in both bracketing samples.
    tracks : sequence of (t, ids (n,), xy (n, 2))
        Tracker updates; their times are the evaluation times.
    c : float
        Cut-off of OSPA/GOSPA and the association radius of ID switches and RMSE, m.
    skip : float
        Updates earlier than ``first truth time + skip`` are ignored (warm-up), s.

    Returns
    -------
    dict
        JSON-serialisable: ``ospa_p1_mean``, ``ospa_p2_mean``, ``gospa_p1_mean``,
        ``gospa_p2_mean`` (alpha 2), ``card_correct_fraction``, ``card_error_mean``,
        ``id_switches`` (per truth target, changes of the track id assigned to it within ``c``,
        gaps ignored, summed over targets; a target keeps its previous track while that
        track stays within ``c``, as in CLEAR MOT, Bernardin & Stiefelhagen 2008),
        ``rmse`` (per truth id, over the updates where the target is assigned; keys are
        ``str(id)``), ``rmse_mean`` and ``n_updates``.
        Means are ``None`` when no update was evaluated.
    """
    keys = ("ospa_p1", "ospa_p2", "gospa_p1", "gospa_p2", "card_ok", "card_err")
    acc: dict[str, list[float]] = {k: [] for k in keys}
    last_id: dict[int, int] = {}
    switches = 0
    sq_err: dict[int, list[float]] = {}
    if not truth:
        raise ValueError("truth is empty")
    t_start = float(truth[0][0]) + skip
    for t, tids, txy in tracks:
        if t < t_start:
            continue
        sample = _interpolate_truth(truth, float(t))
        if sample is None:
            continue
        ids, X = sample
        Y = _as_points(txy)
        est_ids = np.asarray(tids, dtype=np.int64).reshape(-1)
        acc["ospa_p1"].append(ospa(X, Y, c, 1.0))
        acc["ospa_p2"].append(ospa(X, Y, c, 2.0))
        acc["gospa_p1"].append(gospa(X, Y, c, 1.0)[0])
        acc["gospa_p2"].append(gospa(X, Y, c, 2.0)[0])
        acc["card_ok"].append(float(X.shape[0] == Y.shape[0]))
        acc["card_err"].append(float(abs(X.shape[0] - Y.shape[0])))
        if X.shape[0] and Y.shape[0]:
            pairs = _correspond(ids, est_ids, _distances(X, Y), last_id, c)
            for truth_id, track_id, dist in pairs:
                prev = last_id.get(truth_id)
                if prev is not None and prev != track_id:
                    switches += 1
                last_id[truth_id] = track_id
                sq_err.setdefault(truth_id, []).append(dist**2)
    rmse = {str(k): float(np.sqrt(np.mean(v))) for k, v in sorted(sq_err.items())}
    n = len(acc["ospa_p1"])

    def mean(key: str) -> float | None:
        return float(np.mean(acc[key])) if n else None

    return {
        "ospa_p1_mean": mean("ospa_p1"),
        "ospa_p2_mean": mean("ospa_p2"),
        "gospa_p1_mean": mean("gospa_p1"),
        "gospa_p2_mean": mean("gospa_p2"),
        "card_correct_fraction": mean("card_ok"),
        "card_error_mean": mean("card_err"),
        "id_switches": switches,
        "rmse": rmse,
        "rmse_mean": float(np.mean(list(rmse.values()))) if rmse else None,
        "n_updates": n,
    }
