"""``flat_clusters`` numbers the clusters of a cut tree as ``scipy``'s ``fcluster`` does (the
fused measurements' order, and so the tracks, depend on it)."""

from __future__ import annotations

import numpy as np
from scipy.cluster.hierarchy import fcluster, linkage
from scipy.spatial.distance import pdist

from fusion_center.tracking.gmphd import flat_clusters


def test_flat_clusters_are_fclusters_numbering_on_random_and_tied_trees() -> None:
    rng = np.random.default_rng(5)
    cases = 0
    for n in range(2, 16):
        for _ in range(25):
            if rng.random() < 0.5:
                z = rng.uniform(0.0, 3.0, (n, 2))
            else:  # a grid: many equal distances, and merges exactly at the cut
                z = rng.integers(0, 4, (n, 2)).astype(float) * 0.5
            d = pdist(z)
            if rng.random() < 0.3:
                d[rng.random(d.size) < 0.3] = 1e6  # same-sensor pairs kept apart
            for method in ("complete", "single", "average"):
                tree = linkage(d, method=method)
                for t in (0.0, 0.5, 0.6, 1.0, 2.0, 1e7):
                    want = fcluster(tree, t=t, criterion="distance")
                    np.testing.assert_array_equal(flat_clusters(tree, t), want)
                    cases += 1
    assert cases > 6000
