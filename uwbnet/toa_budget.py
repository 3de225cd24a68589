"""Where the LOS range error comes from: noise, overlapping multipath, estimator.

``python -m uwbnet.toa_budget [--scenario lab_los] [--duration 40] [--seed 7] [--method
adaptive]`` simulates the scenario's ranging rounds (:class:`sim_nodes.ranging.RangingSimulator`,
the same links as ``uwbnet sim``), runs the node agent's first-path estimator on every
reception and sets each round's double-sided range error (receive-timestamp errors weighted
0.25 / 0.5 / 0.25, :mod:`node_agent.dsp.rttoa`) next to two bounds of the same round:

- the single-path CRLB (the first path's amplitude the only nuisance), the issue's bound;
- the multipath-aware bound (equivalent Fisher information with the paths within 1 ns of
  the first as nuisance, Shen and Win;
  :func:`fusion_center.localization.crlb.multipath_delay_bound`).

It prints one JSON object: the error's RMS, bias and percentiles; the share of the squared
error in rounds whose three receptions disagree by more than 5 mm (noise-driven jumps of
the estimator: a different peak or a noise crossing), in rounds whose error exceeds three
times the multipath bound (estimator bias that an unbiased estimator of the multipath model
need not have) and in the rest; and both bounds (RMS, median, 90th and 99th percentile),
also propagated to the position error bound of every round's anchor geometry. Only LOS
links are counted (``--all-links`` counts every link).
"""

from __future__ import annotations

import argparse
import json

import numpy as np

from fusion_center.localization.crlb import multipath_delay_bound, position_error_bound
from node_agent.dsp.band_filter import pulse_sigma
from node_agent.dsp.ranging import FirstPathRanger
from protocol.units import C
from sim_nodes.network import scenario_walls
from sim_nodes.ranging import RangingSimulator, track_position
from sim_nodes.scene import load_scenario

DS_WEIGHTS = np.array([0.25, 0.5, 0.25])
"""Weights of the three receive-timestamp errors in a double-sided range error."""

JUMP = 5e-3
"""Receptions of one round disagreeing by more than this (m) mark a noise-driven jump."""


def _pct(x: np.ndarray, q: float) -> float:
    return round(float(np.percentile(x, q)) * 1e3, 3)


def budget(
    scenario: str = "lab_los",
    duration: float = 40.0,
    seed: int = 7,
    method: str = "adaptive",
    all_links: bool = False,
) -> dict:
    """The error budget of ``scenario`` (see the module docstring); lengths in mm."""
    sc = load_scenario(scenario)
    sim = RangingSimulator(sc, scenario_walls(sc), seed)
    cfg = sim.config
    if cfg.scheme != "ds":
        raise ValueError("the budget is written for double-sided ranging (scheme = 'ds')")
    complex_input = cfg.fc > 0.0
    ranger = FirstPathRanger(sim.radar, method=method)
    sig_t = pulse_sigma(sim.radar, complex_input=complex_input)
    f_off = 0.5 * (cfg.f_low + cfg.f_high) - cfg.fc if complex_input or cfg.f_low > 0.0 else 0.0
    noise = 10.0 ** (-cfg.snr_db / 20.0)
    ds_factor = float(np.sqrt(np.sum(DS_WEIGHTS**2)))
    anchors = {a: np.asarray(p, float) for a, p in sim.anchors.items()}
    errors, single, multi, spreads = [], [], [], []
    peb_single, peb_multi = [], []
    for mobile, model in sim.mobiles.items():
        for t in np.arange(0.0, duration, 1.0 / cfg.rate):
            pos, _, _ = track_position(model, float(t))
            std_s, std_m, where = [], [], []
            for a in anchors:
                rnd = sim.round(mobile, a, float(t))
                s_b, m_b = multipath_delay_bound(
                    rnd.delays * 1e-9,
                    rnd.amplitudes,
                    noise_sigma=noise,
                    fs=cfg.fs,
                    n=cfg.n,
                    first_index=rnd.lead * cfg.fs + rnd.delays[0] * 1e-9 * cfg.fs,
                    pulse_sigma=sig_t,
                    offset_frequency=f_off,
                    real_output=not complex_input,
                )
                # one-way delay bound -> double-sided range bound (independent receptions)
                std_s.append(ds_factor * C * s_b)
                std_m.append(ds_factor * C * m_b)
                where.append(anchors[a])
                if not (all_links or rnd.link.los):
                    continue
                toa = ranger.process(rnd.exchange.h).toa
                err = (toa - rnd.lead) * C
                errors.append(float(DS_WEIGHTS @ err))
                spreads.append(float(np.ptp(err)))
                single.append(std_s[-1])
                multi.append(std_m[-1])
            w = np.array(where)
            dz = w[:, 2] - pos[2]
            peb_single.append(position_error_bound(pos[:2], w[:, :2], np.array(std_s), dz))
            peb_multi.append(position_error_bound(pos[:2], w[:, :2], np.array(std_m), dz))
    e = np.array(errors)
    ok = np.isfinite(e)
    e, spread = e[ok], np.array(spreads)[ok]
    sb, mb = np.array(single)[ok], np.array(multi)[ok]
    sq = np.sum(e**2)
    jump = spread > JUMP
    biased = ~jump & (np.abs(e) > 3.0 * mb)
    rest = ~jump & ~biased

    def rms(x: np.ndarray) -> float:
        return round(float(np.sqrt(np.mean(x**2))) * 1e3, 3) if x.size else float("nan")

    def share(mask: np.ndarray) -> float:
        return round(float(np.sum(e[mask] ** 2) / sq), 4) if sq > 0 else 0.0

    ps, pm = np.array(peb_single), np.array(peb_multi)
    return {
        "scenario": scenario,
        "method": method,
        "seed": seed,
        "rounds": int(e.size),
        "missed": int(np.count_nonzero(~ok)),
        "range_error_mm": {
            "rms": rms(e),
            "bias": round(float(np.mean(e)) * 1e3, 3),
            "p50_abs": _pct(np.abs(e), 50),
            "p90_abs": _pct(np.abs(e), 90),
            "p99_abs": _pct(np.abs(e), 99),
            "rms_without_jumps": rms(e[~jump]),
            "rms_rest": rms(e[rest]),
        },
        "share_of_squared_error": {
            "jumps": share(jump),
            "beyond_3x_multipath_bound": share(biased),
            "rest": share(rest),
        },
        "fraction_of_rounds": {
            "jumps": round(float(np.mean(jump)), 4),
            "beyond_3x_multipath_bound": round(float(np.mean(biased)), 4),
        },
        "range_bound_mm": {
            "single_path_rms": rms(sb),
            "single_path_p50": _pct(sb, 50),
            "multipath_rms": rms(mb[np.isfinite(mb)]),
            "multipath_infinite": int(np.count_nonzero(~np.isfinite(mb))),
            "multipath_p50": _pct(mb, 50),
            "multipath_p90": _pct(mb, 90),
            "multipath_p99": _pct(mb, 99),
        },
        "position_bound_mm": {
            "single_path_rms": rms(ps),
            "multipath_rms": rms(pm[np.isfinite(pm)]),
            "multipath_p50": _pct(pm, 50),
            "multipath_p90": _pct(pm, 90),
        },
    }


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(prog="python -m uwbnet.toa_budget", description=__doc__)
    p.add_argument("--scenario", default="lab_los")
    p.add_argument("--duration", type=float, default=40.0)
    p.add_argument("--seed", type=int, default=7)
    p.add_argument("--method", default="adaptive")
    p.add_argument("--all-links", action="store_true")
    a = p.parse_args(argv)
    out = budget(a.scenario, a.duration, a.seed, a.method, a.all_links)
    print(json.dumps(out, indent=1))  # noqa: T201 (a script's output)


if __name__ == "__main__":
    main()
