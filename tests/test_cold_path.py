"""Issue 27, no work done twice on the cold path: the C target's wrapper holds no numpy
equations (the library computes them; the numpy module is printed only when asked for), and
each generated text is parsed once, for its check, and compiled from that tree. The wrapper's
check refuses anything that is not the template's, as the numpy module's does."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bgc.backends import skeleton
from bgc.backends.c import build as cbuild
from bgc.backends.load import c_files, load_module
from bgc.backends.skeleton import WRAPPER_MARK, SkeletonError, check_wrapper
from bgc.run import driver

ROOT = Path(__file__).resolve().parent.parent
MSD = ROOT / "models" / "msd.yaml"  # m = 2 kg, k = 200 N/m, c = 4 N s/m, F = F0 = 10 N

needs_cc = pytest.mark.skipif(not (cbuild.available() and cbuild.runtime_sources()),
                              reason="no C compiler or C runtime (CI installs one)")


@pytest.fixture
def fresh_cache(tmp_path, monkeypatch):
    cache = tmp_path / "cache"
    cache.mkdir(mode=0o700)
    monkeypatch.setenv("BGC_CACHE_DIR", str(cache))
    return cache


def _wrapper():
    c = driver.compile_source(MSD, target="c")
    return c, c_files(c)[1]


def test_the_c_compile_prints_no_numpy_module_and_the_wrapper_no_equations():
    c, wrapper = _wrapper()
    assert c.text is None  # stage 7 for numpy did not run
    assert "print" not in [s for s, _ in c.times]
    numpy_part = wrapper.rpartition(WRAPPER_MARK)[0]
    for fn in ("rhs", "jacobian", "outputs", "initial_state", "input_jacobian",
               "output_jacobian"):
        assert f"\ndef {fn}(" not in numpy_part, fn
    assert "\nX0 = None\n" in numpy_part  # the binding sets it from the library
    # the numpy module is still there for whoever asks, the same as the numpy target's
    assert c.source == (ROOT / "generated" / "msd.py").read_text(encoding="utf-8")


def test_each_text_is_checked_once(monkeypatch, fresh_cache):
    """A syntax tree is built only for a text's model part, once: rendering checks it, loading
    finds it checked (the template's verbatim parts are compared as text)."""
    parsed = []
    real = skeleton._parse
    monkeypatch.setattr(skeleton, "_parse", lambda t, w: (parsed.append(w), real(t, w))[1])
    monkeypatch.setattr(skeleton, "_PASSED", {})
    b = driver.build(MSD, backend="numpy", use_cache=False)
    assert parsed == ["generated module"]
    assert b.module.rhs(0.0, b.module.X0).shape == (2,)
    if cbuild.available() and cbuild.runtime_sources():
        parsed.clear()
        b = driver.build(MSD, backend="c")
        # the wrapper's two parts, once each; no numpy module with equations printed or parsed
        assert parsed == ["generated module", "the wrapper's C part"]
        assert b.compiled.text is None


@pytest.mark.parametrize("where, edit", [
    ("numpy part", lambda w: w.replace("\nN_STATES = ", "\nimport os\nN_STATES = ", 1)),
    ("numpy part", lambda w: w.replace("\nX0 = None\n", "\nX0 = None\nrhs = None\n", 1)),
    ("C part", lambda w: w.replace("\nC_DIGEST = ", "\nimport os\nC_DIGEST = ", 1)),
    ("C part", lambda w: w.replace("\nC_DIGEST = ", "\n_C_NP = 3\nC_DIGEST = ", 1)),
    ("binding", lambda w: w.replace("\ndef _autobind():", "\nimport os\ndef _autobind():", 1)),
    ("binding", lambda w: w + "\nprint('spliced')\n"),
    # a string left open in the numpy part swallows the marker and the C constants
    ("numpy part", lambda w: w.replace(f"\n\n\n{WRAPPER_MARK}", '\n\n\nx = """\n'
                                       + WRAPPER_MARK, 1).replace(
        "\n_C_NWS = ", '\n"""\n_C_NWS = ', 1)),
])
def test_the_wrapper_check_refuses_what_is_not_the_template(where, edit):
    _, wrapper = _wrapper()
    check_wrapper(wrapper)
    bad = edit(wrapper)
    assert bad != wrapper, where
    with pytest.raises(SkeletonError):
        check_wrapper(bad)
    with pytest.raises(SkeletonError):
        load_module(bad, "refused_wrapper", wrapper=True)


@needs_cc
def test_c_wrapper_input_overrides_and_linear_parts_through_bgc(fresh_cache):
    """u= and B, C, D run in the numpy module bgc provides on first use: a constant force
    override settles at its static deflection F/k (closed form), and C = d(position)/dx."""
    mod = driver.build(MSD, backend="c").module
    assert mod._NP_MOD is None  # not made until something needs it
    np.testing.assert_allclose(mod.X0, [0.0, 0.0])
    r = mod.simulate((0.0, 40.0), t_eval=[40.0], method="Radau", rtol=1e-10, atol=1e-12,
                     u={"F": lambda t: 25.0 + 0.0 * np.asarray(t)})
    assert abs(float(r.y["position"][-1]) - 25.0 / 200.0) < 1e-6
    x = np.array([0.3, 0.01])
    dx = mod.rhs(0.0, x, u={"F": lambda t: 0.0 * np.asarray(t)})
    # p = 0.3 kg m/s, q = 0.01 m: dp/dt = -k q - c p/m, dq/dt = p/m
    np.testing.assert_allclose(dx, [-200.0 * 0.01 - 4.0 * 0.3 / 2.0, 0.3 / 2.0], rtol=1e-12)
    C, D = mod.output_jacobian(0.0, x)
    assert C[mod.OUTPUT_LABELS.index("position")].tolist() == [0.0, 1.0]


@needs_cc
def test_a_standalone_wrapper_says_what_it_cannot_do(tmp_path, fresh_cache):
    c = driver.compile_source(MSD, target="c")
    from bgc.backends.load import write_c

    path = write_c(c, tmp_path / "out")
    import importlib.util

    spec = importlib.util.spec_from_file_location("msd_standalone", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    assert mod.simulate((0.0, 1.0)).x.shape == (2, 1001)
    with pytest.raises(RuntimeError, match="numpy module"):
        mod.rhs(0.0, mod.X0, u={"F": lambda t: 0.0})


def test_the_c_sources_print_with_the_collector_paused(monkeypatch):
    """The C stages print with the cyclic collector off (its full passes over the compile's
    objects found nothing and cost as much as the printing), and leave it as they found it,
    also when the printer fails."""
    import gc

    from bgc.backends.c import printer as cprinter

    seen = []
    real = cprinter.render_c
    monkeypatch.setattr(cprinter, "render_c",
                        lambda *a, **k: (seen.append(gc.isenabled()), real(*a, **k))[1])
    c = driver.compile_source(MSD, target="c")
    assert gc.isenabled()
    c_files(c)
    assert seen == [False] and gc.isenabled()

    def broken(*a, **k):
        raise RuntimeError("printer failed")
    monkeypatch.setattr(cprinter, "render_c", broken)
    with pytest.raises(RuntimeError, match="printer failed"):
        c_files(c)
    assert gc.isenabled()


@needs_cc
def test_the_runtime_builds_beside_the_compile(fresh_cache, monkeypatch):
    """A cold C build starts the compiler on the runtime's objects before the compile runs
    (a background thread); the library links what it built, each runtime source compiled
    once, and the thread is done when the build returns."""
    from bgc.base.store import Cache

    order, compiled = [], []
    real_start, real_cc = cbuild.start_runtime, cbuild._cc
    monkeypatch.setattr(cbuild, "start_runtime", lambda cache: (order.append("runtime"),
                                                                real_start(cache))[1])
    monkeypatch.setattr(cbuild, "_cc", lambda args, *a, **k: (compiled.append(args),
                                                              real_cc(args, *a, **k))[1])
    real_compile = driver.compile_source
    monkeypatch.setattr(driver, "compile_source",
                        lambda *a, **k: (order.append("compile"), real_compile(*a, **k))[1])
    b = driver.build(MSD, backend="c")
    assert order == ["runtime", "compile"]
    rt_dir = cbuild.runtime_sources()[0].parent
    runtime_objs = [a[a.index("-o") + 1] for a in compiled
                    if "-c" in a and Path(a[a.index("-c") + 1]).parent == rt_dir]
    names = sorted(Path(o).name for o in runtime_objs)
    assert names == sorted(s.stem + ".o" for s in cbuild.runtime_sources())  # once each
    assert Cache().get("c-runtime", cbuild.runtime_key()) is not None
    assert not cbuild._EARLY  # joined
    x = b.module.simulate((0.0, 0.5)).x
    assert np.isfinite(x).all()


def test_a_failing_early_runtime_build_is_silent(fresh_cache, monkeypatch):
    """Without a compiler, the early runtime build says nothing; the build reports it as it
    always did (one error, no compiler)."""
    from bgc.base.store import Cache

    monkeypatch.setenv("CC", "/nonexistent/cc")
    cache = Cache()
    cbuild.start_runtime(cache)
    cbuild._wait_runtime(cache)  # (nothing raised in or by the thread)
    assert not cbuild._EARLY
    with pytest.raises(cbuild.CompilerMissing):
        cbuild.build_library(fresh_cache, [], cache=cache)


@needs_cc
def test_a_failing_compile_stops_the_early_runtime_build(tmp_path, fresh_cache, monkeypatch):
    """A C compile that fails (a user's error) stops the runtime's early build: its error is
    raised as always, no compiler starts after it, and the cache keeps no runtime entry, whole
    or half-built."""
    from bgc.base.errors import ModelError
    from bgc.base.store import Cache

    started = []
    real_start = cbuild.start_runtime
    monkeypatch.setattr(cbuild, "start_runtime", lambda cache: (
        real_start(cache), started.append(cbuild._EARLY[str(cache.path)]))[0])
    bad = tmp_path / "bad.yaml"
    bad.write_text(MSD.read_text(encoding="utf-8").replace("bonds:", "bonds:\n  - [nowhere, m]", 1))
    with pytest.raises(ModelError):
        driver.build(bad, backend="c")
    assert len(started) == 1 and started[0][1].is_set() and not cbuild._EARLY
    started[0][0].join()
    assert Cache().get("c-runtime", cbuild.runtime_key()) is None
    left = list((fresh_cache / "c-runtime").rglob("*"))  # (the compiler's identity stays)
    assert not [p for p in left if p.suffix == ".o" or p.name.startswith(".")], left
