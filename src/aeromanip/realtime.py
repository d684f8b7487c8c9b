"""Bounded steps for a control loop in Python: the objects made while setting up (the
model, its CasADi Functions, the solvers: tens of thousands) kept out of the cyclic
garbage collector's full passes.

Python's collector occasionally walks every tracked object (a full, "generation 2"
pass): with a controller built, 8-13 ms at once, inside whichever step triggered it
(the flight's Python step, 0.2 ms median, had its worst at 13 ms so). Frozen
(``gc.freeze``), those objects are skipped and a full pass costs what the loop itself
allocated. They are unfrozen when the loop ends, so that a process flying many runs
(a sweep, the tests) frees their cycles as before.
"""

from __future__ import annotations

import gc
from collections.abc import Iterator
from contextlib import contextmanager


@contextmanager
def setup_frozen() -> Iterator[None]:
    """Collect once, freeze what is left for the block's duration, then unfreeze."""
    gc.collect()
    gc.freeze()
    try:
        yield
    finally:
        gc.unfreeze()
