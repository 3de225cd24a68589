"""Compiled (numba) kernels of the node DSP's per-impulse-response hot paths.

A node runs these once per impulse response on a dozen detections and a few dozen mixture
components: loops that numpy cannot vectorize well (each small numpy call costs several
microseconds). They are pure functions of arrays (no I/O, no clocks) and are compiled on
first use with ``cache=True``, so later processes load the machine code from numba's
cache. When no cache directory is writable (read-only install and home), they are compiled
in memory in each process instead: slower to start, the same results.

``tests/unit/dsp/test_kernels.py`` compares every kernel with a plain Python reference.
"""

from __future__ import annotations

import math
import warnings

import numba
import numpy as np

# columns of a range GM-PHD component row (see node_agent.dsp.range_phd)
W, PRR, PRV, PVV, R, V, AMP, CH = range(8)
NCOL = 8
# entries of the parameter vector of range_phd_step
(
    P_PD,
    P_RANGE_VAR,
    P_KAPPA,
    P_BIRTH_WEIGHT,
    P_BIRTH_RATE_VAR,
    P_CLUSTER_GAP,
    P_PRUNE,
    P_MERGE,
    P_MAX_COMPONENTS,
    P_CH_SPAN,
) = range(10)
N_PARAMS = 10
# entries of the prediction vector of range_phd_step: x @ F + Q written out
(
    T_PS,
    T_DT,
    T_2DT,
    T_DT2,
    T_QRR,
    T_QRV,
    T_QVV,
) = range(7)
N_TRANSITION = 7
_SQRT_2PI = math.sqrt(2.0 * math.pi)


def _njit(signature):
    """``numba.njit(signature, cache=True)``: compiled (or loaded from numba's cache) when
    this module is imported, for one signature of any-layout arrays, so a node pays no
    compile during its first impulse responses (``signature`` None: a helper compiled into
    the kernels that call it). Without a writable cache directory
    (numba then refuses ``cache=True``), compiled in memory by every process instead."""

    def decorate(func):
        try:
            return numba.njit(signature, cache=True)(func)
        except RuntimeError as err:  # "cannot cache function ...: no locator available"
            warnings.warn(f"numba cache unavailable, compiling in memory: {err}", stacklevel=2)
            return numba.njit(signature)(func)

    return decorate


@_njit(
    "UniTuple(float64[:, :], 2)"
    "(float64[:, :], float64[:], float64[:], float64[:], intp[:], float64[:])"
)
def range_phd_step(x, transition, ranges, amplitudes, channels, par):  # pragma: no cover
    """One predict-cluster-update-prune-merge-extract cycle of the range GM-PHD.

    The per-receiver range GM-PHD of Section 9.2.1 of the CoLOR chapter (Vo and Ma's
    Gaussian-mixture PHD), for all receivers' mixtures at once on a channel-offset range
    axis (channel ``c`` at ``c * ch_span`` m). Component rows are
    ``(w, P_rr, P_rv, P_vv, r, v, amplitude, channel)``.

    Prediction (skipped when ``transition[T_DT] == 0``), :math:`m^- = F m`,
    :math:`P^- = F P F^T + Q`, :math:`w^- = p_S w` with :math:`F = [[1, \\Delta t], [0, 1]]`
    and :math:`Q = q [[\\Delta t^3/3, \\Delta t^2/2], [\\Delta t^2/2, \\Delta t]]`.
    Measurements: one per cluster of detections closer than ``cluster_gap``, at the
    power-weighted centre, with the cluster's peak amplitude. Update:

    .. math::

        w_j(z) = \\frac{p_D w_j \\mathcal{N}(z; m_{r,j}, S_j)}
        {\\kappa + p_D \\sum_l w_l \\mathcal{N}(z; m_{r,l}, S_l)}, \\quad
        w_j^{miss} = (1 - p_D) w_j, \\quad S_j = P_{rr,j} + \\sigma_r^2

    keeping the hypotheses of weight above the pruning threshold, with the Kalman update
    :math:`K = P H^T / S`, :math:`m + K (z - m_r)`, :math:`P - K H P`; a birth at each
    measurement of weight :math:`w_b \\kappa / (\\kappa + p_D \\sum_l w_l \\mathcal{N})`
    (the share of the measurement the mixture leaves unexplained). Then components
    below the pruning threshold are dropped, runs of range neighbours within the squared
    Mahalanobis gate (under the heavier one's covariance) are moment-matched, and the
    ``max_components`` heaviest are kept. Estimates are the components of weight above
    0.5, each repeated ``round(w)`` times when any weight reaches 1.5.

    Parameters
    ----------
    x : ndarray, float64, shape (n, 8)
        Components, sorted by channel-offset range.
    transition : ndarray, float64, shape (7,)
        ``(p_S, dt, 2 dt, dt^2, Q_rr, Q_rv, Q_vv)``; dt in s, ``dt == 0`` skips prediction.
    ranges, amplitudes : ndarray, float64, shape (k,)
        CFAR detections (bistatic range, m) and amplitudes, sorted by (channel, range).
    channels : ndarray, int, shape (k,)
        Receiver of each detection.
    par : ndarray, float64, shape (10,)
        ``(p_D, sigma_r^2, kappa, w_b, birth rate variance, cluster_gap, prune
        threshold, merge gate, max_components, ch_span)`` (units of
        :class:`~node_agent.dsp.range_phd.RangeGmPhdFilter`).

    Returns
    -------
    x : ndarray, float64, shape (n', 8)
        The new mixture, sorted by channel-offset range.
    est : ndarray, float64, shape (l, 5)
        Estimates ``(P_vv, range, rate, amplitude, channel)`` sorted by (channel, range),
        range in m from the receiver's own origin.
    """
    pd = par[P_PD]
    range_var = par[P_RANGE_VAR]
    kappa = par[P_KAPPA]
    prune = par[P_PRUNE]
    span = par[P_CH_SPAN]
    n = x.shape[0]

    # --- prediction: x @ F + Q ------------------------------------------------------------
    if transition[T_DT] != 0.0 and n > 0:
        ps, dt = transition[T_PS], transition[T_DT]
        dt2x, dtsq = transition[T_2DT], transition[T_DT2]
        y = np.empty((n, NCOL))
        for j in range(n):
            prr, prv, pvv = x[j, PRR], x[j, PRV], x[j, PVV]
            y[j, W] = x[j, W] * ps
            y[j, PRR] = (prr + prv * dt2x + pvv * dtsq) + transition[T_QRR]
            y[j, PRV] = (prv + pvv * dt) + transition[T_QRV]
            y[j, PVV] = pvv + transition[T_QVV]
            y[j, R] = x[j, R] + x[j, V] * dt
            y[j, V] = x[j, V]
            y[j, AMP] = x[j, AMP]
            y[j, CH] = x[j, CH]
        x = y

    # --- measurements: clusters of detections of one extended echo ---------------------------
    k = ranges.shape[0]
    key = np.empty(k)
    for i in range(k):
        key[i] = channels[i] * span + ranges[i]
    starts = np.empty(k, dtype=np.int64)
    m = 0
    for i in range(k):
        if i == 0 or key[i] - key[i - 1] > par[P_CLUSTER_GAP]:
            starts[m] = i
            m += 1
    z = np.empty(m)
    za = np.empty(m)
    zc = np.empty(m)
    for g in range(m):
        i0 = starts[g]
        i1 = starts[g + 1] if g + 1 < m else k
        if m == k:
            z[g] = key[i0]
        else:
            # power-weighted centre: the strongest scatterers of a body dominate its range
            p = amplitudes[i0] * amplitudes[i0]
            num = p * key[i0]
            den = p
            for i in range(i0 + 1, i1):
                p = amplitudes[i] * amplitudes[i]
                num += p * key[i]
                den += p
            z[g] = num / den
        amax = amplitudes[i0]
        for i in range(i0 + 1, i1):
            if amplitudes[i] > amax:
                amax = amplitudes[i]
        za[g] = amax
        zc[g] = channels[i0]

    # --- update ------------------------------------------------------------------------------
    if m == 0:
        u = np.empty((n, NCOL))
        for j in range(n):
            for c in range(NCOL):
                u[j, c] = x[j, c]
        for j in range(n):
            u[j, W] *= 1.0 - pd
    else:
        lik = np.empty((n, m))
        s = np.empty(n)
        den = np.empty(m)
        n_hyp = 0
        if n:
            coef = pd / _SQRT_2PI
            for j in range(n):
                s[j] = x[j, PRR] + range_var
                half = -0.5 / s[j]
                scale = x[j, W] * coef / math.sqrt(s[j])
                for g in range(m):
                    d = z[g] - x[j, R]  # exactly 0 likelihood across channels
                    lik[j, g] = math.exp(d * d * half) * scale
            for g in range(m):
                acc = lik[0, g]
                for j in range(1, n):
                    acc += lik[j, g]
                den[g] = acc + kappa
            for j in range(n):
                for g in range(m):
                    lik[j, g] /= den[g]
                    if lik[j, g] > prune:
                        n_hyp += 1
        u = np.empty((n + n_hyp + m, NCOL))
        miss = 1.0 - pd
        for j in range(n):
            for c in range(NCOL):
                u[j, c] = x[j, c]
            u[j, W] = x[j, W] * miss
        h = n
        for j in range(n):
            for g in range(m):
                if lik[j, g] > prune:
                    prr, prv = x[j, PRR], x[j, PRV]
                    kr = prr / s[j]
                    kv = prv / s[j]
                    d = z[g] - x[j, R]
                    u[h, W] = lik[j, g]
                    u[h, PRR] = prr - kr * prr
                    u[h, PRV] = prv - kr * prv
                    u[h, PVV] = x[j, PVV] - kv * prv
                    u[h, R] = x[j, R] + kr * d
                    u[h, V] = x[j, V] + kv * d
                    u[h, AMP] = za[g]
                    u[h, CH] = x[j, CH]
                    h += 1
        # adaptive birth at the measurements the mixture does not explain yet
        bk = par[P_BIRTH_WEIGHT] * kappa
        for g in range(m):
            u[h, W] = bk / den[g] if n else par[P_BIRTH_WEIGHT]
            u[h, PRR] = range_var
            u[h, PRV] = 0.0
            u[h, PVV] = par[P_BIRTH_RATE_VAR]
            u[h, R] = z[g]
            u[h, V] = 0.0
            u[h, AMP] = za[g]
            u[h, CH] = zc[g]
            h += 1

    # --- prune, merge runs of range neighbours, cap ------------------------------------------
    n_keep = 0
    for j in range(u.shape[0]):
        if u[j, W] > prune:
            n_keep += 1
    xp = np.empty((n_keep, NCOL))
    j2 = 0
    for j in range(u.shape[0]):
        if u[j, W] > prune:
            for c in range(NCOL):
                xp[j2, c] = u[j, c]
            j2 += 1
    n = n_keep
    if n > 1:
        # stable insertion sort by channel-offset range, in place: the rows arrive nearly
        # sorted (survivors, then hypotheses and births in range order per measurement),
        # and numba's np.argsort would add seconds to the first compile
        xs = xp
        row = np.empty(NCOL)
        for j in range(1, n):
            if xs[j, R] < xs[j - 1, R]:
                for c in range(NCOL):
                    row[c] = xs[j, c]
                i = j - 1
                while i >= 0 and xs[i, R] > row[R]:
                    for c in range(NCOL):
                        xs[i + 1, c] = xs[i, c]
                    i -= 1
                for c in range(NCOL):
                    xs[i + 1, c] = row[c]
        first = np.empty(n, dtype=np.bool_)
        first[0] = True
        n_groups = 1
        gate = par[P_MERGE]
        for j in range(1, n):
            dr = xs[j, R] - xs[j - 1, R]
            dv = xs[j, V] - xs[j - 1, V]
            hv = j if xs[j, W] >= xs[j - 1, W] else j - 1
            prr, prv, pvv = xs[hv, PRR], xs[hv, PRV], xs[hv, PVV]
            # d^T adj(P) d <= gate * det(P); a NaN distance starts a group
            d2 = (pvv * dr - 2.0 * prv * dv) * dr + prr * dv * dv
            joined = d2 <= gate * (prr * pvv - prv * prv)
            first[j] = not joined
            if not joined:
                n_groups += 1
        if n_groups < n:
            merged = np.zeros((n_groups, NCOL))
            g = -1
            j0 = 0
            for j in range(n + 1):
                if j == n or first[j]:
                    if g >= 0:
                        # moment matching over rows j0..j-1: weighted means of every
                        # column, plus the spread of the means
                        ws = xs[j0, W]
                        for i in range(j0 + 1, j):
                            ws += xs[i, W]
                        for c in range(NCOL):
                            acc = xs[j0, c] * xs[j0, W]
                            for i in range(j0 + 1, j):
                                acc += xs[i, c] * xs[i, W]
                            merged[g, c] = acc / ws
                        mr, mv = merged[g, R], merged[g, V]
                        srr = 0.0
                        srv = 0.0
                        svv = 0.0
                        for i in range(j0, j):
                            er = xs[i, R] - mr
                            ev = xs[i, V] - mv
                            wr = er * xs[i, W]
                            wv = ev * xs[i, W]
                            if i == j0:
                                srr, srv, svv = wr * er, wr * ev, wv * ev
                            else:
                                srr += wr * er
                                srv += wr * ev
                                svv += wv * ev
                        merged[g, PRR] += srr / ws
                        merged[g, PRV] += srv / ws
                        merged[g, PVV] += svv / ws
                        merged[g, W] = ws
                        # members share a channel; rint undoes the weighted mean's rounding
                        merged[g, CH] = np.rint(merged[g, CH])
                    g += 1
                    j0 = j
            xs = merged
        xp = xs
    cap = int(par[P_MAX_COMPONENTS])
    if xp.shape[0] > cap:
        # the heaviest, kept in (channel, range) order
        # the cap heaviest (of equal weights the first), kept in (channel, range) order
        xc = np.empty((cap, NCOL))
        j2 = 0
        for j in range(xp.shape[0]):
            heavier = 0
            for i in range(xp.shape[0]):
                if xp[i, W] > xp[j, W] or (xp[i, W] == xp[j, W] and i < j):
                    heavier += 1
            if heavier < cap:
                for c in range(NCOL):
                    xc[j2, c] = xp[j, c]
                j2 += 1
        xp = xc

    # --- extraction ------------------------------------------------------------------------
    n = xp.shape[0]
    n_est = 0
    repeat = False
    for j in range(n):
        if xp[j, W] > 0.5:
            n_est += 1
            if xp[j, W] >= 1.5:
                repeat = True
    if repeat:
        # a weight near 2 means two unresolved targets at that range
        n_est = 0
        for j in range(n):
            if xp[j, W] > 0.5:
                n_est += int(np.rint(xp[j, W]))
    est = np.empty((n_est, 5))
    e = 0
    for j in range(n):
        if xp[j, W] > 0.5:
            times = int(np.rint(xp[j, W])) if repeat else 1
            for _ in range(times):
                est[e, 0] = xp[j, PVV]
                est[e, 1] = xp[j, R] - xp[j, CH] * span
                est[e, 2] = xp[j, V]
                est[e, 3] = xp[j, AMP]
                est[e, 4] = xp[j, CH]
                e += 1
    return xp, est


@_njit(None)
def _cfar_real(s, var, k2, floor, padded_ranges, rates, half, step):  # pragma: no cover
    """The body of :func:`cfar_detect_real` (inlined into the compiled kernels that call it)."""
    n_rx, m = s.shape
    width = m + 2 * half
    clip2, a_noise, a_cross = rates[0], rates[1], rates[2]
    zero = np.float32(0.0)
    d2 = np.zeros(width, dtype=np.float32)  # one padded row of squared samples
    rate = np.empty(width, dtype=np.float32)
    cross = np.empty(m, dtype=np.intp)
    out_r = np.empty(n_rx * m)
    out_a = np.empty(n_rx * m)
    out_c = np.empty(n_rx * m, dtype=np.intp)
    n_out = 0
    frac_scale = 0.5 * step
    for row in range(n_rx):
        n_cross = 0
        for i in range(m):
            c = i + half
            v = s[row, i]
            d = v * v
            d2[c] = d
            if d > k2[row, c] * var[row, c]:
                cross[n_cross] = c
                n_cross += 1
        # the slow rate within a pulse width of a crossing (a passing person does not mask
        # itself), then the clipped variance update over the whole padded row
        for c in range(width):
            rate[c] = a_noise
        for q in range(n_cross):
            for c in range(cross[q] - half, cross[q] + half + 1):
                rate[c] = a_cross
        for c in range(width):
            vr = var[row, c]
            lim = vr * clip2
            st = d2[c]
            lo = st if (st < lim or st != st) else lim
            nv = vr + (lo - vr) * rate[c]
            fl = floor[row, c]
            var[row, c] = nv if (nv > fl or nv != nv) else fl
        # peaks: the first maximum within one pulse width
        for q in range(n_cross):
            c = cross[q]
            centre = d2[c]
            peak = True
            for j in range(c - half, c):
                if not d2[j] < centre:
                    peak = False
                    break
            if peak:
                for j in range(c + 1, c + half + 1):
                    if d2[j] > centre:
                        peak = False
                        break
            if not peak:
                continue
            a_m = math.sqrt(np.float64(d2[c - 1]))
            amp = math.sqrt(np.float64(centre))
            a_p = math.sqrt(np.float64(d2[c + 1]))
            den = a_m - 2.0 * amp + a_p
            frac = (a_m - a_p) / min(den, -1e-300)
            out_r[n_out] = padded_ranges[c] + frac * frac_scale
            out_a[n_out] = amp
            out_c[n_out] = row
            n_out += 1
        for c in range(half, width - half):
            d2[c] = zero
    return out_r[:n_out].copy(), out_a[:n_out].copy(), out_c[:n_out].copy()


@_njit(
    "Tuple((float64[:], float64[:], intp[:]))"
    "(float32[:, :], float32[:, :], float32[:, :], float32[:, :], float64[:], float32[:],"
    " intp, float64)"
)
def cfar_detect_real(s, var, k2, floor, padded_ranges, rates, half, step):  # pragma: no cover
    """One frame of the Gaussian adaptive-threshold (CFAR) detector on real samples.

    The Neyman-Pearson test of Section 9.2 of the CoLOR chapter, per range bin ``k``,
    :math:`y_k^2 > \\kappa_k \\sigma_k^2` with :math:`\\kappa_k = (\\sqrt{2}\\,
    \\operatorname{erfc}^{-1}(P_{fa}))^2` (infinite where the bin is switched off), then the
    exponential update of the noise variance with the squared sample clipped at
    ``clip2`` times the variance,

    .. math::

        \\sigma_k^2 \\leftarrow \\max\\big(\\sigma_k^2 + \\alpha_k (\\min(y_k^2,
        c\\, \\sigma_k^2) - \\sigma_k^2),\\ \\sigma_{floor}^2\\big)

    at the slow rate :math:`\\alpha_k = \\alpha_{cross}` within ``half`` bins of a crossing,
    :math:`\\alpha_{noise}` elsewhere. A crossing is a peak when its :math:`y_k^2` is the
    first maximum within ``half`` bins; its range is refined by the parabola through the
    envelope :math:`|y|` at the peak and its two neighbours. Arithmetic is float32 where
    the numpy form of :class:`~node_agent.dsp.cfar.GaussianCfarDetector` is, in the same
    order, so both give the same bits.

    Parameters
    ----------
    s : ndarray, float32, shape (n_rx, m)
        Background-subtracted samples of the range window.
    var : ndarray, float32, shape (n_rx, m + 2 half)
        Noise variance per padded bin; updated in place.
    k2, floor : ndarray, float32, shape (n_rx, m + 2 half)
        Squared threshold factor (inf: bin off) and variance floor per padded bin.
    padded_ranges : ndarray, float64, shape (m + 2 half,)
        Range of each padded bin, m.
    rates : ndarray, float32, shape (3,)
        ``(clip2, alpha_noise, alpha_cross)``.
    half : int
        Half the pulse width in bins (the padding on each side).
    step : float
        Range step between bins, m.

    Returns
    -------
    ranges, amplitudes : ndarray, float64, shape (k,)
        Detected ranges (m) and peak amplitudes :math:`|y_k|`, sorted by (row, range).
    rows : ndarray, intp, shape (k,)
        Row of ``s`` of each detection.
    """
    return _cfar_real(s, var, k2, floor, padded_ranges, rates, half, step)


def _background_cfar_signatures() -> list:
    """The signatures of :func:`background_cfar_real`: the impulse responses writable (a
    driver's) or read-only (decoded from a recording), the state C-contiguous (so that the
    loops vectorise)."""
    t = numba.types
    c2 = t.float32[:, ::1]
    ret = t.Tuple((t.float64[:], t.float64[:], t.intp[:]))
    rest = (t.float32, c2, c2, c2, c2, t.float64[::1], t.float32[::1], t.intp, t.float64)
    return [ret(h, c2, *rest) for h in (t.float32[:, :], t.Array(t.float32, 2, "A", readonly=True))]


@_njit(_background_cfar_signatures())
def background_cfar_real(
    h, background, alpha, y, var, k2, floor, padded_ranges, rates, half, step
):  # pragma: no cover
    """Background subtraction and CFAR detection of one frame of real samples, in one call.

    The exponential background of Section 9.2 of the CoLOR chapter
    (:class:`~node_agent.dsp.background.ExponentialBackgroundSubtractor`),
    :math:`y_k = h_k - b_{k-1}`, :math:`b_k = b_{k-1} + \\alpha y_k`, in float32 and in
    that order (the same bits as its numpy form), then :func:`cfar_detect_real` on
    :math:`y`. One compiled call instead of the subtractor's numpy calls and a second
    kernel call: a node runs it once per impulse response (issue 11, stop 20 notes).

    Parameters
    ----------
    h : ndarray, float32, shape (n_rx, m)
        Impulse responses over the range window (any strides, writable or read-only).
    background : ndarray, float32, shape (n_rx, m)
        The background :math:`b_{k-1}`; updated in place to :math:`b_k`.
    alpha : float32
        Forgetting factor of the background.
    y : ndarray, float32, shape (n_rx, m)
        Receives :math:`y_k` (the background-subtracted frame).
    var, k2, floor, padded_ranges, rates, half, step
        As for :func:`cfar_detect_real`.

    Returns
    -------
    As :func:`cfar_detect_real`.
    """
    n_rx, m = h.shape
    for row in range(n_rx):
        for i in range(m):
            d = h[row, i] - background[row, i]
            y[row, i] = d
            background[row, i] += d * alpha
    return _cfar_real(y, var, k2, floor, padded_ranges, rates, half, step)


@_njit(
    "Tuple((float64[:], float64[:], intp[:]))"
    "(float32[:, :], boolean[:, :], float32[:, :], float64, intp, intp, float64[:], float64)"
)
def integrated_peaks(
    padded, searched, noise_power, threshold, half, frames, ranges, step
):  # pragma: no cover
    """Peaks of the non-coherently integrated power above its threshold, one pass per row.

    The detection step of :class:`~node_agent.dsp.integration.NoncoherentIntegrator`
    (:func:`~node_agent.dsp.integration.integrated_peaks_reference` is its numpy form): a
    searched bin whose sum :math:`T_k` exceeds ``threshold`` is a peak when it is the first
    maximum within ``half`` bins; its range is refined by the parabola through
    :math:`\\sqrt{T}` at the peak and its two neighbours, its amplitude is the RMS echo
    amplitude :math:`\\sqrt{T_k P_k / N}`.

    Parameters
    ----------
    padded : ndarray, float32, shape (n_rx, m + 2 half)
        The sums :math:`T`, with ``half`` zero columns on each side.
    searched : ndarray, bool, shape (n_rx, m)
        Bins searched.
    noise_power : ndarray, float32, shape (n_rx, m)
        Expected power :math:`P_k` of each bin without a target.
    threshold : float
        Threshold on :math:`T`.
    half : int
        Half a pulse width in bins.
    frames : int
        :math:`N`.
    ranges : ndarray, float64, shape (m,)
        Range of each bin, m.
    step : float
        Range step, m.

    Returns
    -------
    ranges, amplitudes : ndarray, float64, shape (k,)
        Sorted by (row, range).
    rows : ndarray, intp, shape (k,)
    """
    n_rx, m = searched.shape
    out_r = np.empty(n_rx * m)
    out_a = np.empty(n_rx * m)
    out_c = np.empty(n_rx * m, dtype=np.intp)
    n_out = 0
    for row in range(n_rx):
        for i in range(m):
            c = i + half
            centre = padded[row, c]
            if not (centre > threshold and searched[row, i]):
                continue
            peak = True
            for j in range(c - half, c):
                if not padded[row, j] < centre:
                    peak = False
                    break
            if peak:
                for j in range(c + 1, c + half + 1):
                    if padded[row, j] > centre:
                        peak = False
                        break
            if not peak:
                continue
            a_m = math.sqrt(max(np.float64(padded[row, c - 1]), 0.0))
            a_0 = math.sqrt(np.float64(centre))
            a_p = math.sqrt(max(np.float64(padded[row, c + 1]), 0.0))
            den = a_m - 2.0 * a_0 + a_p
            out_r[n_out] = ranges[i] + 0.5 * step * (a_m - a_p) / min(den, -1e-300)
            out_a[n_out] = math.sqrt(np.float64(centre) / frames * np.float64(noise_power[row, i]))
            out_c[n_out] = row
            n_out += 1
    return out_r[:n_out].copy(), out_a[:n_out].copy(), out_c[:n_out].copy()
