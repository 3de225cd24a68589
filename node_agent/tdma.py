"""TDMA slot timing from the published schedule (pure: time is an argument)."""

from __future__ import annotations

import dataclasses
import math

from protocol import TdmaSchedule


@dataclasses.dataclass(frozen=True, slots=True, kw_only=True)
class SlotTiming:
    """One concrete slot: TDMA frame number, slot index, transmitter, start time (network s)
    and duration (s)."""

    frame: int
    slot: int
    tx: str
    t: float
    duration: float


def next_slot(schedule: TdmaSchedule, tx: str, after: float) -> SlotTiming | None:
    """The first slot of transmitter ``tx`` that starts at or after network time ``after``.

    Slot start of frame k is ``epoch + k * frame_period + start``. Returns None when ``tx`` has
    no slot in the schedule.
    """
    for s in schedule.slots:
        if s.tx == tx:
            k = max(0, math.ceil((after - schedule.epoch - s.start) / schedule.frame_period - 1e-9))
            t = schedule.epoch + k * schedule.frame_period + s.start
            return SlotTiming(frame=k, slot=s.slot, tx=tx, t=t, duration=s.duration)
    return None


def frame_of(schedule: TdmaSchedule, t: float) -> int:
    """The TDMA frame number that contains network time ``t``."""
    return math.floor((t - schedule.epoch) / schedule.frame_period)
