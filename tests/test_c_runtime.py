"""The C runtime (templates/c/runtime/*.c) against answers from outside it: closed forms,
scipy (DOP853, Radau, expm), numpy.linalg.solve, and the Radau IIA collocation conditions.
The runtime is built with the system compiler together with hand-written models
(tests/c_models/models.c) and driven through ctypes (tests/c_runtime_harness.py)."""

from __future__ import annotations

import ctypes as C
import sys
from pathlib import Path

import numpy as np
import pytest
import scipy.linalg
from scipy.integrate import solve_ivp

sys.path.insert(0, str(Path(__file__).parent))
import c_runtime_harness as H  # noqa: E402

from bgc.lower.sparse_lu import make_plan, plan_c  # noqa: E402

METHODS = ("Rodas4", "Radau5")
ORDER = {"Rodas4": 4, "Radau5": 5}

if H.compiler() is None:
    pytest.skip("no C compiler: set CC or install cc to test the C runtime",
                allow_module_level=True)


@pytest.fixture(scope="module")
def lib(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("c_runtime")
    omp = H.openmp_works(H.compiler(), tmp)
    return H.Lib(H.build(tmp / "rt.so", openmp=omp))


def pend(lib):
    return lib.model("pend", 2, [0, 1], [1, 0], 1)


def pend_ref(t, x0, g=9.81):
    return solve_ivp(lambda t, y: [y[1], -g * np.sin(y[0])], (0, t[-1]), x0, method="DOP853",
                     rtol=1e-13, atol=1e-14, t_eval=t).y.T


def test_warning_free_build_without_openmp(tmp_path):
    """-Wall -Wextra give no warning (build raises on any stderr), also without OpenMP, and
    batches still run (serially)."""
    lib = H.Lib(H.build(tmp_path / "serial.so", openmp=False))
    assert lib.lib.bgc_have_openmp() == 0
    m = pend(lib)
    P = np.array([[9.81], [4.0]])
    status, Y, st = m.run_batch(P, 0.0, 1.0, np.array([[1.0, 0], [0.5, 0]]), t_out=[1.0])
    assert status == 0 and all(s.status == 0 for s in st)
    for k in range(2):
        assert np.allclose(Y[k, 0], pend_ref([0, 1.0], [1.0, 0] if k == 0 else [0.5, 0],
                                              g=P[k, 0])[-1], rtol=0, atol=1e-5)


def test_radau_constants(lib):
    """T^-1 A^-1 T has the real eigenvalue gamma and the block [[alpha, -beta], [beta,
    alpha]] for the Radau IIA collocation matrix A (built here from its definition), and the
    error estimate's weights are those of the embedded order-3 formula with b0 = 1/gamma."""
    k = np.zeros(26)
    lib.lib.bgc_radau5_constants(H.ptr(k))
    s6 = np.sqrt(6)
    c = np.array([(4 - s6) / 10, (4 + s6) / 10, 1.0])
    assert np.allclose(k[:2], c[:2], rtol=1e-15)
    V = np.vander(c, 3, increasing=True).T  # V[q, j] = c_j^q
    A = np.array([np.linalg.solve(V, [ci ** (q + 1) / (q + 1) for q in range(3)]) for ci in c])
    T, Ti = k[5:14].reshape(3, 3), k[14:23].reshape(3, 3)
    gam, alpha, beta = k[2:5]
    Lam = np.array([[gam, 0, 0], [0, alpha, -beta], [0, beta, alpha]])
    assert np.allclose(Ti @ T, np.eye(3), atol=1e-14)
    assert np.allclose(Ti @ np.linalg.inv(A) @ T, Lam, atol=1e-12)
    g0 = 1 / gam
    bh = np.linalg.solve(V, [1 - g0, 1 / 2, 1 / 3])
    e = (bh - A[2]) @ np.linalg.inv(A)
    assert np.allclose(k[23:26], e / g0, rtol=1e-12)


def msd_exact(t, m_, k, c, F, w, x0=(1.0, 0.0)):
    """Closed form of m x'' + c x' + k x = F cos(w t): particular X cos + Y sin, plus the
    homogeneous solution that fits x0."""
    M = np.array([[k - m_ * w ** 2, c * w], [-c * w, k - m_ * w ** 2]])
    X, Yc = np.linalg.solve(M, [F, 0.0])
    lam = np.roots([m_, c, k])
    a, b = np.linalg.solve([[1, 1], lam], [x0[0] - X, x0[1] - Yc * w])
    t = np.asarray(t, dtype=float)
    xs = (a * np.exp(lam[0] * t) + b * np.exp(lam[1] * t)).real + X * np.cos(w * t) \
        + Yc * np.sin(w * t)
    vs = (a * lam[0] * np.exp(lam[0] * t) + b * lam[1] * np.exp(lam[1] * t)).real \
        - X * w * np.sin(w * t) + Yc * w * np.cos(w * t)
    return np.stack([xs, vs], axis=-1)


def fixed_step_orders(mod, p, x0, exact, method, t1=2.0):
    """Observed orders from the error at t1 with fixed steps h = 2^-3, 2^-4, 2^-5 (h0 =
    max_step; tolerances so loose that every step is accepted)."""
    errs = []
    for k in (3, 4, 5):
        h = 2.0 ** -k
        status, Y, st = mod.run(p, 0.0, t1, x0, method=method, rtol=1e6, atol=1e6, h0=h,
                                max_step=h, t_out=[t1])
        assert status == 0 and st.nreject == 0 and st.naccept == t1 / h
        errs.append(np.abs(Y[0] - exact).max())
    return errs, np.log2(np.array(errs[:-1]) / np.array(errs[1:]))


MSD = (1.0, 40.0, 0.8, 2.0, 3.0)


@pytest.mark.parametrize("method", METHODS)
def test_convergence_order_closed_form(lib, method):
    """The forced mass-spring-damper (a time input) against its closed form: the error falls
    like h^p, p the method's order (Radau's Newton iteration is exact on a linear problem,
    so loose tolerances do not spoil it)."""
    mod = lib.model("msd", 2, [0, 1, 1], [1, 0, 1], 5, time_inputs=True)
    errs, orders = fixed_step_orders(mod, MSD, [1.0, 0.0], msd_exact(2.0, *MSD), method)
    assert np.all(np.abs(orders - ORDER[method]) < 0.5), (errs, orders)


def test_convergence_order_nonlinear_rodas4(lib):
    """Rodas4 (no iteration) on the nonlinear pendulum against DOP853 at rtol 1e-13."""
    errs, orders = fixed_step_orders(pend(lib), [9.81], [1.0, 0.0],
                                     pend_ref([0.0, 2.0], [1.0, 0.0])[-1], "Rodas4")
    assert np.all(np.abs(orders - 4) < 0.5), (errs, orders)


@pytest.mark.parametrize("method", METHODS)
def test_forced_msd_closed_form(lib, method):
    """Forced mass-spring-damper (time input: Rodas4 takes df/dt) against its closed form at
    dense-output times; the error falls with the tolerance and stays within 20 * tol."""
    mod = lib.model("msd", 2, [0, 1, 1], [1, 0, 1], 5, time_inputs=True)
    t = np.linspace(0, 5, 101)
    exact = msd_exact(t, *MSD)
    errs = []
    for tol in (1e-5, 1e-7, 1e-9):
        status, Y, st = mod.run(MSD, 0.0, 5.0, [1.0, 0.0], method=method,
                                rtol=tol, atol=tol, t_out=t)
        assert status == 0
        errs.append(np.abs(Y - exact).max())
        assert errs[-1] < 20 * tol * np.abs(exact).max(), (tol, errs[-1])
    assert errs[0] > errs[1] > errs[2]


@pytest.mark.parametrize("method", METHODS)
def test_pendulum_tight(lib, method):
    """At rtol = atol = 1e-11 the nonlinear pendulum matches DOP853 (rtol 1e-13) to 1e-8."""
    t = np.linspace(0, 10, 41)
    status, Y, st = pend(lib).run([9.81], 0.0, 10.0, [2.5, 0.0], method=method, rtol=1e-11,
                                  atol=1e-11, t_out=t)
    assert status == 0 and st.n_done == len(t)
    assert np.abs(Y - pend_ref(t, [2.5, 0.0])).max() < 1e-8


@pytest.mark.parametrize("method", METHODS)
def test_stiff_chain_against_expm(lib, method):
    """Two masses, a stiff spring (k = 1e6) and stiff dampers (c = 1e4; eigenvalues from about
    -1e-4 to -2e4): the result matches expm(A t) x0 to the tolerance, with far fewer steps
    than an explicit method's stability bound would allow."""
    N, p = 2, [2, 1e6, 1.0, 1e4, 1.0]
    rows, cols = H.chain_pattern(N)
    mod = lib.model("chain", 2 * N, rows, cols, 5)
    A = H.chain_matrix(N, *p[1:])
    x0 = np.array([0.01, 0.0, 0.0, 1.0])
    t = np.linspace(0, 2, 21)
    exact = np.array([scipy.linalg.expm(A * ti) @ x0 for ti in t])
    status, Y, st = mod.run(p, 0.0, 2.0, x0, method=method, rtol=1e-8, atol=1e-10, t_out=t)
    assert status == 0
    assert np.abs(Y - exact).max() < 1e-6 * np.abs(exact).max()
    lam_max = np.abs(np.linalg.eigvals(A)).max()
    assert st.naccept < 0.02 * 2.0 * lam_max  # an explicit method needs ~2 * lam_max steps


@pytest.mark.parametrize("method", METHODS)
def test_l_stability(lib, method):
    """One fixed step on y' = lam y with h|lam| = 1e4 and 1e8: the stability function is
    small and goes to 0 (L-stable); an A-stable, not L-stable method (trapezoidal) keeps
    |R| -> 1."""
    mod = lib.model("lin", 2, [0, 1], [0, 1], 2)
    R = []
    for z in (-1e4, -1e8):
        status, Y, st = mod.run([z, z], 0.0, 1.0, [1.0, 1.0], method=method, rtol=1e9,
                                atol=1e9, h0=1.0, max_step=1.0, t_out=[1.0])
        assert status == 0 and st.naccept == 1
        R.append(abs(Y[0, 0]))
    assert R[0] < 1e-3 and R[1] < 1e-6 and R[1] < R[0]


@pytest.mark.parametrize("method", METHODS)
def test_breakpoint_one_sided_step(lib, method):
    """x' = -a x + u, u steps from 0 to 1 at ts = 0.7 (exactly where(t < ts)): restarting
    at the breakpoint (and never showing the model t = ts before it) gives the closed form to
    1e-10; breakpoints outside the span are ignored."""
    a, ts = 2.0, 0.7
    mod = lib.model("step", 1, [0], [0], 2)
    t = np.linspace(0, 2, 41)
    exact = np.exp(-a * t) + np.where(t > ts, (1 - np.exp(-a * (t - ts))) / a, 0.0)
    status, Y, st = mod.run([a, ts], 0.0, 2.0, [1.0], method=method, rtol=1e-12, atol=1e-14,
                            t_out=t, breaks=[ts, 5.0, -1.0])
    assert status == 0
    assert np.abs(Y[:, 0] - exact).max() < 1e-10


@pytest.mark.parametrize("method", METHODS)
def test_per_state_atol(lib, method):
    """y1' = -y1, y2' = -20 y2: a large atol on y2 alone takes fewer steps, leaves y2 less
    accurate and keeps y1 accurate."""
    mod = lib.model("lin", 2, [0, 1], [0, 1], 2)
    exact = np.exp([-1.0, -20.0])
    runs = [mod.run([-1.0, -20.0], 0.0, 1.0, [1.0, 1.0], method=method, rtol=1e-12, atol=atol,
                    t_out=[1.0]) for atol in ([1e-12, 1e-12], [1e-12, 1e-2])]
    (s1, Y1, st1), (s2, Y2, st2) = runs
    assert s1 == s2 == 0
    assert st2.naccept < st1.naccept
    e1, e2 = np.abs(Y1[0] - exact), np.abs(Y2[0] - exact)
    assert e2[1] > e1[1] and e1.max() < 1e-9 and e2[0] < 1e-9


@pytest.mark.parametrize("method", METHODS)
def test_limits(lib, method):
    """max_steps and max_wall stop the run with their statuses, a message, and NaN rows for
    the output times not reached."""
    m = pend(lib)
    t = np.linspace(0, 1e6, 5)
    status, Y, st = m.run([9.81], 0.0, 1e6, [1.0, 0.0], method=method, rtol=1e-8, t_out=t,
                          max_steps=7)
    assert status == H.BGC["MAX_STEPS"] == st.status and st.nsteps == 7
    assert b"max_steps" in st.message and 0 < st.t_fail < 1e6
    assert np.all(Y[0] == [1.0, 0.0]) and np.all(np.isnan(Y[1:])) and st.n_done == 1
    status, Y, st = m.run([9.81], 0.0, 1e6, [1.0, 0.0], method=method, rtol=1e-8, t_out=t,
                          max_wall=1e-3)
    assert status == H.BGC["WALL"] and b"max_wall" in st.message and st.t_fail < 1e6


@pytest.mark.parametrize("method,where", [("Rodas4", 0), ("Radau5", 0), ("Rodas4", 1)])
def test_nonfinite_detection(lib, method, where):
    """A model whose state-1 rhs (where=0) or Jacobian entry (where=1) is NaN after t = 1
    stops with BGC_ERR_NONFINITE, the right index and a time just after 1: a non-finite
    value at a trial stage rejects the step, so the steps shrink onto t = 1 before the run
    gives up (for the rhs: to within 1e-12; the Jacobian is taken at accepted states only,
    so at the first step start past 1, within max_step = 0.05). (Radau5 keeps its
    Jacobian while Newton converges fast, so on this linear model it never asks for J again:
    only Rodas4, which takes J every step, is checked for where=1.)"""
    mod = lib.model("nan", 2, [0, 1], [0, 1], 2)
    status, Y, st = mod.run([1.0, float(where)], 0.0, 3.0, [1.0, 1.0], method=method,
                            rtol=1e-6, max_step=0.05, t_out=[0.5, 2.0])
    assert status == H.BGC["NONFINITE"] == st.status
    assert st.bad_index == 1 and st.bad_where == where
    assert 1.0 < st.t_fail <= (1.05 + 1e-12 if where else 1.0 + 1e-12)
    assert b"not finite" in st.message
    assert np.allclose(Y[0], np.exp(-0.5), rtol=1e-5) and np.all(np.isnan(Y[1]))


def test_model_failure_and_bad_arguments(lib):
    """A model function returning nonzero stops the run with BGC_ERR_MODEL; bad arguments
    give BGC_ERR_ARGS and a message."""
    for method in METHODS:
        status, Y, st = lib.model("fail", 1, [0], [0], 0).run([0.0], 0.0, 1.0, [1.0],
                                                             method=method, t_out=[1.0])
        assert status == H.BGC["MODEL"] and 0.5 < st.t_fail <= 1.0 and b"failed" in st.message
    status, Y, st = lib.model("step", 1, [0], [0], 2).run([1.0, 0.5], 0.0, 1.0, [1.0],
                                                          rtol=-1.0, t_out=[0.5])
    assert status == H.BGC["ARGS"] and b"rtol" in st.message
    status, Y, st = lib.model("step", 1, [0], [0], 2).run([1.0, 0.5], 0.0, 1.0, [1.0],
                                                          t_out=[0.5, 0.2])
    assert status == H.BGC["ARGS"] and b"increasing" in st.message


# VDPOL of Hairer & Wanner's stiff test set (eps = 1e-6, y(0) = (2, 0)) at t = 2: the
# published reference solution (also in Mazzia & Magherini's Test Set for IVP Solvers);
# scipy's Radau at rtol 1e-11 agrees to 7e-14.
VDPOL_T2 = np.array([1.706167732170483, -0.8928097010248125])


@pytest.mark.parametrize("method,tol,bound", [("Rodas4", 1e-8, 1e-8), ("Radau5", 1e-8, 1e-9),
                                              ("Radau5", 1e-10, 1e-11)])
def test_van_der_pol_stiff(lib, method, tol, bound):
    """Van der Pol with eps = 1e-6 (mu = 1e3) over [0, 2], through a fast transition, against
    the published reference values; a few thousand steps where an explicit method needs
    millions."""
    mod = lib.model("vdp", 2, [0, 1, 1], [1, 0, 1], 1)
    status, Y, st = mod.run([1e-6], 0.0, 2.0, [2.0, 0.0], method=method, rtol=tol, atol=tol,
                            t_out=[2.0])
    assert status == 0
    assert np.abs(Y[0] - VDPOL_T2).max() < bound
    assert st.naccept < 20000


@pytest.mark.parametrize("method", METHODS)
def test_batch_equals_single_runs(lib, method):
    """Each instance of a batch (own parameters, own x0, own step size, over threads) gives
    bit for bit what a single run gives."""
    m = pend(lib)
    rng = np.random.default_rng(3)
    P = rng.uniform(1, 20, (7, 1))
    X0 = np.column_stack([rng.uniform(-2, 2, 7), rng.uniform(-1, 1, 7)])
    t = np.linspace(0, 3, 13)
    status, Y, sts = m.run_batch(P, 0.0, 3.0, X0, nthreads=2, method=method, rtol=1e-7, t_out=t)
    assert status == 0
    for k in range(7):
        s, Yk, st = m.run(P[k], 0.0, 3.0, X0[k], method=method, rtol=1e-7, t_out=t)
        assert s == 0 and np.array_equal(Yk, Y[k])
        assert (st.naccept, st.nfev) == (sts[k].naccept, sts[k].nfev)
    assert len({s.naccept for s in sts}) > 1  # the instances took their own steps


def random_pattern(rng, n, density):
    M = rng.random((n, n)) < density
    np.fill_diagonal(M, False)
    return np.nonzero(M)


@pytest.mark.parametrize("n,density", [(1, 0.0), (5, 0.5), (30, 0.1), (60, 0.03)])
def test_sparse_lu_matches_numpy(lib, n, density):
    """Along a plan from bgc.lower.sparse_lu, c I - J (real and complex c) for random patterns and
    values solves random systems as numpy.linalg.solve does, to 1e-12."""
    rng = np.random.default_rng(n)
    rows, cols = random_pattern(rng, n, density)
    plan = make_plan(n, rows, cols)
    ps = H.plan_struct(plan)
    # the filled pattern covers the matrix and the plan's schedule is complete
    assert plan.nnz_lu >= n + len(rows) and plan.row_ptr[-1] == plan.nnz_lu
    for trial in range(3):
        jv = rng.normal(size=len(rows))
        for c in (1.0 + np.abs(jv).sum(), 3.0 + 2.0j + np.abs(jv).sum()):
            A = np.zeros((n, n), dtype=complex)
            A[rows, cols] -= jv
            A[np.arange(n), np.arange(n)] += c
            b = rng.normal(size=n) + (1j * rng.normal(size=n) if isinstance(c, complex) else 0)
            x = np.linalg.solve(A, b)
            if isinstance(c, complex):
                a = np.zeros(plan.nnz_lu, dtype=complex)
                a[plan.jac_pos] -= jv
                a[plan.diag_pos] += c
                assert lib.lib.bgc_sparse_lu_z(C.byref(ps), a.ctypes.data) == 0
                bb, w = b.astype(complex).copy(), np.zeros(n, dtype=complex)
                lib.lib.bgc_sparse_solve_z(C.byref(ps), a.ctypes.data, bb.ctypes.data,
                                           w.ctypes.data)
            else:
                a = np.zeros(plan.nnz_lu)
                np.subtract.at(a, plan.jac_pos, jv)
                a[plan.diag_pos] += c
                assert lib.lib.bgc_sparse_lu(C.byref(ps), H.ptr(a)) == 0
                bb, w = b.real.copy(), np.zeros(n)
                lib.lib.bgc_sparse_solve(C.byref(ps), H.ptr(a), H.ptr(bb), H.ptr(w))
            assert np.allclose(bb, x, rtol=1e-12, atol=1e-12 * np.abs(x).max())


def test_dense_lu_matches_numpy(lib):
    rng = np.random.default_rng(0)
    n = 12
    A = rng.normal(size=(n, n))
    b = rng.normal(size=n)
    a, piv, bb = A.copy(), np.zeros(n, dtype=np.int32), b.copy()
    assert lib.lib.bgc_dense_lu(n, H.ptr(a), H.ptr(piv, C.c_int)) == 0
    lib.lib.bgc_dense_solve(n, H.ptr(a), H.ptr(piv, C.c_int), H.ptr(bb))
    assert np.allclose(bb, np.linalg.solve(A, b), rtol=1e-12)
    Z = A + 1j * rng.normal(size=(n, n))
    z = Z.copy()
    bz = (b + 1j).astype(complex)
    assert lib.lib.bgc_dense_lu_z(n, z.ctypes.data, H.ptr(piv, C.c_int)) == 0
    lib.lib.bgc_dense_solve_z(n, z.ctypes.data, H.ptr(piv, C.c_int), bz.ctypes.data)
    assert np.allclose(bz, np.linalg.solve(Z, b + 1j), rtol=1e-12)


def test_sparse_tiny_pivot_falls_back_to_dense(lib):
    """c I - J = [[0, 1], [1, 0]] (c = 0) has no usable pivot without pivoting: the sparse LU
    says so, and the integrators' solver then factorises densely with partial pivoting and
    still solves correctly (real and complex); a well-conditioned c uses the plan."""
    plan = make_plan(2, [0, 1], [1, 0])
    ps = H.plan_struct(plan)
    a = np.zeros(plan.nnz_lu)
    a[plan.jac_pos] = -1.0
    assert lib.lib.bgc_sparse_lu(C.byref(ps), H.ptr(a)) != 0
    mod = lib.model("lin", 2, [0, 1], [1, 0], 2, plan=plan)
    jv = np.array([-1.0, -1.0])
    for c, fallbacks in ((0.0, 1), (3.0, 0)):
        A = np.array([[c, 1.0], [1.0, c]])
        b = np.array([1.0, 2.0])
        nfb = C.c_long(-1)
        assert lib.lib.bgc_linsys_solve_once(C.byref(mod.s), c, H.ptr(jv), H.ptr(b),
                                             C.byref(nfb)) == 0
        assert nfb.value == fallbacks and np.allclose(b, np.linalg.solve(A, [1.0, 2.0]))
        bz = np.array([1.0 + 1j, 2.0])
        cz = H.Complex(c, 0.0)
        assert lib.lib.bgc_linsys_solve_once_z(C.byref(mod.s), cz, H.ptr(jv), bz.ctypes.data,
                                               C.byref(nfb)) == 0
        assert nfb.value == fallbacks and np.allclose(bz, np.linalg.solve(A, [1.0 + 1j, 2.0]))


@pytest.mark.parametrize("method", METHODS)
def test_sparse_plan_integration_equals_dense(lib, method):
    """The chain with a sparse LU plan gives the dense-LU run's answer (within
    the tolerance: rounding differences change the step sequence slightly) and expm's."""
    N = 20
    p = [N, 1e5, 10.0, 2.0, 1.0]
    rows, cols = H.chain_pattern(N)
    x0 = np.zeros(2 * N)
    x0[-1] = 1.0
    t = np.linspace(0, 1, 11)
    dense = lib.model("chain", 2 * N, rows, cols, 5)
    sparse = lib.model("chain", 2 * N, rows, cols, 5, plan=make_plan(2 * N, rows, cols))
    s1, Y1, st1 = dense.run(p, 0.0, 1.0, x0, method=method, rtol=1e-8, atol=1e-10, t_out=t)
    s2, Y2, st2 = sparse.run(p, 0.0, 1.0, x0, method=method, rtol=1e-8, atol=1e-10, t_out=t)
    assert s1 == s2 == 0 and st2.nsparse_fallback == 0
    assert np.abs(Y1 - Y2).max() < 1e-8 * np.abs(Y1).max()
    exact = np.array([scipy.linalg.expm(H.chain_matrix(N, *p[1:]) * ti) @ x0 for ti in t])
    assert np.abs(Y2 - exact).max() < 1e-6


def test_plan_c_compiles(tmp_path):
    """The emitted C initialiser compiles warning-free against bgc_runtime.h and describes
    the same plan (read back through a tiny program)."""
    rows, cols = H.chain_pattern(4)
    plan = make_plan(8, rows, cols)
    src = tmp_path / "plan.c"
    src.write_text('#include <stdio.h>\n#include "bgc_runtime.h"\n' + plan_c(plan, "pl") +
                   "int main(void){printf(\"%d %d %d %d\\n\", pl.n, pl.nnz_lu, pl.n_elim,"
                   " pl.elim_tgt[pl.n_elim ? pl.n_elim - 1 : 0]); return 0;}\n")
    import subprocess
    exe = tmp_path / "plan"
    r = subprocess.run(H.compiler().split() + ["-O0", "-std=c99", "-Wall", "-Wextra", "-I",
                                               str(H.RUNTIME), "-o", str(exe), str(src)],
                       capture_output=True, text=True)
    assert r.returncode == 0 and not r.stderr, r.stderr
    out = subprocess.run([str(exe)], capture_output=True, text=True).stdout.split()
    last = plan.elim_tgt[-1] if plan.n_elim else 0
    assert list(map(int, out)) == [8, plan.nnz_lu, plan.n_elim, last]
    with pytest.raises(ValueError):
        plan_c(plan, "bad name")


def test_plan_structure_properties():
    """Minimum degree on a path (tridiagonal pattern, given in scrambled numbering) finds an
    ordering without fill: L+U holds exactly the pattern and the diagonal and each row
    elimination touches one entry; a full pattern gains nothing from the plan, a long chain
    does."""
    from bgc.lower.sparse_lu import prefer_sparse

    n = 40
    rng = np.random.default_rng(1)
    label = rng.permutation(n)
    rows = np.concatenate([label[:-1], label[1:]])
    cols = np.concatenate([label[1:], label[:-1]])
    plan = make_plan(n, rows, cols)
    assert plan.nnz_lu == n + 2 * (n - 1) and plan.n_elim == n - 1
    assert sorted(plan.perm) == list(range(n))
    full = np.nonzero(~np.eye(50, dtype=bool))
    assert not prefer_sparse(make_plan(50, *full))
    assert prefer_sparse(make_plan(2000, *H.chain_pattern(1000)))


@pytest.mark.parametrize("problem", ["pendulum", "forced msd"])
def test_rodas4_is_the_numpy_modules_rodas4(lib, gen, problem):
    """The port against its original: the numpy module's Rodas4 class (from a generated
    module) with the same rhs and Jacobian written in Python takes the same steps (the same
    rhs calls, less the one the C code saves after the last step) and gives the same
    answers to rounding."""
    Rodas4 = gen("pendulum")._rodas_class()
    if problem == "pendulum":
        mod, p, t1, td = pend(lib), [9.81], 10.0, False
        f = lambda t, y: np.array([y[1], -9.81 * np.sin(y[0])])  # noqa: E731
        jac = lambda t, y: np.array([[0, 1.0], [-9.81 * np.cos(y[0]), 0]])  # noqa: E731
    else:
        mod, p, t1, td = lib.model("msd", 2, [0, 1, 1], [1, 0, 1], 5, True), MSD, 5.0, True
        m_, k, c, F, w = MSD
        f = lambda t, y: np.array([y[1], (-k * y[0] - c * y[1] + F * np.cos(w * t)) / m_])  # noqa: E731,E501
        jac = lambda t, y: np.array([[0, 1.0], [-k / m_, -c / m_]])  # noqa: E731
    t = np.linspace(0, t1, 11)
    for tol in (1e-4, 1e-7):
        ref = solve_ivp(f, (0, t1), [1.0, 0.0], method=Rodas4, jac=jac, time_dependent=td,
                        rtol=tol, atol=tol, t_eval=t)
        status, Y, st = mod.run(p, 0.0, t1, [1.0, 0.0], method="Rodas4", rtol=tol, atol=tol,
                                t_out=t)
        assert status == 0 and st.nfev + 1 == ref.nfev
        assert np.abs(Y - ref.y.T).max() < 1e-3 * tol


@pytest.mark.parametrize("method", METHODS)
def test_l_stability_on_stiff_chain(lib, method):
    """The stiff two-mass chain started on its fastest mode (eigenvalue about -2e4): one
    fixed step of h = 0.1 (h |lambda| ~ 2000) leaves almost none of that mode (an A-stable
    method that is not L-stable, like the trapezoidal rule, would keep about all of it with
    its sign flipped)."""
    p = [2, 1e6, 1.0, 1e4, 1.0]
    rows, cols = H.chain_pattern(2)
    mod = lib.model("chain", 4, rows, cols, 5)
    A = H.chain_matrix(2, *p[1:])
    lam, V = np.linalg.eig(A)
    fast = int(np.argmin(lam.real))
    assert lam[fast].real < -1e4 and abs(lam[fast].imag) == 0
    x0 = V[:, fast].real / np.abs(V[:, fast].real).max()
    h = 0.1
    status, Y, st = mod.run(p, 0.0, h, x0, method=method, rtol=1e9, atol=1e9, h0=h,
                            max_step=h, t_out=[h])
    assert status == 0 and st.naccept == 1
    w0 = np.linalg.solve(V, x0)
    w1 = np.linalg.solve(V, Y[0])
    assert abs(w1[fast]) < 1e-2 * abs(w0[fast])
    trapezoid = (1 + h * lam[fast] / 2) / (1 - h * lam[fast] / 2)
    assert abs(trapezoid) > 0.99
