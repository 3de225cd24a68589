"""Compiled (numba) kernels of the labelled GM-PHD tracker's per-scan hot path.

The fusion center's GM-PHD (:mod:`fusion_center.tracking.gmphd`) corrects a few dozen
Gaussian components with a handful of measurements per scan: every numpy call there costs
more than its arithmetic. These kernels do the correction (gating, weights, Kalman update),
pruning, merging and the per-label weight cap in one call each. They are pure functions of
arrays (no I/O, no clocks), compiled on import for one explicit signature with
``cache=True``; without a writable cache directory they are compiled in memory by every
process instead (slower to start, the same results).

They perform the same floating-point operations in the same order as the numpy reference
(:func:`fusion_center.tracking.gmphd.merge_components` and the numpy branch of
``GmPhdTracker._update``), so results differ at most by the rounding of ``exp`` and of
numpy's pairwise sums. ``tests/unit/tracking/test_kernels.py`` compares them.
"""

from __future__ import annotations

import math
import warnings

import numba
import numpy as np

_TWO_PI = 2.0 * math.pi


def _njit(signature):
    """``numba.njit(signature, cache=True)``, compiled (or loaded from numba's cache) at
    import; compiled in memory when numba has no writable cache directory."""

    def decorate(func):
        try:
            return numba.njit(signature, cache=True)(func)
        except RuntimeError as err:  # "cannot cache function ...: no locator available"
            warnings.warn(f"numba cache unavailable, compiling in memory: {err}", stacklevel=2)
            return numba.njit(signature)(func)

    return decorate


@_njit("int64[:](float64[:])")
def _argsort(key):  # pragma: no cover
    """Stable ascending argsort (``np.argsort(key, kind="stable")``): a bottom-up merge sort,
    written out because numba's generic sort costs seconds of compile time per kernel."""
    n = key.shape[0]
    order = np.arange(n)
    buf = np.empty(n, dtype=np.int64)
    width = 1
    while width < n:
        for lo in range(0, n, 2 * width):
            mid = min(lo + width, n)
            hi = min(lo + 2 * width, n)
            i, j = lo, mid
            for k in range(lo, hi):
                if j < hi and (i >= mid or key[order[j]] < key[order[i]]):
                    buf[k] = order[j]
                    j += 1
                else:
                    buf[k] = order[i]
                    i += 1
        order, buf = buf, order
        width *= 2
    return order


@_njit("void(float64[:], int64[:], float64)")
def _cap(w, label, cap):  # pragma: no cover
    """Scale each label's weights in place so that they sum to at most ``cap``."""
    n = w.shape[0]
    if n == 0 or math.isinf(cap):
        return
    order = _argsort(label.astype(np.float64))
    start = 0
    while start < n:
        stop = start
        total = 0.0
        while stop < n and label[order[stop]] == label[order[start]]:
            total += w[order[stop]]
            stop += 1
        scale = min(1.0, cap / max(total, 1e-300))
        for g in range(start, stop):
            w[order[g]] *= scale
        start = stop


_MIXTURE = "Tuple((float64[:], float64[:, :], float64[:, :, :], int64[:]))"


@_njit(
    _MIXTURE + "(float64[:], float64[:, :], float64[:, :, :], int64[:], int64[:], float64, float64)"
)
def merge_mixture(w, m, P, label, confirmed, threshold, cap):  # pragma: no cover
    """Greedy moment-matching merge (Vo & Ma 2006, Table II) and per-label weight cap.

    :func:`fusion_center.tracking.gmphd.merge_components` compiled: the heaviest remaining
    component ``l`` absorbs every remaining ``i`` within the squared Mahalanobis distance
    ``threshold`` under ``P_l``,

    .. math::

        (m_i - m_l)^T P_l^{-1} (m_i - m_l) \\le U,\\quad
        \\tilde w = \\sum_i w_i,\\quad
        \\tilde m = \\frac{1}{\\tilde w}\\sum_i w_i m_i,\\quad
        \\tilde P = \\frac{1}{\\tilde w}\\sum_i w_i \\left(P_i + (\\tilde m - m_i)
        (\\tilde m - m_i)^T\\right),

    never joining two components of different confirmed labels; a merged component keeps the
    label of its heaviest confirmed member, else of ``l``. Then each label's components are
    scaled so that their summed weight is at most ``cap`` (``inf``: no cap).

    Parameters
    ----------
    w : ndarray, float64, shape (J,)
    m : ndarray, float64, shape (J, 4)
        Means ``[x, vx, y, vy]``, m and m/s.
    P : ndarray, float64, shape (J, 4, 4)
    label : ndarray, int64, shape (J,)
    confirmed : ndarray, int64, shape (C,)
        Confirmed labels, sorted ascending (their components are "protected").
    threshold : float
        ``U``.
    cap : float
        Largest summed weight of one label.

    Returns
    -------
    w, m, P, label
        The merged mixture, sorted by decreasing weight (stable) before the cap.
    """
    n = w.shape[0]
    order = _argsort(-w)
    ws = np.empty(n)
    ms = np.empty((n, 4))
    Ps = np.empty((n, 4, 4))
    ls = np.empty(n, dtype=np.int64)
    prot = np.zeros(n, dtype=np.bool_)
    for i in range(n):
        o = order[i]
        ws[i] = w[o]
        ls[i] = label[o]
        for r in range(4):
            ms[i, r] = m[o, r]
            for c in range(4):
                Ps[i, r, c] = P[o, r, c]
        if confirmed.shape[0]:
            k = np.searchsorted(confirmed, ls[i])
            prot[i] = k < confirmed.shape[0] and confirmed[k] == ls[i]
    if n <= 1:
        _cap(ws, ls, cap)
        return ws, ms, Ps, ls

    # close[l, i]: i is within the gate of l under P_l (rows: leader candidates)
    close = np.zeros((n, n), dtype=np.bool_)
    for lead in range(n):
        a, b, c = Ps[lead, 0, 0], Ps[lead, 0, 2], Ps[lead, 2, 2]
        den = a * c - b * b
        have_block = False
        ia = ib = ic = b00 = b01 = b10 = b11 = s00 = s01 = s11 = s_det = 0.0
        for i in range(n):
            if i == lead:
                continue
            dx = ms[i, 0] - ms[lead, 0]
            dy = ms[i, 2] - ms[lead, 2]
            # position marginal first: a lower bound of the full distance
            d2 = (c * dx * dx - 2.0 * b * dx * dy + a * dy * dy) / den
            if d2 > threshold:
                continue
            if not have_block:
                # velocity part by the Schur complement (see gmphd._velocity_term)
                inv_det = 1.0 / (a * c - b * b)
                ia, ib, ic = c * inv_det, -b * inv_det, a * inv_det
                b00, b01, b10, b11 = Ps[lead, 0, 1], Ps[lead, 0, 3], Ps[lead, 2, 1], Ps[lead, 2, 3]
                g00, g01 = ia * b00 + ib * b10, ia * b01 + ib * b11
                g10, g11 = ib * b00 + ic * b10, ib * b01 + ic * b11
                s00 = Ps[lead, 1, 1] - (b00 * g00 + b10 * g10)
                s01 = Ps[lead, 1, 3] - (b00 * g01 + b10 * g11)
                s11 = Ps[lead, 3, 3] - (b01 * g01 + b11 * g11)
                s_det = s00 * s11 - s01 * s01
                have_block = True
            dvx = ms[i, 1] - ms[lead, 1]
            dvy = ms[i, 3] - ms[lead, 3]
            ux = ia * dx + ib * dy
            uy = ib * dx + ic * dy
            r0 = dvx - (b00 * ux + b10 * uy)
            r1 = dvy - (b01 * ux + b11 * uy)
            d2 = d2 + (s11 * r0 * r0 - 2.0 * s01 * r0 * r1 + s00 * r1 * r1) / s_det
            if d2 <= threshold and (ls[lead] == ls[i] or not (prot[lead] and prot[i])):
                close[lead, i] = True

    # components close to none are clusters of their own, numbered first
    assign = np.empty(n, dtype=np.int64)
    lonely = np.ones(n, dtype=np.bool_)
    for lead in range(n):
        for i in range(n):
            if close[lead, i]:
                lonely[lead] = False
                lonely[i] = False
    leaders = np.empty(n, dtype=np.int64)
    n_clusters = 0
    for i in range(n):
        if lonely[i]:
            assign[i] = n_clusters
            leaders[n_clusters] = i
            n_clusters += 1
    remaining = ~lonely
    for lead in range(n):  # the heaviest remaining leads: the arrays are weight-sorted
        if not remaining[lead]:
            continue
        for i in range(lead, n):
            if remaining[i] and (i == lead or close[lead, i]):
                assign[i] = n_clusters
                remaining[i] = False
        leaders[n_clusters] = lead
        n_clusters += 1
    if n_clusters == n:
        _cap(ws, ls, cap)
        return ws, ms, Ps, ls

    # moment matching, members in index (weight) order within each cluster
    grouped = _argsort(assign.astype(np.float64))
    w_new = np.zeros(n_clusters)
    m_new = np.zeros((n_clusters, 4))
    P_new = np.zeros((n_clusters, 4, 4))
    for g in range(n):
        i = grouped[g]
        w_new[assign[i]] += ws[i]
    for g in range(n):
        i = grouped[g]
        k = assign[i]
        for r in range(4):
            m_new[k, r] += ws[i] * ms[i, r]
    for k in range(n_clusters):
        for r in range(4):
            m_new[k, r] /= w_new[k]
    d = np.empty(4)
    for g in range(n):
        i = grouped[g]
        k = assign[i]
        for r in range(4):
            d[r] = ms[i, r] - m_new[k, r]
        for r in range(4):
            for c in range(4):
                P_new[k, r, c] += ws[i] * (Ps[i, r, c] + d[r] * d[c])
    for k in range(n_clusters):
        for r in range(4):
            for c in range(4):
                P_new[k, r, c] /= w_new[k]
    label_new = np.empty(n_clusters, dtype=np.int64)
    have_prot = np.zeros(n_clusters, dtype=np.bool_)
    for k in range(n_clusters):
        label_new[k] = ls[leaders[k]]
    for i in range(n):  # a confirmed track keeps its id: its heaviest member's label wins
        if prot[i] and not have_prot[assign[i]]:
            label_new[assign[i]] = ls[i]
            have_prot[assign[i]] = True

    by_weight = _argsort(-w_new)
    wo = np.empty(n_clusters)
    mo = np.empty((n_clusters, 4))
    Po = np.empty((n_clusters, 4, 4))
    lo = np.empty(n_clusters, dtype=np.int64)
    for i in range(n_clusters):
        o = by_weight[i]
        wo[i] = w_new[o]
        lo[i] = label_new[o]
        for r in range(4):
            mo[i, r] = m_new[o, r]
            for c in range(4):
                Po[i, r, c] = P_new[o, r, c]
    _cap(wo, lo, cap)
    return wo, mo, Po, lo


@_njit(
    "Tuple((float64[:], float64[:, :], float64[:, :, :], int64[:], float64[:], boolean[:],"
    " boolean[:, :]))"
    "(float64[:], float64[:, :], float64[:, :, :], int64[:], float64[:, :], float64[:],"
    " float64[:, :], float64[:, :, :], float64[:], int64[:], float64, float64, float64, float64)"
)
def gmphd_correct(
    w, m, P, label, detect, keep, z, R, kappa, confirmed, gate, prune, threshold, cap
):  # pragma: no cover
    """GM-PHD update with one scan, then prune, merge and cap (Vo & Ma 2006, eqs. (20)-(21)).

    For component ``j`` and measurement ``k`` (``H`` selects ``x, y``):

    .. math::

        S_{jk} = H P_j H^T + R_k,\\quad
        q_{jk} = \\mathcal N(z_k; H m_j, S_{jk}),\\quad
        w_{jk} = \\frac{w_j\\, D_{jk}\\, q_{jk}}{\\kappa_k + \\sum_i w_i\\, D_{ik}\\, q_{ik}}

    for the pairs within the squared Mahalanobis ``gate`` (others 0), Kalman means and
    covariances for the hypotheses above ``prune``, and the missed-detection components
    ``keep_j w_j``. The result is pruned (``w > prune``) and reduced by :func:`merge_mixture`.

    Parameters
    ----------
    w, m, P, label : ndarray, shapes (J,), (J, 4), (J, 4, 4), (J,)
        The predicted mixture, state ``[x, vx, y, vy]``.
    detect : ndarray, float64, shape (J, K)
        ``D_jk``: the probability of the detection pattern behind measurement ``k`` for
        component ``j`` (a sensor's ``p_D(m_j)`` for every ``k`` for a single scan).
    keep : ndarray, float64, shape (J,)
        Probability that component ``j`` goes undetected (``1 - p_D``).
    z : ndarray, float64, shape (K, 2)
        Measured positions, world x, y, m.
    R : ndarray, float64, shape (K, 2, 2)
        Their covariances, m².
    kappa : ndarray, float64, shape (K,)
        Clutter intensity at each measurement, 1/m².
    confirmed : ndarray, int64, shape (C,)
        Confirmed labels, sorted.
    gate, prune, threshold, cap : float
        Gate, pruning threshold, merge threshold ``U``, per-label weight cap.

    Returns
    -------
    w, m, P, label
        The corrected, merged mixture (see :func:`merge_mixture`).
    explained : ndarray, float64, shape (K,)
        Share of each measurement the mixture explains, ``Σ_j w_jk``.
    claimed : ndarray, bool, shape (K,)
        Whether the measurement is in the gate of a confirmed label's component.
    gated : ndarray, bool, shape (J, K)
        Component-measurement pairs within the gate.
    """
    n = w.shape[0]
    k_meas = z.shape[0]
    gated = np.zeros((n, k_meas), dtype=np.bool_)
    num = np.zeros((n, k_meas))
    d2s = np.empty((n, k_meas))
    dets = np.empty((n, k_meas))
    explained = np.zeros(k_meas)
    claimed = np.zeros(k_meas, dtype=np.bool_)
    total = np.zeros(k_meas)
    for j in range(n):
        owned = False
        if confirmed.shape[0]:
            c = np.searchsorted(confirmed, label[j])
            owned = c < confirmed.shape[0] and confirmed[c] == label[j]
        for k in range(k_meas):
            s00 = P[j, 0, 0] + R[k, 0, 0]
            s01 = P[j, 0, 2] + R[k, 0, 1]
            s11 = P[j, 2, 2] + R[k, 1, 1]
            det = s00 * s11 - s01 * s01
            n0 = z[k, 0] - m[j, 0]
            n1 = z[k, 1] - m[j, 2]
            d2 = (s11 * n0 * n0 - 2.0 * s01 * n0 * n1 + s00 * n1 * n1) / det
            d2s[j, k] = d2
            dets[j, k] = det
            if d2 < gate:
                gated[j, k] = True
                if owned:
                    claimed[k] = True
                q = math.exp(-0.5 * d2) / (_TWO_PI * math.sqrt(det))
                num[j, k] = w[j] * detect[j, k] * q
            total[k] += num[j, k]
    n_det = 0
    for k in range(k_meas):
        explained[k] = total[k] / (kappa[k] + total[k])
    for j in range(n):
        for k in range(k_meas):
            num[j, k] = num[j, k] / (kappa[k] + total[k])
            if num[j, k] > prune:
                n_det += 1
    # missed-detection components first, then the detections in (j, k) order
    size = n + n_det
    wu = np.empty(size)
    mu = np.empty((size, 4))
    Pu = np.empty((size, 4, 4))
    lu = np.empty(size, dtype=np.int64)
    for j in range(n):
        wu[j] = w[j] * keep[j]
        lu[j] = label[j]
        for r in range(4):
            mu[j, r] = m[j, r]
            for c in range(4):
                Pu[j, r, c] = P[j, r, c]
    i = n
    for j in range(n):
        for k in range(k_meas):
            if not num[j, k] > prune:
                continue
            s00 = P[j, 0, 0] + R[k, 0, 0]
            s01 = P[j, 0, 2] + R[k, 0, 1]
            s11 = P[j, 2, 2] + R[k, 1, 1]
            inv_det = 1.0 / dets[j, k]
            a, b, c = s11 * inv_det, -s01 * inv_det, s00 * inv_det
            v0 = z[k, 0] - m[j, 0]
            v1 = z[k, 1] - m[j, 2]
            wu[i] = num[j, k]
            lu[i] = label[j]
            for r in range(4):
                k0 = P[j, r, 0] * a + P[j, r, 2] * b  # K = P H^T S^{-1}
                k1 = P[j, r, 0] * b + P[j, r, 2] * c
                mu[i, r] = m[j, r] + k0 * v0 + k1 * v1
                for s in range(4):
                    Pu[i, r, s] = P[j, r, s] - k0 * P[j, s, 0] - k1 * P[j, s, 2]
            i += 1
    # prune, then merge and cap
    keep_idx = np.flatnonzero(wu > prune)
    wr, mr, Pr, lr = merge_mixture(
        wu[keep_idx], mu[keep_idx], Pu[keep_idx], lu[keep_idx], confirmed, threshold, cap
    )
    return wr, mr, Pr, lr, explained, claimed, gated


@_njit(
    _MIXTURE + "(float64[:], float64[:, :], float64[:, :, :], float64[:, :], float64[:, :],"
    " float64, float64, float64)"
)
def predict_mixture(w, m, P, F, Q, ps, maneuver_weight, maneuver_var):  # pragma: no cover
    """GM-PHD prediction (Vo & Ma 2006, eqs. (16)-(17)) with the manoeuvre copies.

    :math:`w \\leftarrow p_S w`, :math:`m \\leftarrow F m`, :math:`P \\leftarrow F P F^T + Q`;
    then every component heavier than 0.3 gives ``maneuver_weight`` of its weight to a copy
    with the velocity reset to zero, variance ``maneuver_var`` per axis (see
    ``GmPhdTracker._predict``).

    Parameters
    ----------
    w, m, P : ndarray, shapes (J,), (J, 4), (J, 4, 4)
        The mixture, state ``[x, vx, y, vy]``.
    F, Q : ndarray, float64, shape (4, 4)
        Transition matrix and process noise covariance of the step.
    ps : float
        Survival probability of the step.
    maneuver_weight, maneuver_var : float
        Share of weight of a manoeuvre copy (0: none) and its velocity variance, m²/s².

    Returns
    -------
    w, m, P : the predicted components, then the copies
    src : ndarray, int64, shape (J + copies,)
        The component each came from (for its label).
    """
    n = w.shape[0]
    n_copy = 0
    if maneuver_weight > 0.0:
        for j in range(n):
            if w[j] * ps > 0.3:
                n_copy += 1
    size = n + n_copy
    wo = np.empty(size)
    mo = np.empty((size, 4))
    Po = np.empty((size, 4, 4))
    src = np.empty(size, dtype=np.int64)
    fp = np.empty((4, 4))
    for j in range(n):
        wo[j] = w[j] * ps
        src[j] = j
        for r in range(4):
            acc = 0.0
            for c in range(4):
                acc += m[j, c] * F[r, c]
            mo[j, r] = acc
            for c in range(4):
                acc = 0.0
                for k in range(4):
                    acc += F[r, k] * P[j, k, c]
                fp[r, c] = acc
        for r in range(4):
            for c in range(4):
                acc = 0.0
                for k in range(4):
                    acc += fp[r, k] * F[c, k]
                Po[j, r, c] = acc + Q[r, c]
    i = n
    for j in range(n):
        if n_copy == 0 or not wo[j] > 0.3:
            continue
        wc = wo[j] * maneuver_weight
        wo[j] -= wc
        wo[i] = wc
        src[i] = j
        for r in range(4):
            mo[i, r] = mo[j, r] if r % 2 == 0 else 0.0
            for c in range(4):
                Po[i, r, c] = Po[j, r, c] if r % 2 == 0 and c % 2 == 0 else 0.0
        Po[i, 1, 1] = maneuver_var
        Po[i, 3, 3] = maneuver_var
        i += 1
    return wo, mo, Po, src


@_njit(
    "Tuple((float64[:], float64[:, :], float64[:, :, :]))"
    "(float64[:, :], float64[:, :, :], float64[:], boolean[:], float64, float64, float64)"
)
def seed_births(
    z, R, explained, claimed, max_association, weight, velocity_var
):  # pragma: no cover
    """Adaptive birth (Ristic, Clark, Vo & Vo 2012): one component per measurement that the
    mixture explains by less than ``max_association`` and no confirmed track claims.

    Parameters
    ----------
    z : ndarray, float64, shape (K, 2)
        Measured positions, m.
    R : ndarray, float64, shape (K, 2, 2)
        Their covariances, m² (the birth's position covariance).
    explained : ndarray, float64, shape (K,)
        Share ``r`` of each measurement explained by the mixture.
    claimed : ndarray, bool, shape (K,)
    max_association, weight, velocity_var : float
        ``birth_max_association``, ``birth_weight`` (a birth weighs ``weight (1 - r)``) and
        the velocity variance per axis, m²/s².

    Returns
    -------
    w, m, P : the births, in measurement order, state ``[x, vx, y, vy]``
    """
    k_meas = z.shape[0]
    n = 0
    for k in range(k_meas):
        if explained[k] < max_association and not claimed[k]:
            n += 1
    w = np.empty(n)
    m = np.zeros((n, 4))
    P = np.zeros((n, 4, 4))
    i = 0
    for k in range(k_meas):
        if not (explained[k] < max_association and not claimed[k]):
            continue
        w[i] = weight * (1.0 - explained[k])
        m[i, 0], m[i, 2] = z[k, 0], z[k, 1]
        P[i, 0, 0], P[i, 0, 2], P[i, 2, 0], P[i, 2, 2] = (
            R[k, 0, 0],
            R[k, 0, 1],
            R[k, 1, 0],
            R[k, 1, 1],
        )
        P[i, 1, 1] = P[i, 3, 3] = velocity_var
        i += 1
    return w, m, P


@_njit(_MIXTURE + "(float64[:], float64[:, :], float64[:, :, :], int64[:], float64)")
def merge_births(w, m, P, label, cluster_distance):  # pragma: no cover
    """One birth per person: leader clustering of one step's births within
    ``cluster_distance`` (m), moment-matched, weights summed and capped at 1, the first
    birth's label (``GmPhdTracker._merge_births``).

    Parameters
    ----------
    w, m, P, label : ndarray, shapes (B,), (B, 4), (B, 4, 4), (B,)

    Returns
    -------
    w, m, P, label : the merged births, one per group, in order of their first member
    """
    n = w.shape[0]
    group = np.full(n, -1, dtype=np.int64)
    k = 0
    for i in range(n):
        if group[i] >= 0:
            continue
        for j in range(n):
            if group[j] < 0:
                dx = m[i, 0] - m[j, 0]
                dy = m[i, 2] - m[j, 2]
                if math.sqrt(dx * dx + dy * dy) <= cluster_distance:
                    group[j] = k
        k += 1
    if k == n:
        return w.copy(), m.copy(), P.copy(), label.copy()
    wo = np.zeros(k)
    mo = np.zeros((k, 4))
    Po = np.zeros((k, 4, 4))
    lo = np.empty(k, dtype=np.int64)
    first = np.full(k, -1, dtype=np.int64)
    for i in range(n):
        g = group[i]
        wo[g] += w[i]
        if first[g] < 0:
            first[g] = i
            lo[g] = label[i]
    for i in range(n):
        for r in range(4):
            mo[group[i], r] += w[i] * m[i, r]
    for g in range(k):
        for r in range(4):
            mo[g, r] /= wo[g]
    d = np.empty(4)
    for i in range(n):
        g = group[i]
        for r in range(4):
            d[r] = m[i, r] - mo[g, r]
        for r in range(4):
            for c in range(4):
                Po[g, r, c] += w[i] * (P[i, r, c] + d[r] * d[c])
    for g in range(k):
        for r in range(4):
            for c in range(4):
                Po[g, r, c] /= wo[g]
        wo[g] = min(wo[g], 1.0)
    return wo, mo, Po, lo


@_njit("int64[:](float64[:], int64[:])")
def _by_label(w, label):  # pragma: no cover
    """Indices sorted by label, then by decreasing weight (``np.lexsort((-w, label))``)."""
    by_weight = _argsort(-w)
    return by_weight[_argsort(label[by_weight].astype(np.float64))]


@_njit(
    "Tuple((int64[:], int64[:], float64[:], int64))"
    "(float64[:], float64[:, :], float64[:, :, :], int64[:], float64, float64, int64)"
)
def label_heads(w, m, P, label, split_threshold, merge_threshold, next_label):  # pragma: no cover
    """Per label, its heaviest component and summed weight (``GmPhdTracker._extract``).

    First a component of a label other than its heaviest (the head) that weighs at least
    ``split_threshold`` and lies beyond the squared Mahalanobis distance ``merge_threshold``
    from the head (positions, under the head's position covariance) gets a fresh label
    ``next_label, next_label + 1, ...``, in (label, decreasing weight) order: it is another
    person.

    Parameters
    ----------
    w, m, P, label : ndarray, shapes (J,), (J, 4), (J, 4, 4), (J,)
    split_threshold, merge_threshold : float
    next_label : int

    Returns
    -------
    label : ndarray, int64, shape (J,)
        The labels after splitting (a new array).
    heads : ndarray, int64, shape (L,)
        Each label's heaviest component (first of equal weights), in ascending label order.
    label_w : ndarray, float64, shape (L,)
        Each label's summed weight.
    next_label : int
        The next unused label.
    """
    n = w.shape[0]
    orig = label
    label = label.copy()
    order = _by_label(w, label)
    head = -1
    for g in range(n):
        i = order[g]
        if g == 0 or orig[i] != orig[order[g - 1]]:
            head = i
            continue
        if w[i] < split_threshold:
            continue
        dx = m[i, 0] - m[head, 0]
        dy = m[i, 2] - m[head, 2]
        a, b, c = P[head, 0, 0], P[head, 0, 2], P[head, 2, 2]
        if (c * dx * dx - 2.0 * b * dx * dy + a * dy * dy) / (a * c - b * b) > merge_threshold:
            label[i] = next_label
            next_label += 1
    order = _by_label(w, label)
    n_labels = 0
    for g in range(n):
        if g == 0 or label[order[g]] != label[order[g - 1]]:
            n_labels += 1
    heads = np.empty(n_labels, dtype=np.int64)
    label_w = np.zeros(n_labels)
    h = -1
    for g in range(n):
        i = order[g]
        if g == 0 or label[i] != label[order[g - 1]]:
            h += 1
            heads[h] = i
        label_w[h] += w[i]
    return label, heads, label_w, next_label


@_njit("int64[:, :](float64[:], float64[:, :], int64[:], float64, float64, float64)")
def duplicate_pairs(w, m, label, min_weight, distance, velocity):  # pragma: no cover
    """Pairs of labels whose heads (heaviest components, if above ``min_weight``) are within
    ``distance`` (m) in position and ``velocity`` (m/s) in velocity
    (``GmPhdTracker._fold_duplicate_labels``).

    Returns
    -------
    ndarray, int64, shape (n, 2)
        ``(a, b)`` with ``a < b``, in ascending order of ``a`` then ``b``; shape (0, 1) when
        fewer than two labels have a head above ``min_weight``.
    """
    n = w.shape[0]
    order = _by_label(w, label)
    heads = np.empty(n, dtype=np.int64)
    n_heads = 0
    for g in range(n):
        i = order[g]
        if (g == 0 or label[i] != label[order[g - 1]]) and w[i] > min_weight:
            heads[n_heads] = i
            n_heads += 1
    if n_heads < 2:
        return np.empty((0, 1), dtype=np.int64)
    out = np.empty((n_heads * (n_heads - 1) // 2, 2), dtype=np.int64)
    n_pairs = 0
    for a in range(n_heads):
        i = heads[a]
        for b in range(a + 1, n_heads):
            j = heads[b]
            dx, dy = m[i, 0] - m[j, 0], m[i, 2] - m[j, 2]
            dvx, dvy = m[i, 1] - m[j, 1], m[i, 3] - m[j, 3]
            if (
                math.sqrt(dx * dx + dy * dy) < distance
                and math.sqrt(dvx * dvx + dvy * dvy) < velocity
            ):
                out[n_pairs, 0] = label[i]
                out[n_pairs, 1] = label[j]
                n_pairs += 1
    return out[:n_pairs]


@_njit("boolean[:, :](float64[:], float64[:, :], int64[:], float64[:, :], boolean[:, :], float64)")
def occluded(w, m, label, origins, mask, radius):  # pragma: no cover
    """Components shadowed for each sensor (``GmPhdTracker._occluded_many``): a component
    of another label heavier than 0.3 stands nearer to the sensor, less than ``radius``
    (m) from the line of sight and more than ``2 radius`` before the component.

    Parameters
    ----------
    w, m, label : ndarray, shapes (J,), (J, 4), (J,)
    origins : ndarray, float64, shape (S, 2)
        The sensors' positions, m.
    mask : ndarray, bool, shape (J, S)
        The pairs to test (those a sensor can see); the others are False.
    radius : float

    Returns
    -------
    ndarray, bool, shape (J, S)
    """
    n, n_s = w.shape[0], origins.shape[0]
    out = np.zeros((n, n_s), dtype=np.bool_)
    heavy = np.flatnonzero(w > 0.3)
    if heavy.shape[0] == 0:
        return out
    for s in range(n_s):
        ox, oy = origins[s, 0], origins[s, 1]
        for j in range(n):
            if not mask[j, s]:
                continue
            x, y = m[j, 0] - ox, m[j, 2] - oy
            dist = math.sqrt(x * x + y * y)
            ux, uy = x / max(dist, 1e-9), y / max(dist, 1e-9)
            for o in heavy:
                px, py = m[o, 0] - ox, m[o, 2] - oy
                along = px * ux + py * uy
                if (
                    along > 0.0
                    and along < dist - 2.0 * radius
                    and abs(px * uy - py * ux) < radius
                    and label[o] != label[j]
                ):
                    out[j, s] = True
                    break
    return out


@_njit("int64[:](float64[:, :], float64[:, :], float64[:, :], float64[:, :], float64)")
def wall_crossings(origins, xy, start, end, margin):  # pragma: no cover
    """Number of walls each sight line ``origins[k]`` -> ``xy[k]`` crosses
    (``WallSightModel.pairs``): the same arithmetic per (line, wall) as the numpy reference
    (:meth:`fusion_center.tracking.walls.WallSightModel.crossings`), so the same counts.

    Parameters
    ----------
    origins, xy : ndarray, float64, shape (K, 2)
        Ends of the sight lines, world x, y, m.
    start, end : ndarray, float64, shape (W, 2)
        Wall segments, m.
    margin : float
        A wall crossed within this fraction of the sight line's ends does not count.

    Returns
    -------
    ndarray, int64, shape (K,)
    """
    n_k, n_w = xy.shape[0], start.shape[0]
    out = np.zeros(n_k, dtype=np.int64)
    upper = 1 - margin
    for k in range(n_k):
        ox, oy = origins[k, 0], origins[k, 1]
        rx, ry = xy[k, 0] - ox, xy[k, 1] - oy
        for i in range(n_w):
            ex, ey = end[i, 0] - start[i, 0], end[i, 1] - start[i, 1]
            wx, wy = start[i, 0] - ox, start[i, 1] - oy
            den = rx * ey - ry * ex
            if den == 0.0:
                continue  # parallel: the reference's u and s are inf or nan, never a hit
            u = (wx * ey - wy * ex) / den
            s = (wx * ry - wy * rx) / den
            if u > margin and u < upper and s >= 0.0 and s <= 1.0:
                out[k] += 1
    return out


@_njit(
    "Tuple((int64[:], int64[:], float64[:], float64[:], float64[:]))"
    "(float64[:, :], float64[:, :], float64[:], float64[:])"
)
def range_pairs(xy, origin, hi2, lo2):  # pragma: no cover
    """The (component, sensor) pairs of a frame within the sensors' distance limits
    (``GmPhdTracker._frame_detection``): ``lo2[s] <= r2 <= hi2[s]`` with ``r2`` the squared
    distance ``dx * dx + dy * dy`` from sensor ``s`` at ``origin[s]`` to the component at
    ``xy[j]``, the same products and sum as the numpy reference's
    ``einsum("jsi,jsi->js", d, d)``, so the same pairs.

    Parameters
    ----------
    xy : ndarray, float64, shape (J, 2)
        Component positions, world x, y, m.
    origin : ndarray, float64, shape (S, 2)
        Sensor array centres, m.
    hi2, lo2 : ndarray, float64, shape (S,)
        Squared largest and smallest distance, m².

    Returns
    -------
    j, s : ndarray, int64, shape (P,)
        The pairs, in row-major (j, s) order (that of ``np.nonzero`` on a (J, S) mask).
    dx, dy, r2 : ndarray, float64, shape (P,)
        ``xy[j] - origin[s]`` and its squared length.
    """
    n_j, n_s = xy.shape[0], origin.shape[0]
    jj = np.empty(n_j * n_s, dtype=np.int64)
    ss = np.empty(n_j * n_s, dtype=np.int64)
    ddx = np.empty(n_j * n_s)
    ddy = np.empty(n_j * n_s)
    rr = np.empty(n_j * n_s)
    n = 0
    for j in range(n_j):
        x, y = xy[j, 0], xy[j, 1]
        for s in range(n_s):
            dx, dy = x - origin[s, 0], y - origin[s, 1]
            r2 = dx * dx + dy * dy
            if r2 <= hi2[s] and r2 >= lo2[s]:
                jj[n], ss[n], ddx[n], ddy[n], rr[n] = j, s, dx, dy, r2
                n += 1
    return jj[:n], ss[:n], ddx[:n], ddy[:n], rr[:n]
