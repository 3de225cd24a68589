"""The optimised node DSP against straightforward reference implementations.

The chain's hot functions are restructured for few numpy calls per impulse response
(``uwbnet bench dsp``); these references follow the docstrings' formulas literally, one
receiver, component and detection at a time, and must agree on seeded random inputs up to
float rounding (the GM-PHD keeps ranges on a channel-offset axis of ~1e6 m, ulp ~1e-10 m).
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from scipy.special import erfcinv

from node_agent.dsp import GaussianCfarDetector, RangeGmPhdFilter, RangePairAssociator

# --- range GM-PHD --------------------------------------------------------------------------


class ReferenceRangePhd:
    """Vo and Ma's GM-PHD on [range, rate] per receiver, component by component."""

    def __init__(self, f: RangeGmPhdFilter) -> None:
        self.f = f
        # per channel: list of dicts w, m (2,), P (2, 2), amp
        self.mix: list[list[dict]] = [[] for _ in range(f.n_channels)]
        self.t: float | None = None

    def step(self, t, ranges, amps, channels):
        f = self.f
        dt = 0.0 if self.t is None else max(t - self.t, 0.0)
        self.t = t
        F = np.array([[1.0, dt], [0.0, 1.0]])
        Q = f.q * np.array([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]])
        for comps in self.mix:
            for c in comps:
                if dt > 0:
                    c["w"] *= f.ps
                    c["m"] = F @ c["m"]
                    c["P"] = F @ c["P"] @ F.T + Q
        out = []
        for ch, comps in enumerate(self.mix):
            r = [x for x, c in zip(ranges, channels, strict=True) if c == ch]
            a = [x for x, c in zip(amps, channels, strict=True) if c == ch]
            # clusters of detections closer than the gap: power-weighted centre, peak amp
            z, za, run = [], [], []
            for k in range(len(r)):
                if run and r[k] - r[run[-1]] > f.cluster_gap:
                    p = [a[i] ** 2 for i in run]
                    z.append(sum(pi * r[i] for pi, i in zip(p, run, strict=True)) / sum(p))
                    za.append(max(a[i] for i in run))
                    run = []
                run.append(k)
            if run:
                p = [a[i] ** 2 for i in run]
                z.append(sum(pi * r[i] for pi, i in zip(p, run, strict=True)) / sum(p))
                za.append(max(a[i] for i in run))
            new = []
            if z:
                for c in comps:
                    new.append({**c, "w": (1 - f.pd) * c["w"]})
                for zj, aj in zip(z, za, strict=True):
                    terms = []
                    for c in comps:
                        s = c["P"][0, 0] + f.range_var
                        q = math.exp(-0.5 * (zj - c["m"][0]) ** 2 / s) / math.sqrt(2 * math.pi * s)
                        terms.append(f.pd * c["w"] * q)
                    den = f.kappa + sum(terms)
                    for c, term in zip(comps, terms, strict=True):
                        if term / den > f.prune_threshold:
                            s = c["P"][0, 0] + f.range_var
                            gain = c["P"][:, 0] / s
                            new.append(
                                {
                                    "w": term / den,
                                    "m": c["m"] + gain * (zj - c["m"][0]),
                                    "P": c["P"] - np.outer(gain, c["P"][0]),
                                    "amp": aj,  # a detected component takes the echo's
                                }
                            )
                    explained = sum(terms) / den
                    new.append(
                        {
                            "w": f.birth_weight * max(1.0 - explained, 0.0),
                            "m": np.array([zj, 0.0]),
                            "P": np.diag([f.range_var, f.birth_rate_var]),
                            "amp": aj,
                        }
                    )
            else:
                new = [{**c, "w": (1 - f.pd) * c["w"]} for c in comps]
            out.append(self._prune_merge(new))
        # cap over all channels by weight (of equal weights the first), keeping the order
        flat = [(-c["w"], ch, k) for ch, comps in enumerate(out) for k, c in enumerate(comps)]
        if len(flat) > f.max_components:
            keep = {(ch, k) for _, ch, k in sorted(flat)[: f.max_components]}
            out = [[c for k, c in enumerate(cs) if (ch, k) in keep] for ch, cs in enumerate(out)]
        self.mix = out
        est = []
        for ch, comps in enumerate(self.mix):
            strong = [c for c in comps if c["w"] > 0.5]
            repeat = any(c["w"] >= 1.5 for c in strong)
            for c in strong:
                row = [c["P"][1, 1], c["m"][0], c["m"][1], c["amp"], float(ch)]
                est.extend([row] * (round(c["w"]) if repeat else 1))
        return np.array(est).reshape(-1, 5)

    def _prune_merge(self, comps):
        f = self.f
        comps = sorted((c for c in comps if c["w"] > f.prune_threshold), key=lambda c: c["m"][0])
        groups: list[list[dict]] = []
        for c in comps:
            if groups:
                prev = groups[-1][-1]
                heavy = c if c["w"] >= prev["w"] else prev
                d = c["m"] - prev["m"]
                if d @ np.linalg.solve(heavy["P"], d) <= f.merge_threshold:
                    groups[-1].append(c)
                    continue
            groups.append([c])
        merged = []
        for g in groups:
            w = sum(c["w"] for c in g)
            m = sum(c["w"] * c["m"] for c in g) / w
            P = sum(c["w"] * (c["P"] + np.outer(c["m"] - m, c["m"] - m)) for c in g) / w
            amp = sum(c["w"] * c["amp"] for c in g) / w
            merged.append({"w": w, "m": m, "P": P, "amp": amp})
        return merged


def _detections(rng, k, n_ch=2):
    """Sorted (channel, range) detections: walkers with extended echoes, plus clutter."""
    r, ch = [], []
    for c in range(n_ch):
        for base, rate in ((4.0 + c, 1.2), (9.0 - c, -0.7)):
            centre = base + rate * k / 50
            body = centre + np.array([-0.12, 0.0, 0.1])[rng.uniform(size=3) < 0.8]
            r.extend(body + 0.01 * rng.standard_normal(body.size))
            ch.extend([c] * body.size)
        clutter = rng.uniform(2.0, 20.0, rng.poisson(2.0))
        r.extend(clutter)
        ch.extend([c] * clutter.size)
    r, ch = np.array(r), np.array(ch, dtype=np.intp)
    order = np.lexsort((r, ch))
    return r[order], rng.uniform(0.2, 2.0, r.size)[order], ch[order]


@pytest.mark.parametrize("max_components", [60, 9])
def test_range_phd_matches_reference(max_components):
    rng = np.random.default_rng(7)
    phd = RangeGmPhdFilter(n_channels=2, clutter_intensity=0.05, max_components=max_components)
    ref = ReferenceRangePhd(phd)
    n_est = 0
    for k in range(60):
        t = 3.0 + k / 50 + 1e-4 * rng.standard_normal()
        r, a, ch = _detections(rng, k) if k % 17 else (np.empty(0),) * 2 + (np.empty(0, int),)
        got = phd.step_detections(t, r, a, ch)
        want = ref.step(t, r.tolist(), a.tolist(), ch.tolist())
        assert got.shape == want.shape, k
        np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-8)
        n_est += len(got)
    assert n_est > 60  # the walkers were tracked, not only clutter rejected


# --- CFAR ----------------------------------------------------------------------------------


class ReferenceCfar:
    """The Gaussian adaptive threshold of :class:`GaussianCfarDetector`, bin by bin."""

    def __init__(self, det: GaussianCfarDetector, ranges, min_range):
        self.k = det.threshold_factor
        self.half = det._half
        self.alpha, self.slow = det.alpha, det.alpha * det.censor
        self.ranges, self.min_range = ranges, min_range
        self.var = None

    def step(self, y):
        y = y.astype(np.float32)
        if self.var is None:
            var0 = np.median(y * y, axis=1) / 0.454936423119572
            self.var = np.repeat(var0[:, None], y.shape[1], axis=1).astype(np.float32)
            self.floor = np.float32(1e-6 * var0.min())
        out_r, out_a, out_c = [], [], []
        d2 = (y * y).astype(np.float32)
        on = (self.ranges[None, :] >= np.asarray(self.min_range)[:, None]) & np.isfinite(d2)
        crossing = on & (d2 > np.float32(self.k**2) * self.var)
        rate = np.full(y.shape, np.float32(self.alpha))
        h = self.half
        for c in range(y.shape[0]):
            padded = np.concatenate((np.zeros(h), d2[c], np.zeros(h)))
            for j in np.flatnonzero(crossing[c]):
                rate[c, max(j - h, 0) : j + h + 1] = np.float32(self.slow)
                nb = padded[j : j + 2 * h + 1]
                if nb[h] < nb.max() or nb[h] <= nb[:h].max():
                    continue
                am, amp, ap = np.sqrt(nb[h - 1 : h + 2].astype(np.float64))
                den = am - 2 * amp + ap
                frac = 0.0 if den == 0 else (am - ap) / den * 0.5
                out_r.append(self.ranges[j] + frac * (self.ranges[1] - self.ranges[0]))
                out_a.append(amp)
                out_c.append(c)
        clipped = np.minimum(d2, np.float32(9.0) * self.var)
        self.var = np.maximum(self.var + rate * (clipped - self.var), self.floor)
        return out_r, out_a, out_c


def test_cfar_matches_reference():
    rng = np.random.default_rng(11)
    ranges = 1.0 + 0.0428 * np.arange(600)
    min_range = np.array([1.6, 1.9])
    det = GaussianCfarDetector(1e-3, ranges=ranges, pulse_width=0.0857, min_range=min_range)
    ref = ReferenceCfar(det, ranges, min_range)
    assert det.threshold_factor == pytest.approx(math.sqrt(2) * erfcinv(1e-3))
    n = 0
    for k in range(40):
        y = rng.standard_normal((2, 600)).astype(np.float32)
        for c, j in ((0, 100 + k), (1, 300 - k), (0, 599)):  # echoes, one at the window's end
            y[c, j - 2 : j + 3] += (
                np.float32(6.0) * np.array([0.3, 0.8, 1.0, 0.7, 0.2])[: y[c, j - 2 : j + 3].size]
            )
        got = det.detect(y)
        want = ref.step(y)
        assert [g.tolist() for g in got[2:]] == [want[2]], k
        np.testing.assert_allclose(got[0], want[0], rtol=0, atol=1e-12)
        np.testing.assert_allclose(got[1], want[1], rtol=1e-12)
        n += len(want[0])
    assert n > 80


# --- pairing -------------------------------------------------------------------------------


def test_pairing_is_the_best_admissible_matching():
    rng = np.random.default_rng(3)
    assoc = RangePairAssociator(1.1)
    for _ in range(200):
        r1 = np.sort(rng.uniform(3.0, 7.0, rng.integers(0, 5))).tolist()
        r2 = np.sort(rng.uniform(3.0, 7.0, rng.integers(0, 5))).tolist()
        f1 = [(0.01, rng.normal(), rng.uniform(0.1, 2)) for _ in r1]
        f2 = [(0.01, rng.normal(), rng.uniform(0.1, 2)) for _ in r2]

        def cost(i, j, r1=r1, r2=r2, f1=f1, f2=f2):
            dv = f1[i][1] - f2[j][1]
            dl = math.log(f1[i][2]) - math.log(f2[j][2])
            return abs(r1[i] - r2[j]) * 1e-3 / 1.1 + dv * dv / 0.11 + dl * dl / 0.49

        # brute force: most admissible pairs, then least total cost
        best = (0, 0.0, [])
        short, long_ = sorted((len(r1), len(r2)))
        for perm in itertools.permutations(range(long_), short):
            # the shorter list's entries each take a distinct entry of the longer one
            both = enumerate(perm) if len(r1) <= len(r2) else ((i, j) for j, i in enumerate(perm))
            pairs = [(i, j) for i, j in both if abs(r1[i] - r2[j]) <= 1.1]
            score = (len(pairs), -sum(cost(i, j) for i, j in pairs))
            if score > best[:2]:
                best = (*score, sorted(pairs))
        i1, i2 = assoc.associate_lists(r1, r2, f1, f2)
        got = sorted(zip(i1, i2, strict=True))
        assert len(got) == best[0]
        # a different matching only when it costs the same (uncompeted pairs take no cost)
        assert sum(cost(i, j) for i, j in got) == pytest.approx(-best[1], abs=1e-9)
