"""The cyclic garbage collector paused around the compile's big allocations.

One implementation for every floor that runs one (bgc.run.driver's compile, bgc.backends.load's
C printing): the standard library only.
"""
from __future__ import annotations

import contextlib
import gc


@contextlib.contextmanager
def gc_paused():
    """The cyclic garbage collector off for the block (and back to its former state after).

    A compile allocates millions of small, short-lived sympy objects that reference counting
    frees; the collector's passes over them found almost nothing and cost a fifth of the 3R2S
    compile (measured: bench/bench_compile.py). Memory stays bounded: the model limits bound
    the compile, and the collector runs again as soon as the block ends.

    What the block made and kept (the compile's results) is moved to the oldest generation as
    it ends (``gc.freeze`` then ``gc.unfreeze``, only when nothing else is frozen): else the
    first young collection after the block, and the middle one after it, each walked every
    object the block allocated (a compile keeps hundreds of thousands).
    Nothing is kept from the collector: the next full collection looks at them as before."""
    was = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was:
            if gc.get_freeze_count() == 0:  # (a host's own frozen objects stay frozen)
                gc.freeze()
                gc.unfreeze()
            gc.enable()
