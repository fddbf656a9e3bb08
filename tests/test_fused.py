"""bgc.fused: the generated rhs and Jacobian rewritten for JAX and jax.jit-compiled, against
closed forms and against the numpy module (skipped without JAX).

JAX starts threads when it is imported, and other tests in the same pytest worker fork (the
accuracy studies run each method in a forked child; JAX warns that a fork after its threads
may deadlock). So each check runs in its own interpreter, and JAX never loads in the worker."""
from __future__ import annotations

import importlib.util
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

if importlib.util.find_spec("jax") is None or importlib.util.find_spec("array_api_compat") is None:
    pytest.skip("could not import 'jax' or 'array_api_compat'", allow_module_level=True)

ROOT = Path(__file__).resolve().parents[1]

_PRELUDE = f"""
import importlib.util, sys
import numpy as np
from bgc.fused import jax_functions

def gen(name):
    spec = importlib.util.spec_from_file_location("bgc_generated_" + name,
                                                  {str(ROOT / "generated")!r} + "/" + name + ".py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod
    spec.loader.exec_module(mod)
    return mod
"""


def _run(body: str):
    code = _PRELUDE + textwrap.dedent(body) + "\nprint('checked')\n"
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0 and r.stdout.strip().endswith("checked"), r.stderr[-3000:]


def test_fused_pendulum_is_the_closed_form_with_batched_parameters():
    _run("""
        mod = gen("pendulum")
        rng = np.random.default_rng(2)
        x = np.stack([rng.normal(0, 1, 6), rng.uniform(-3, 3, 6)])
        g = np.linspace(1.0, 20.0, 6)
        rhs, jac = jax_functions(mod, {"g": g})
        dx, J = np.asarray(rhs(0.0, x)), np.asarray(jac(0.0, x))
        p, q = x
        # m = l = 1: p' = -g sin q, q' = p; Jacobian [[0, -g cos q], [1, 0]]
        np.testing.assert_allclose(dx, [-g * np.sin(q), p], rtol=1e-14, atol=1e-14)
        np.testing.assert_allclose(J[0, 1], -g * np.cos(q), rtol=1e-14, atol=1e-14)
        np.testing.assert_allclose(J[1, 0], 1.0)
        assert J[0, 0].tolist() == [0.0] * 6 and J[1, 1].tolist() == [0.0] * 6
        assert dx.dtype == np.float64
    """)


def test_fused_msd_equals_the_numpy_module():
    _run("""
        mod = gen("msd")
        x = np.random.default_rng(3).normal(size=(mod.N_STATES, 4))
        rhs, jac = jax_functions(mod)
        np.testing.assert_allclose(np.asarray(rhs(0.5, x)), mod.rhs(0.5, x), rtol=1e-14)
        np.testing.assert_array_equal(np.asarray(jac(0.5, x)), mod.jacobian(0.5, x))
        # unbatched state too
        np.testing.assert_allclose(np.asarray(rhs(0.5, x[:, 0])), mod.rhs(0.5, x[:, 0]),
                                   rtol=1e-14)
    """)
