"""bgc.fused: the generated rhs and Jacobian rewritten for JAX and jax.jit-compiled, against
closed forms and against the numpy module (skipped without JAX)."""
from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("jax")
pytest.importorskip("array_api_compat")

from bgc.fused import jax_functions  # noqa: E402


def test_fused_pendulum_is_the_closed_form_with_batched_parameters(gen):
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


def test_fused_msd_equals_the_numpy_module(gen):
    mod = gen("msd")
    x = np.random.default_rng(3).normal(size=(mod.N_STATES, 4))
    rhs, jac = jax_functions(mod)
    np.testing.assert_allclose(np.asarray(rhs(0.5, x)), mod.rhs(0.5, x), rtol=1e-14)
    np.testing.assert_array_equal(np.asarray(jac(0.5, x)), mod.jacobian(0.5, x))
    # unbatched state too
    np.testing.assert_allclose(np.asarray(rhs(0.5, x[:, 0])), mod.rhs(0.5, x[:, 0]),
                               rtol=1e-14)
