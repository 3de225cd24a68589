"""The track resolves the mirror ambiguity of two LOS anchors (lab_nlos, seed 1, t = 2.8 s)."""

import math

import numpy as np
import pytest

from fusion_center.localization import LocalizerConfig, RangingLocalizer

ANCHORS = {
    "rx1": (0.4, 0.4, 1.5),
    "rx2": (0.4, 4.6, 1.5),
    "rx3": (8.0, 2.5, 1.5),  # next door: NLOS
    "rx4": (4.5, 6.0, 1.5),  # corridor: NLOS
}
TRUTH = np.array([1.5, 1.5, 1.0])


def links(rng, rx3_excess=0.3):
    out = {}
    for a, pos in ANCHORS.items():
        d = float(np.linalg.norm(np.array(pos) - TRUTH))
        nlos = a in ("rx3", "rx4")
        excess = (rx3_excess if a == "rx3" else 0.25) if nlos else 0.0
        snr = 50.0 - 20.0 * math.log10(d) - (15.0 if nlos else 0.0)
        out[a] = (d + excess + 0.003 * rng.standard_normal(), 0.005, not nlos, snr)
    return out


@pytest.mark.parametrize("branch_gate", [13.8, 0.0])
def test_a_far_nlos_range_does_not_flip_the_fix_to_the_mirror(branch_gate):
    rng = np.random.default_rng(1)
    loc = RangingLocalizer(ANCHORS, 1.0, LocalizerConfig(branch_gate=branch_gate))
    for k in range(40):
        res = loc.step(0.1 * k, links(rng))
    assert not loc.los_decisions()["rx3"] and not loc.los_decisions()["rx4"]
    assert np.hypot(*(np.asarray(res.fix.position) - TRUTH[:2])) < 0.02
    # the direct path next door is missed: 1.8 m of excess on rx3, which fits the mirror
    # image of the position about the LOS anchors' wall (x = 0.4) better than the truth
    res = loc.step(4.0, links(rng, rx3_excess=1.79))
    err = np.hypot(*(np.asarray(res.fix.position) - TRUTH[:2]))
    if branch_gate > 0:
        assert err < 0.02
        assert np.hypot(res.pose[0] - TRUTH[0], res.pose[1] - TRUTH[1]) < 0.02
    else:
        assert err > 1.0  # without the track's branch check the fix is the mirror
