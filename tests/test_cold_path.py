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
    monkeypatch.setattr(skeleton, "_PASSED", set())
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
