"""Generated modules on another array library: rhs, jacobian and outputs of msd, pendulum and
the 3R2S on array-api-strict arrays (a namespace with nothing but the standard) at random
points, against the same functions on numpy arrays."""
from __future__ import annotations

import numpy as np
import pytest

xps = pytest.importorskip("array_api_strict")
from array_api_strict._array_object import Array as StrictArray  # noqa: E402

pytest.importorskip("array_api_compat")


def _points(mod, rng, batch):
    """Random states around the initial state: x0 + a perturbation of its own size."""
    x0 = np.asarray(mod.X0, dtype=float).reshape(mod.N_STATES, 1)
    scale = np.maximum(np.abs(x0), 0.1)
    return x0 + 0.3 * scale * rng.standard_normal((mod.N_STATES, batch))


@pytest.mark.parametrize("name", ["msd", "pendulum", "mech3r2s"])
def test_rhs_jacobian_outputs_on_array_api_strict_equal_numpy(gen, name):
    mod = gen(name)
    rng = np.random.default_rng(4)
    x = _points(mod, rng, 5)
    t = 0.7
    # batched parameters too: every scalar parameter scaled per instance (numpy arrays, as a
    # caller passes them; the module turns them into the namespace's arrays)
    p = {k: v * rng.uniform(0.8, 1.2, 5) for k, v in mod.PARAM_DEFAULTS.items()
         if np.ndim(v) == 0}
    xs = xps.asarray(x)
    for fn in (mod.rhs, mod.jacobian):
        for pp in (None, p):
            a = fn(t, xs, pp)
            assert isinstance(a, StrictArray) and a.dtype == xps.float64
            b = fn(t, x, pp)
            assert isinstance(b, np.ndarray)
            np.testing.assert_allclose(np.asarray(a), b, rtol=1e-13, atol=1e-13 * np.max(
                np.abs(b)))
    ya, yb = mod.outputs(t, xs, p), mod.outputs(t, x, p)
    assert set(ya) == set(mod.OUTPUT_NAMES)
    for k in ya:
        assert isinstance(ya[k], StrictArray)
        assert ya[k].shape == yb[k].shape
        np.testing.assert_allclose(np.asarray(ya[k]), yb[k], rtol=1e-13,
                                   atol=1e-13 * (np.max(np.abs(yb[k])) + 1))


def test_the_jacobian_on_strict_arrays_is_the_derivative_of_the_rhs(gen):
    # independent of the numpy path: central differences of the strict rhs
    mod = gen("pendulum")
    x = xps.asarray(_points(mod, np.random.default_rng(1), 3))
    J = np.asarray(mod.jacobian(0.0, x))
    h = 1e-6
    for j in range(mod.N_STATES):
        e = np.zeros((mod.N_STATES, 1))
        e[j] = h
        d = (np.asarray(mod.rhs(0.0, x + xps.asarray(e))) -
             np.asarray(mod.rhs(0.0, x - xps.asarray(e)))) / (2 * h)
        np.testing.assert_allclose(J[:, j], d, rtol=1e-6, atol=1e-8)


def test_numpy_inputs_stay_on_numpy_without_array_api_compat(gen, monkeypatch):
    import sys

    mod = gen("pendulum")
    monkeypatch.setitem(sys.modules, "array_api_compat", None)  # import fails
    x = np.array([[0.1], [0.4]])
    dx = mod.rhs(0.0, x)
    # closed form: q'' = -(g/l) sin q with p = m l^2 q'
    np.testing.assert_allclose(dx[:, 0], [-9.81 * np.sin(0.4), 0.1], rtol=1e-15)
    assert mod._namespace(x) is np
