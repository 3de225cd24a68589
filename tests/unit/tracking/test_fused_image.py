"""FusedImageTracker: simulate an isolated walker, recover it."""

from __future__ import annotations

import numpy as np

from fusion_center.tracking.fused_image import FusedImageConfig, FusedImageTracker

from .sim import FRAME, detect, sensors_around


def test_isolated_target_found_with_stable_id(rng: np.random.Generator) -> None:
    sensors = sensors_around(10.0, 8.0)
    tracker = FusedImageTracker(FusedImageConfig(bounds=(0.0, 10.0, 0.0, 8.0)))
    velocity = np.array([0.5, 0.25])
    ids = set()
    for k in range(100):
        t = k * FRAME
        p = np.array([[4.0, 3.0]]) + velocity * t
        out = tracker.step(t, [detect(rng, s, t, p, clutter=0.5) for s in sensors])
        if k >= 25:
            assert len(out.tracks) == 1
            ids.add(out.tracks[0].id)
    tr = out.tracks[0]
    # The forgetting factor makes the image lag by about λ/(1-λ) frames of motion.
    assert np.hypot(tr.x - p[0, 0], tr.y - p[0, 1]) < 0.15
    assert np.allclose([tr.vx, tr.vy], velocity, atol=0.3)
    assert len(ids) == 1
    img, _, _, _ = tracker.image
    assert img.max() > 0
