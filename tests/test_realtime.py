"""``realtime.setup_frozen``: the objects made before a control loop are out of the
cyclic collector's full passes while it runs, and collectable again after; the closed
loop runs inside it. Truth: Python's ``gc`` (its freeze count, and a reference cycle
freed or not by ``gc.collect``)."""

import gc
import weakref

from aeromanip.bench.controller_speed import bench_scenario
from aeromanip.experiment.closed_loop import fly
from aeromanip.realtime import setup_frozen


class Node:
    """A reference cycle's member (freed only by the cyclic collector)."""

    def __init__(self) -> None:
        self.me = self


def test_the_setups_cycles_are_left_alone_during_the_loop_and_freed_after():
    dropped = Node()
    gone = weakref.ref(dropped)
    del dropped  # garbage already: the block's first collection frees it
    kept = Node()
    frozen = weakref.ref(kept)
    gc.disable()  # no automatic pass but the block's and the test's own
    try:
        with setup_frozen():
            assert gone() is None and gc.get_freeze_count() > 0
            del kept  # garbage during the loop, but frozen with the setup
            gc.collect()
            assert frozen() is not None  # a full pass does not walk it
        assert gc.get_freeze_count() == 0
        gc.collect()
        assert frozen() is None  # unfrozen: freed
    finally:
        gc.enable()


def test_the_closed_loop_flies_with_the_setups_objects_frozen():
    sc = bench_scenario("flight", 1.0)
    frozen = []
    fly(sc, lambda row: frozen.append(gc.get_freeze_count()), progress=False)
    assert len(frozen) == sc.steps and min(frozen) > 10_000  # the controller's objects
    assert gc.get_freeze_count() == 0
