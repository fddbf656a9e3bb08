"""Sparse linear algebra in the numpy runtime's implicit methods (issue 27).

simulate(sparse=True) hands scipy's Radau and BDF a scipy.sparse Jacobian (splu) and makes
Rodas4 factorise with splu; sparse=False keeps dense LAPACK. Both must give the solution the
model has: checked against references written here, outside bgc (the RC ladder's node
equations by hand, solved by scipy's solve_ivp at tight tolerance; the mass-spring-damper's
closed-form step response), and against each other.
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sps
from scipy.integrate import solve_ivp

import bgc

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "bench"))

from bench_scale import ladder_yaml  # noqa: E402

N = 24  # ladder nodes
R, C = 1.0, 0.01  # bench_scale's ladder: R = 1 Ohm, C = 0.01 F, V = sin(2 pi t)
# models/msd.yaml: m x'' + c x' + k x = F0 from rest; states (mass.p, spring.q)
M, K, D, F0 = 2.0, 200.0, 4.0, 10.0


@pytest.fixture(scope="module")
def ladder():
    return bgc.compile(ladder_yaml(N)).module


@pytest.fixture(scope="module")
def msd():
    return bgc.compile(str(ROOT / "models" / "msd.yaml")).module


@pytest.fixture(scope="module")
def ladder_reference():
    """The ladder's node voltages by hand: C dv_i/dt = (v_{i-1} - v_i)/R - (v_i - v_{i+1})/R,
    v_{-1} = sin(2 pi t), no current beyond the last node; solved at rtol 1e-11."""
    def f(t, v):
        left = np.concatenate(([np.sin(2 * np.pi * t)], v[:-1]))
        right = np.concatenate((v[1:], [v[-1]]))
        return ((left - v) - (v - right)) / (R * C)
    t = np.linspace(0.0, 2.0, 201)
    r = solve_ivp(f, (0.0, 2.0), np.zeros(N), method="DOP853", rtol=1e-11, atol=1e-14,
                  t_eval=t)
    assert r.success
    return t, r.y


@pytest.mark.parametrize("method", ["Radau", "BDF", "Rodas4"])
def test_sparse_and_dense_agree_with_the_hand_written_ladder(ladder, ladder_reference, method):
    t, v = ladder_reference
    assert ladder.STATE_NAMES == tuple(f"c{i}.q" for i in range(N))
    kw = dict(t_eval=t, method=method, rtol=1e-8, atol=1e-12)
    dense = ladder.simulate((0.0, 2.0), sparse=False, **kw)
    sparse = ladder.simulate((0.0, 2.0), sparse=True, **kw)
    scale = np.max(np.abs(v))
    for res in (dense, sparse):
        assert np.max(np.abs(res.x / C - v)) <= 1e-5 * scale  # charge q = C v
        assert np.max(np.abs(res.y["v_end"] - v[-1])) <= 1e-5 * scale
    # the same steps, so the same solution up to the linear solves' rounding
    assert np.max(np.abs(sparse.x - dense.x)) <= 1e-9 * np.max(np.abs(dense.x))
    assert sparse.stats["nsteps"] == pytest.approx(dense.stats["nsteps"], rel=0.05)


def test_the_sparse_jacobian_is_a_csc_matrix_with_the_ladders_pattern(ladder):
    """What the solver gets: scipy.sparse with the tridiagonal's entries, equal to the
    hand-written Jacobian d(dq_i/dt)/dq_j (q = C v: the same matrix as for v)."""
    shape = (N,)
    opts = ladder._jacobian_options("Radau", True, lambda t: t, shape, ladder._params(None),
                                    None, {"nfev": 0, "njev": 0, "nlu": 0}, True)
    J = opts["jac"](0.3, np.linspace(0.0, 0.01, N))
    assert sps.issparse(J) and J.format == "csc"
    main = np.full(N, -2.0 / (R * C))
    main[-1] = -1.0 / (R * C)
    expected = (np.diag(main) + np.diag(np.full(N - 1, 1 / (R * C)), 1)
                + np.diag(np.full(N - 1, 1 / (R * C)), -1))
    np.testing.assert_allclose(J.toarray(), expected, rtol=1e-14)
    assert J.nnz == 3 * N - 2
    dense = ladder._jacobian_options("Radau", True, lambda t: t, shape, ladder._params(None),
                                     None, {}, False)["jac"](0.3, np.zeros(N))
    assert isinstance(dense, np.ndarray) and not sps.issparse(dense)


def test_the_size_rule(ladder):
    """By default small systems stay dense; a large batch of them goes sparse (the flat
    Jacobian is block diagonal: few of its entries can be nonzero)."""
    for method in ("Radau", "BDF", "Rodas4"):
        assert not ladder._use_sparse(1, None, method)
        assert ladder._use_sparse(1, True, method) and not ladder._use_sparse(10**4, False, method)
        big = -(-ladder.SPARSE_MIN_BATCH_SIZE[method] // N)  # instances that reach it
        assert ladder._use_sparse(big, None, method)
        assert not ladder._use_sparse(big - 1, None, method)


def _pattern(n, nnz, seed=0):
    """An n x n sparsity pattern of nnz entries: the diagonal, then random off-diagonal ones."""
    rng = np.random.default_rng(seed)
    P = np.eye(n, dtype=bool)
    off = np.flatnonzero(~P)
    P.flat[rng.choice(off, size=nnz - n, replace=False)] = True
    return P


@pytest.mark.parametrize("n, density", [(2, 0.75), (12, 0.76), (24, 0.12), (95, 0.19),
                                        (101, 0.25), (150, 0.02), (150, 0.3), (300, 1.0)])
def test_the_batch_rule_is_monotone_and_never_denser_than_the_flat_rule(ladder, monkeypatch,
                                                                        n, density):
    """Properties of _use_sparse for one instance's pattern of n states and a given density
    (patterns made here): a system under both sizes (SPARSE_MIN_SIZE[method] alone,
    SPARSE_MIN_BATCH_SIZE[method] flat) stays dense; once sparse at nb instances, sparse at
    every larger nb (a block-diagonal batch of a model whose single run is sparse stays
    sparse); sparse wherever the flat matrix's own size and density say so by the
    one-instance rule; a batch of 2 or more over SPARSE_MIN_BATCH_SIZE[method] goes sparse
    whatever its block's density (the dense LU of the block-diagonal matrix does nb**2 times
    the block's work)."""
    P = _pattern(n, max(n, int(round(density * n * n))))
    monkeypatch.setattr(ladder, "N_STATES", n)
    monkeypatch.setattr(ladder, "JAC_SPARSITY", P)
    nnz = int(P.sum())
    single = P.sum() <= ladder.SPARSE_MAX_DENSITY * n * n
    for method in ("Radau", "BDF", "Rodas4"):
        floor = ladder.SPARSE_MIN_SIZE[method]
        seen_sparse = False
        for nb in (1, 2, 3, 4, 5, 8, 16, 64, 1000):
            use = ladder._use_sparse(nb, None, method)
            size = n * nb
            if size < min(floor, ladder.SPARSE_MIN_BATCH_SIZE[method]):
                assert not use, (method, nb)
            if nb == 1:
                assert use == (size >= floor and single), method
            if seen_sparse:
                assert use, (method, nb)  # monotone in nb
            if size >= floor and nnz * nb <= ladder.SPARSE_MAX_DENSITY * size * size:
                assert use, (method, nb)  # the flat density's rule said sparse
            if nb >= 2 and size >= ladder.SPARSE_MIN_BATCH_SIZE[method]:
                assert use, (method, nb)
            seen_sparse = seen_sparse or use
            assert ladder._use_sparse(nb, True, method)
            assert not ladder._use_sparse(nb, False, method)


def test_the_3r2s_block_goes_sparse_from_a_batch_of_two(gen):
    """The 3R2S (about 100 states, a block of about 19 % nonzeros: dense alone) goes sparse
    from 2 instances, where bench/bench_sparse.py measured splu ahead
    (bench/RESULTS_sparse_batch.md); the flat density alone (the block's / 2, over 5 %)
    would keep it dense."""
    mod = gen("mech3r2s")
    n, nnz = mod.N_STATES, int(np.count_nonzero(mod.JAC_SPARSITY))
    assert 0.1 < nnz / n**2 <= 0.2
    assert not mod._use_sparse(1, None, "Radau")
    assert 2 * nnz > mod.SPARSE_MAX_DENSITY * (2 * n) ** 2  # the flat rule: dense
    assert all(mod._use_sparse(2, None, m) for m in ("Radau", "BDF", "Rodas4"))


def test_a_dense_block_batch_on_the_new_sparse_path_equals_its_single_runs(gen):
    """The top (12 states, 76 % of its block nonzero): a batch of 9 has 108 flat states and a
    flat density of 8.5 %, dense by the flat rule, sparse by the batch rule. Each instance
    (its own mass and spin) must equal its own single run (dense, its own steps) to the runs'
    tolerance, and the default must be the sparse path (the same trajectory bit for bit)."""
    mod = gen("top")
    nb = 9
    assert mod._use_sparse(nb, None, "Radau") and not mod._use_sparse(1, None, "Radau")
    scale = np.linspace(0.8, 1.2, nb)
    p = {"m": mod.PARAM_DEFAULTS["m"] * scale, "omega3": mod.PARAM_DEFAULTS["omega3"] * scale}
    kw = dict(method="Radau", rtol=1e-8, atol=1e-10, dt=0.01)
    auto = mod.simulate((0.0, 0.1), p=p, **kw)
    forced = mod.simulate((0.0, 0.1), p=p, sparse=True, **kw)
    assert np.array_equal(auto.x, forced.x)
    for i in range(nb):
        one = mod.simulate((0.0, 0.1), p={k: float(v[i]) for k, v in p.items()}, **kw)
        err = np.max(np.abs(auto.x[:, i] - one.x))
        assert err <= 1e-6 * np.max(np.abs(one.x)), (i, err)
    assert np.ptp(auto.x[:, :, -1], axis=1).max() > 1e-3  # the instances differ


def msd_step(t, k):
    """x(t) of m x'' + c x' + k x = F0 from rest (underdamped for every k used here)."""
    wn = np.sqrt(k / M)
    z = D / (2 * np.sqrt(k * M))
    r = np.sqrt(1 - z * z)
    ex = np.exp(-z * wn * t)
    return F0 / k * (1 - ex * (np.cos(wn * r * t) + z / r * np.sin(wn * r * t)))


@pytest.mark.slow
@pytest.mark.parametrize("method", ["Radau", "BDF", "Rodas4"])
def test_a_batch_sparse_and_dense_agree_with_the_closed_form(msd, method):
    ks = np.linspace(100.0, 2000.0, 110)  # 220 flat states: above the size rule
    t = np.linspace(0.0, 1.0, 51)
    kw = dict(t_eval=t, method=method, rtol=1e-9, atol=1e-12, p={"k": ks})
    dense = msd.simulate((0.0, 1.0), sparse=False, **kw)
    sparse = msd.simulate((0.0, 1.0), sparse=True, **kw)
    auto = msd.simulate((0.0, 1.0), **kw)
    exact = msd_step(t[None, :], ks[:, None])
    scale = float(np.max(np.abs(exact)))
    for res in (dense, sparse, auto):
        assert res.x.shape == (2, ks.size, t.size)
        assert np.max(np.abs(res.y["position"] - exact)) <= 2e-6 * scale
    assert np.max(np.abs(sparse.x - dense.x)) <= 1e-8 * np.max(np.abs(dense.x))
    np.testing.assert_array_equal(auto.x, sparse.x)  # 220 states: the sparse path


def test_a_non_finite_sparse_jacobian_is_located(ladder):
    """The sparse path keeps the check before every solve: with C = 0 the Jacobian's first
    entry, -2/(R C), is -inf, and the run stops there naming it, as the dense path does."""
    stats = {"nfev": 0, "njev": 0, "nlu": 0}
    for sparse in (True, False):
        with np.errstate(all="ignore"):
            p = ladder._params({"C": 0.0})
        jac = ladder._flat_jacobian(lambda t: t, (N,), p, None, sparse, "Radau", stats)
        with pytest.raises(ladder.NonFiniteError) as e, np.errstate(all="ignore"):
            jac(0.0, np.zeros(N))
        assert e.value.where == "jacobian" and e.value.index == (0, 0)
        assert "c0.q" in str(e.value) and "-inf" in str(e.value)
