"""Several estimates of one sensor on one body (extended target): absorbed by its track."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fusion_center.tracking.gmphd import GmPhdConfig, fuse_estimates

R = np.broadcast_to(np.eye(2) * 0.1**2, (3, 2, 2)).copy()
ANCHOR = np.array([[5.0, 4.0]])
ANCHOR_COV = np.eye(2)[None] * 0.3**2


def _group(absorb: float, z: np.ndarray, owner: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    zf, _, group = fuse_estimates(
        z, R[: len(z)], owner, 0.6, 0.05, ANCHOR, ANCHOR_COV, absorb_distance=absorb
    )
    return zf, group


def test_second_estimate_of_a_tracked_body_joins_its_group_with_no_weight() -> None:
    # sensor 0 resolves two parts of the tracked body 0.4 m apart, sensor 1 sees it once
    z = np.array([[5.1, 4.0], [5.5, 4.0], [4.9, 4.0]])
    owner = np.array([0, 0, 1])
    zf, group = _group(0.0, z, owner)
    assert len(zf) == 2  # off: the second echo is a measurement of its own (a birth seed)
    zf, group = _group(0.6, z, owner)
    assert len(zf) == 1 and np.all(group == 0)
    # the fused position is that of the assigned estimates only
    np.testing.assert_allclose(zf[0], [5.0, 4.0], atol=1e-9)


def test_an_estimate_beyond_the_absorb_distance_stays_apart() -> None:
    # 0.9 m from the track (inside its gate): a second person next to it
    zf, _ = _group(0.6, np.array([[5.0, 4.0], [5.9, 4.0]]), np.array([0, 0]))
    assert len(zf) == 2
    zf, _ = _group(1.0, np.array([[5.0, 4.0], [5.9, 4.0]]), np.array([0, 0]))
    assert len(zf) == 1


@pytest.mark.parametrize("value", [-0.1, math.nan, math.inf])
def test_absorb_distance_is_validated(value: float) -> None:
    with pytest.raises(ValueError, match="extent_absorb_distance"):
        GmPhdConfig(extent_absorb_distance=value)
