"""features.merge_walls: walls on one line merge only across gaps up to max_gap."""

from __future__ import annotations

import numpy as np

from fusion_center.mapping.features import merge_walls


def _collinear():
    # three walls on the line y = 1 (alpha = pi / 2, d = 1), extents along its tangent;
    # gaps 0.5 m (first to second) and 2 m (second to third)
    walls = np.array([[np.pi / 2, 1.0], [np.pi / 2, 1.01], [np.pi / 2, 0.99]])
    extent = np.array([[0.0, 2.0], [2.5, 4.0], [6.0, 8.0]])
    hits = np.array([10.0, 5.0, 3.0])
    return walls, extent, hits


def test_collinear_walls_merge_only_across_small_gaps() -> None:
    w, e, h = merge_walls(*_collinear(), dist=0.05, angle=np.radians(5.0), max_gap=1.0)
    assert len(w) == 2
    order = np.argsort(e[:, 0])
    np.testing.assert_allclose(e[order], [[0.0, 4.0], [6.0, 8.0]], atol=1e-9)
    np.testing.assert_allclose(h[order], [15.0, 3.0])
    # the merged line is the hit-weighted mean of its walls
    np.testing.assert_allclose(w[order][0], [np.pi / 2, (10 * 1.0 + 5 * 1.01) / 15], atol=1e-12)
    np.testing.assert_allclose(w[order][1], [np.pi / 2, 0.99], atol=1e-12)


def test_without_max_gap_collinear_walls_make_one() -> None:
    w, e, h = merge_walls(*_collinear(), dist=0.05, angle=np.radians(5.0))
    assert len(w) == 1
    np.testing.assert_allclose(e[0], [0.0, 8.0], atol=1e-9)
    assert h[0] == 18.0
