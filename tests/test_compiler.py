"""The driver (bgc.run.driver): the collector pause around a compile, and the skeleton check's
in-process memo (a module checked when rendered is not parsed again when loaded)."""
from __future__ import annotations

import gc
from pathlib import Path

import pytest

from bgc.backends import skeleton
from bgc.format.parse import parse_file
from bgc.run.driver import compile_model, gc_paused

ROOT = Path(__file__).resolve().parents[1]


def test_gc_paused_restores_the_collector_state():
    assert gc.isenabled()
    with gc_paused():
        assert not gc.isenabled()
    assert gc.isenabled()
    with pytest.raises(ZeroDivisionError):
        with gc_paused():
            1 / 0
    assert gc.isenabled()
    gc.disable()  # a caller that turned it off keeps it off
    try:
        with gc_paused():
            pass
        assert not gc.isenabled()
    finally:
        gc.enable()



def test_gc_paused_leaves_what_it_made_collectable():
    """Objects made in the block move to the oldest generation when it ends (not frozen): a
    cycle made there and dropped afterwards is freed by the next full collection, and a
    host's own frozen objects stay frozen."""
    import weakref

    class Node:
        pass

    with gc_paused():
        a, b = Node(), Node()
        a.other, b.other = b, a  # a cycle: only the collector frees it
        dead = weakref.ref(a)
    assert gc.get_freeze_count() == 0
    del a, b
    gc.collect()
    assert dead() is None
    gc.freeze()  # a host that froze its own objects
    try:
        frozen = gc.get_freeze_count()
        with gc_paused():
            pass
        assert gc.get_freeze_count() == frozen
    finally:
        gc.unfreeze()


def test_compile_leaves_the_collector_on_and_matches_the_golden():
    c = compile_model(parse_file(ROOT / "models" / "msd.yaml"))
    assert gc.isenabled()
    assert c.source == (ROOT / "generated" / "msd.py").read_text(encoding="utf-8")


def test_skeleton_memo_remembers_passes_only(monkeypatch):
    src = (ROOT / "generated" / "msd.py").read_text(encoding="utf-8")
    calls = []
    real = skeleton._check_skeleton
    monkeypatch.setattr(skeleton, "_check_skeleton", lambda t, b: (calls.append(1), real(t, b))[1])
    monkeypatch.setattr(skeleton, "_PASSED", {})
    skeleton.check_skeleton(src)
    skeleton.check_skeleton(src)
    assert len(calls) == 1  # the second check of the same text is a lookup
    bad = src + "\nprint('spliced')\n"  # a foreign statement after the runtime
    for _ in range(2):  # a refusal is never remembered as a pass
        with pytest.raises(skeleton.SkeletonError):
            skeleton.check_skeleton(bad)
    assert len(calls) == 3
