"""``uwbnet bench hub`` on a small network: a live hub (``uwbnet scale``'s hub process) fed
by played nodes over real zenoh reports its CPU per message, latency and drops."""

from __future__ import annotations

import pytest

from uwbnet.bench_hub import run_one

pytestmark = pytest.mark.integration


def test_the_hub_bench_measures_a_live_hub() -> None:
    got = run_one(8, seconds=1.5, warmup=0.5)
    assert got["nodes"] == 8
    # every detection of the window reached a track update (a loaded machine may lose a few)
    assert got["drop_rate"] < 0.2 and got["late_detections"] is not None
    assert got["p50_latency_ms"] is not None and 0.0 < got["p50_latency_ms"] < 1000.0
    # the hub spent CPU on the messages (read in clock ticks of 10 ms: zenoh's threads may
    # show none for the few hundred messages of this run, the fusion thread does)
    assert got["python_threads_us_per_msg"] > 0.0 and got["zenoh_threads_us_per_msg"] >= 0.0
    total = got["zenoh_threads_us_per_msg"] + got["python_threads_us_per_msg"]
    assert got["hub_us_per_msg"] == pytest.approx(total, abs=0.2)
