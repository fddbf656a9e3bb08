"""The numpy runtime's Radau keeps its LUs at held steps by standing in for scipy's identity.

The runtime (templates/numpy/runtime.py, ``_guard_solves``) replaces ``solver.I`` by an object
whose ``c * I - J`` is an unbuilt matrix, so that a factorisation asked for the same (c, J) again
is given back instead of recomputed. That relies on how scipy's Radau forms its two Newton
matrices. These tests pin that assumption to the installed scipy: if a scipy release forms them
differently, they fail here, by name, rather than as a slow run or a TypeError in a user's model.
"""

import inspect

import numpy as np
import pytest
from scipy.integrate._ivp import radau


def test_scipy_radau_forms_its_matrices_as_c_times_i_minus_j():
    """The two lines the stand-in is written against (scipy >= 1.10 up to the installed one)."""
    src = inspect.getsource(radau.Radau._step_impl)
    assert "self.lu(MU_REAL / h * self.I - J)" in src
    assert "self.lu(MU_COMPLEX / h * self.I - J)" in src
    # I is used nowhere else in the step: the stand-in needs no other operation.
    assert src.count("self.I") == 2


def _stand_in_namespace():
    """The runtime's stand-in classes, executed from the template file itself."""
    from bgc.base.paths import templates_dir

    text = (templates_dir() / "numpy" / "runtime.py").read_text(encoding="utf-8")
    start = text.index("class _Identity:")
    end = text.index("def _newton_nonfinite")
    ns: dict = {}
    exec(text[start:end], ns)  # noqa: S102 - the project's own runtime file
    return ns


@pytest.mark.parametrize("c", [2.5, 1.5 + 0.75j])
def test_the_stand_in_builds_the_same_matrix(c):
    """``c * I - J`` through the stand-in, once built, equals the matrix scipy would form."""
    ns = _stand_in_namespace()
    rng = np.random.default_rng(7)
    J = rng.normal(size=(5, 5))
    eye = np.identity(5)
    shifted = c * ns["_Identity"](eye) - J
    assert isinstance(shifted, ns["_Shifted"])
    np.testing.assert_array_equal(shifted.c * shifted.eye - shifted.J, c * eye - J)
