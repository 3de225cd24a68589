"""FusionCore's ``frame_wait``: an incomplete frame waits a little longer for a sensor whose
detection may still be in flight, and not for one that skipped the frame or went silent."""

from __future__ import annotations

import functools

import msgpack
import pytest

from fusion_center.core import FusionCore, FusionCoreConfig
from fusion_center.tracking.base import TrackerOutput
from protocol import Detections, NodeInfo
from sim_nodes.network import SimNetwork

NO = {"rx1": (), "rx2": ()}


class FrameRecorder:
    """A tracker that records the sensors of each step."""

    def __init__(self) -> None:
        self.steps: list[tuple[str, ...]] = []

    def step(self, t, scans):  # type: ignore[no-untyped-def]
        self.steps.append(tuple(sorted(s.sensor for s in scans)))
        return TrackerOutput(t=t, tracks=(), n_estimate=0.0)

    def reset(self) -> None:
        pass


@functools.cache
def _infos() -> tuple[NodeInfo, ...]:
    return tuple(
        NodeInfo.from_wire(
            msgpack.packb({"v": 1, "kind": "node_info", "src": nid, "seq": 0, "t": 0.0, **info})
        )
        for nid, info in SimNetwork("foyer3", seed=1).node_infos().items()
    )


def _core(wait: int) -> tuple[FusionCore, FrameRecorder]:
    rec = FrameRecorder()
    core = FusionCore(rec, FusionCoreConfig(frame_lag=2, frame_wait=wait))  # type: ignore[arg-type]
    for info in _infos():
        core.add_node(info)
    core.expected = frozenset({"bat1", "bat2"})
    return core, rec


def _det(core: FusionCore, src: str, frame: int) -> list[TrackerOutput]:
    t = frame * 0.02 + (0.0 if src == "bat1" else 0.01)
    det = Detections(src=src, seq=frame, t=t, tx=f"{src}/tx", frame=frame, ranges=NO, amplitudes=NO)
    return core.add_detections(det)


def _frames(core: FusionCore, frames: range, src: tuple[str, ...] = ("bat1", "bat2")) -> None:
    for f in frames:
        for s in src:
            _det(core, s, f)


@pytest.mark.parametrize("wait", [0, 1, 2])
def test_a_late_batch_is_waited_for(wait: int) -> None:
    core, rec = _core(wait)
    _frames(core, range(3))  # both sensors report frames 0-2
    _det(core, "bat1", 3)
    _det(core, "bat1", 4)
    _det(core, "bat1", 5)  # bat2's frame 3 is late: frame 3 is due now with frame_lag 2
    if wait == 0:
        assert rec.steps[-1] == ("bat1",)
    else:
        assert rec.steps[-1] == ("bat1", "bat2")  # frame 2; frame 3 waits for bat2
    _det(core, "bat2", 3)  # the late detection arrives
    if wait == 0:
        assert core.counters.late == 1
    else:
        assert core.counters.late == 0
        assert rec.steps[-1] == ("bat1", "bat2")  # frame 3, complete
    assert core.counters.updates == 4


def test_a_sensor_that_skipped_the_frame_is_not_waited_for() -> None:
    core, rec = _core(2)
    _frames(core, range(3))
    _det(core, "bat1", 3)
    _det(core, "bat1", 4)
    _det(core, "bat2", 5)  # bat2 skipped frames 3 and 4: its messages arrive in order
    _det(core, "bat1", 6)
    assert core.counters.updates == 5
    assert rec.steps[3:] == [("bat1",), ("bat1",)]


def test_the_wait_is_bounded() -> None:
    core, rec = _core(1)
    _frames(core, range(3))
    for f in range(3, 7):
        _det(core, "bat1", f)  # bat2 goes silent after frame 2
    # frames 3-5 (bat2 reported one of the 3 frames before each) wait one frame more each
    assert core.counters.updates == 4
    for f in range(7, 10):
        _det(core, "bat1", f)
    # from frame 6 on bat2 is silent too long to be waited for: frame_lag 2 again
    assert core.counters.updates == 8
    assert rec.steps[3:] == [("bat1",)] * 5


def test_a_silent_sensor_does_not_delay_later_frames() -> None:
    core, _ = _core(2)
    _frames(core, range(2))
    for f in range(2, 20):
        _det(core, "bat1", f)
    assert core.counters.updates == 20 - 2 - 0  # every frame up to 17 processed
    assert core.counters.late == 0
