"""The C runtime's DOP853 (templates/c/runtime/bgc_dop853.c): against closed forms, against
scipy's DOP853 (an independent implementation of the same method), batched against single
runs, across a breakpoint, and its coefficient table against scipy's.
"""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from bgc.backends import load as backends
from bgc.backends.c import build as cbuild
from bgc.backends.load import load_module
from bgc.format.scene import parse_scene
from bgc.run.driver import compile_file
from bgc.run.runner import compile_scene

ROOT = Path(__file__).resolve().parents[1]
needs_cc = pytest.mark.skipif(not (cbuild.available() and cbuild.runtime_sources()),
                              reason="no C compiler or C runtime")
_built: dict = {}


def _pair(name):
    """(numpy module, C module) of models/<name>.yaml."""
    if name not in _built:
        c = compile_file(ROOT / "models" / f"{name}.yaml")
        _, c_mod = backends.load(f"{name}_dop_c", "c", None, lambda: c, None)
        _built[name] = (load_module(c.source, f"{name}_dop_np"), c_mod)
    return _built[name]


def msd_closed_form(t, m, k, c, F0):
    """The underdamped step response x(t) of m x'' + c x' + k x = F0 from rest."""
    wn = np.sqrt(k / m)
    z = c / (2 * np.sqrt(k * m))
    wd = wn * np.sqrt(1 - z * z)
    return F0 / k * (1 - np.exp(-z * wn * t) * (np.cos(wd * t) + z / np.sqrt(1 - z * z)
                                                   * np.sin(wd * t)))


def test_the_table_is_the_published_method():
    """The committed header holds the coefficients scipy tabulates for DOP853."""
    r = subprocess.run([sys.executable, str(ROOT / "scripts" / "dop853_table.py"), "--check"])
    assert r.returncode == 0, "templates/c/runtime/bgc_dop853_tab.h is stale: rerun the script"


@needs_cc
@pytest.mark.parametrize("rtol, tol", [(1e-6, 2e-6), (1e-10, 2e-10)])
def test_step_response_against_the_closed_form(rtol, tol):
    """A batch over mass and damping: every instance against its closed form (relative to
    the static deflection F0/k), the error shrinking with rtol."""
    _, mod = _pair("msd")
    ms = np.array([1.0, 2.0, 5.0])
    cs = np.array([0.5, 4.0, 10.0])
    t = np.linspace(0.0, 3.0, 301)
    r = mod.simulate((0.0, 3.0), t_eval=t, method="DOP853", rtol=rtol, atol=1e-14,
                     p={"m": ms, "c": cs})
    q = r.x[list(mod.STATE_NAMES).index("q_spring")] if "q_spring" in mod.STATE_NAMES else None
    pos = r.y["position"]
    for i in range(3):
        exact = msd_closed_form(t, ms[i], 200.0, cs[i], 10.0)
        assert np.max(np.abs(pos[i] - exact)) <= tol * 10.0 / 200.0 * 50, (i, rtol)
    assert r.stats["njev"] == 0 and r.stats["nlu"] == 0  # explicit: no Jacobian, no LU
    assert q is None or np.allclose(q, pos)


@needs_cc
def test_against_scipys_dop853_on_a_nonlinear_model():
    """Van der Pol at mu = 1 (non-stiff; the model's default mu = 1e3 is stiff) against scipy's
    DOP853 at tight tolerances on the numpy module's rhs."""
    np_mod, mod = _pair("van_der_pol")
    p = {"mu": 1.0}
    t = np.linspace(0.0, 10.0, 201)
    x0 = np_mod.initial_state(p)
    ref = solve_ivp(lambda tt, x: np_mod.rhs(tt, x, p), (0.0, 10.0), x0, method="DOP853",
                    t_eval=t, rtol=1e-13, atol=1e-13)
    r = mod.simulate((0.0, 10.0), t_eval=t, method="DOP853", rtol=1e-11, atol=1e-13, p=p)
    scale = np.max(np.abs(ref.y))
    assert np.max(np.abs(r.x - ref.y)) <= 1e-8 * scale


@needs_cc
def test_a_batch_equals_its_single_runs():
    _, mod = _pair("msd")
    ks = np.array([50.0, 200.0, 800.0, 3200.0])
    t = np.linspace(0.0, 2.0, 51)
    rb = mod.simulate((0.0, 2.0), t_eval=t, method="DOP853", rtol=1e-8, p={"k": ks})
    for i, k in enumerate(ks):
        r1 = mod.simulate((0.0, 2.0), t_eval=t, method="DOP853", rtol=1e-8, p={"k": k})
        np.testing.assert_array_equal(rb.x[:, i], r1.x)


@needs_cc
def test_a_delayed_step_is_a_breakpoint():
    """msd_step's force starts at t = 1 s: the run restarts there, and the response after it
    is the closed form shifted by 1 s (the mass at rest before)."""
    sc = parse_scene(ROOT / "models" / "scenes" / "msd_step.yaml")
    compiled, _ = compile_scene(sc)
    _, mod = backends.load("msd_step_dop_c", "c", None, lambda: compiled, None)
    t = np.linspace(0.0, 5.0, 501)
    r = mod.simulate((0.0, 5.0), t_eval=t, method="DOP853", rtol=1e-10, atol=1e-14,
                     breakpoints=(1.0,))
    exact = np.where(t < 1, 0.0, msd_closed_form(np.maximum(t - 1, 0), 3.0, 200.0, 4.0, 10.0))
    assert np.max(np.abs(r.y["position"] - exact)) <= 1e-9


@needs_cc
def test_an_explicit_method_on_a_stiff_model_is_stopped_not_wrong():
    """With a tiny max_steps DOP853 stops with the runtime's located message (not a wrong
    answer); the method's name is in it."""
    _, mod = _pair("msd")
    with pytest.raises(Exception) as err:
        mod.simulate((0.0, 100.0), method="DOP853", rtol=1e-10, max_steps=20, p={"k": 1e9})
    assert "DOP853" in str(err.value) and "max_steps" in str(err.value)


_OSCILLATOR_MAIN = r"""
#include <math.h>
#include <stdio.h>
#include "bgc_runtime.h"
static int rhs(double t, const double *x, const double *p, double *dx)
{ (void)t; (void)p; dx[0] = x[1]; dx[1] = -x[0]; return 0; }
static int jac(double t, const double *x, const double *p, double *jv)
{ (void)t; (void)x; (void)p; jv[0] = 1.0; jv[1] = -1.0; return 0; }
int main(void)
{
    static const int row[2] = {0, 1}, col[2] = {1, 0};
    bgc_model m = {.n = 2, .np = 0, .nnz = 2, .jac_row = row, .jac_col = col, .rhs = rhs,
                   .jac = jac};
    double atol = 1e-14, tout[101], y[202], x0[2] = {1.0, 0.0}, brk = 3.3;
    for (int k = 0; k < 101; k++) tout[k] = 0.1 * k;
    bgc_options o = {.method = BGC_DOP853, .rtol = 1e-10, .atol = &atol, .atol_len = 1,
                     .t_out = tout, .n_out = 101, .breaks = &brk, .n_breaks = 1};
    bgc_stats st;
    int s = bgc_integrate(&m, NULL, 0.0, 10.0, x0, &o, y, &st);
    double err = 0.0;
    for (int k = 0; k < 101; k++) err = fmax(err, fabs(y[2 * k] - cos(tout[k])));
    printf("%d %.3e %ld %ld\n", s, err, st.nfev, st.njev);
    return s != 0 || !(err < 1e-8);
}
"""


@needs_cc
def test_the_c_method_alone_under_address_and_undefined_sanitizers(tmp_path):
    """The runtime with DOP853 and a hand-written oscillator, built with AddressSanitizer and
    UBSan: cos(t) within 1e-8 at rtol 1e-10 across a breakpoint, no invalid access, no
    undefined behaviour (a buffer overrun here once corrupted the heap silently)."""
    cc = cbuild.compiler()
    main = tmp_path / "main.c"
    main.write_text(_OSCILLATOR_MAIN)
    rt = ROOT / "templates" / "c" / "runtime"
    exe = tmp_path / "osc"
    r = subprocess.run(cc + ["-std=c99", "-g", "-O1", "-fsanitize=address,undefined",
                             "-fno-sanitize-recover=undefined", f"-I{rt}", "-o", str(exe),
                             str(main)] + [str(p) for p in sorted(rt.glob("*.c"))] + ["-lm"],
                       capture_output=True, text=True)
    if r.returncode != 0:
        pytest.skip(f"cannot build with sanitizers: {r.stderr[-300:]}")
    r = subprocess.run([str(exe)], capture_output=True, text=True, timeout=120,
                       env={"ASAN_OPTIONS": "detect_leaks=1"})
    assert r.returncode == 0, (r.stdout, r.stderr[-3000:])
    status, err, nfev, njev = r.stdout.split()
    assert status == "0" and float(err) < 1e-8 and njev == "0" and int(nfev) > 0
