"""The fusion service publishes no pose that is not finite, and keeps publishing the others."""

from __future__ import annotations

import numpy as np

from fusion_center.localization.estimators import PositionFix
from fusion_center.localization.mobile import PoseResult
from fusion_center.service import FusionConfig, FusionService
from protocol import Poses, decode


class _Publisher:
    def __init__(self) -> None:
        self.sent: list[bytes] = []

    def put(self, payload: bytes) -> None:
        self.sent.append(payload)


def _pose(t: float, x: float, cov: float) -> PoseResult:
    fix = PositionFix(position=np.array([x, 1.0]), cov=np.eye(2) * 1e-4, ok=True)
    return PoseResult(t=t, pose=(x, 1.0, 0.5, 0.0), cov=np.eye(3) * cov, los={}, fix=fix)


def test_a_nan_pose_is_counted_and_not_published() -> None:
    service = FusionService(None, FusionConfig(net="t"))  # type: ignore[arg-type]
    pub = _Publisher()
    service._pub_poses = pub
    service._publish_pose(("a", _pose(0.0, 1.0, 1e-4)))
    service._publish_pose(("b", _pose(0.1, 2.0, float("nan"))))
    service._publish_pose(("a", _pose(0.2, 1.1, 1e-4)))
    assert service.rejected_poses == 1
    msgs = [decode(b) for b in pub.sent]
    assert len(msgs) == 2 and all(isinstance(m, Poses) for m in msgs)
    assert set(msgs[-1].poses) == {"a"}
