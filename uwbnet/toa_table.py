"""ToA bias and standard deviation of each estimator vs SNR, in LOS and NLOS channels.

``python -m uwbnet.toa_table [--radar dw1000|msequence] [--count N] [--seed S]`` draws seeded
stochastic residential LOS and NLOS channels (:mod:`sim_nodes.channel.stochastic`), renders
them at each SNR from -5 to 30 dB (strongest path's envelope over the noise's per-component
standard deviation), runs the chain of ``uwbnet ranging`` with each method and prints a
markdown table and, on the last line, the figures as JSON. The reference is the direct
path's arrival (with its excess delay through the obstacle in NLOS: what an ideal first-path
detector finds). Errors in ns; ``rmse`` and ``med`` (median absolute error) beside bias and
standard deviation because first-path errors are far from Gaussian (rare early false alarms,
frequent late misses).
"""

from __future__ import annotations

import argparse
import json

import numpy as np

from node_agent.dsp.geometry import RadarParams
from node_agent.dsp.ranging import FirstPathRanger
from sim_nodes.channel.stochastic import RESIDENTIAL_LOS, RESIDENTIAL_NLOS, draw_channel, render

RADARS = {
    "dw1000": RadarParams(fs=998.4e6, n=1016, t0=0.0, f_low=6.2396e9, f_high=6.7396e9, fc=6.4896e9),
    "msequence": RadarParams(fs=7e9, n=4095, t0=0.0, f_low=0.0, f_high=3.5e9),
}
SNRS_DB = (-5.0, 0.0, 5.0, 10.0, 15.0, 20.0, 25.0, 30.0)
METHODS = ("mpd", "threshold", "adaptive", "peak")


def toa_table(radar: RadarParams, count: int, seed: int) -> list[dict]:
    """Rows ``{"channel", "snr_db", "method", "bias", "std", "rmse", "med", "missed"}`` (ns)."""
    rng = np.random.default_rng(seed)
    rangers = {m: FirstPathRanger(radar, method=m) for m in METHODS}
    rows = []
    for name, env in (("LOS", RESIDENTIAL_LOS), ("NLOS", RESIDENTIAL_NLOS)):
        channels = [draw_channel(env, rng) for _ in range(count)]
        first = rng.uniform(0.3, 0.6, count) * radar.n
        truth = first / radar.fs + np.array([d[0] for d, _ in channels]) * 1e-9
        for snr in SNRS_DB:
            h = np.stack(
                [
                    render(
                        d,
                        a,
                        fs=radar.fs,
                        n=radar.n,
                        f_low=radar.f_low,
                        f_high=radar.f_high,
                        fc=radar.fc,
                        first_index=k,
                        snr_db=snr,
                        rng=rng,
                    )
                    for (d, a), k in zip(channels, first, strict=True)
                ]
            )
            for method, ranger in rangers.items():
                err = (ranger.process(h).toa - truth) * 1e9
                ok = np.isfinite(err)
                e = err[ok]
                rows.append(
                    {
                        "channel": name,
                        "snr_db": snr,
                        "method": method,
                        "bias": round(float(np.mean(e)), 2) if e.size else None,
                        "std": round(float(np.std(e)), 2) if e.size else None,
                        "rmse": round(float(np.sqrt(np.mean(e * e))), 2) if e.size else None,
                        "med": round(float(np.median(np.abs(e))), 2) if e.size else None,
                        "missed": round(float(1.0 - ok.mean()), 3),
                    }
                )
    return rows


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--radar", choices=sorted(RADARS), default="dw1000")
    p.add_argument("--count", type=int, default=200, help="channels per class and SNR")
    p.add_argument("--seed", type=int, default=1)
    args = p.parse_args(argv)
    rows = toa_table(RADARS[args.radar], args.count, args.seed)
    lines = ["| channel | SNR dB | " + " | ".join(f"{m} bias/std/med" for m in METHODS) + " |"]
    lines.append("|---|---|" + "---|" * len(METHODS))
    index = {(x["channel"], x["snr_db"], x["method"]): x for x in rows}
    for ch in ("LOS", "NLOS"):
        for snr in SNRS_DB:
            cells = []
            for m in METHODS:
                r = index[(ch, snr, m)]
                cells.append(f"{r['bias']} / {r['std']} / {r['med']}")
            lines.append(f"| {ch} | {snr:g} | " + " | ".join(cells) + " |")
    print("\n".join(lines))  # noqa: T201 (a script's output)
    print(json.dumps({"radar": args.radar, "count": args.count, "rows": rows}))  # noqa: T201


if __name__ == "__main__":
    main()
