"""settle_heap: the start-up heap of a real-time process leaves the collector's generations."""

import gc

from uwbnet.processes import settle_heap


class _Node:
    """A container the cyclic collector tracks (it can hold references)."""

    def __init__(self) -> None:
        self.peer: _Node | None = None


def test_start_up_objects_are_frozen_and_later_ones_are_not() -> None:
    before = _Node()
    before.peer = before  # a reference cycle that is still alive: it must not be collected
    try:
        settle_heap()
        after = _Node()
        tracked = {id(o) for g in range(3) for o in gc.get_objects(generation=g)}
        assert gc.get_freeze_count() > 0
        assert id(before) not in tracked  # in the permanent generation: never scanned again
        assert id(after) in tracked  # what the run allocates is collected as usual
        assert before.peer is before
    finally:
        gc.unfreeze()
