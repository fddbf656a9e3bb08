"""bgc's numpy runtime: the step loop, bgc's Rodas4 and the stiffness watch of every
generated numpy module.

Everything below the marker line is copied verbatim to the end of each generated module (the
template ``module.py.j2`` includes it), so this file is read by linters, coverage and tests as
ordinary code. The names the model's part of the module defines (``rhs``, ``jacobian``,
``initial_state``, ``N_STATES``, ...) are declared here for readers and linters only; the
declarations above the marker are not copied.
"""
# flake8: noqa: F821
from __future__ import annotations

import numpy as np

N_STATES: int
STATE_NAMES: tuple
STATE_OWNERS: tuple
INPUT_NAMES: tuple
RHS_USES_T: bool
_PARAM_NDIM: dict
JAC_SPARSITY: np.ndarray
INPUT_NAMES: tuple
INPUT_LABELS: tuple
OUTPUT_LABELS: tuple
TABLE_BREAKPOINTS: dict
TABLE_MAX_STEP: dict
_TABLES: tuple
rhs = jacobian = outputs = initial_state = _params = None  # the model's, in a generated module
input_jacobian = output_jacobian = None
xp = np  # the model part's array namespace

# ==== bgc numpy runtime: copied below this line ====
class SimulationError(RuntimeError):
    """The integrator failed or was stopped (the message says why): .t where, .stats the counts."""

    t = None
    stats = None


class NonFiniteError(SimulationError):
    """rhs or jacobian gave a value that is not finite (nan or inf): .where is "rhs",
    "jacobian" or "initial state", .index the state (rhs) or (row, column) entry (jacobian),
    .x the state of the instance concerned, .instance its index in the batch (flat)."""

    where = index = x = instance = None


class StiffnessError(SimulationError):
    """An explicit method met a stiff model (the message says where, why, and what to use)."""


class SimResult(tuple):
    """(t, x, y) with x of shape (n, *batch, len(t)) and y the outputs; .stats the solver's counts."""

    def __new__(cls, t, x, y, stats):
        self = super().__new__(cls, (t, x, y))
        self.stats = stats
        return self

    t = property(lambda self: self[0])
    x = property(lambda self: self[1])
    y = property(lambda self: self[2])


# --------------------------------------------------------------------------------------------
# The runtime: simulate() steps one of scipy's OdeSolver classes (or Rodas4, below) through
# each segment between breakpoints and reads the output times off each step's dense output.

METHODS = ("RK23", "RK45", "DOP853", "Radau", "BDF", "LSODA", "Rodas4")  # Rodas4: bgc's own
# Explicit methods are stable on y' = lam*y while h*|lam| stays within these limits on the
# negative real axis and on the imaginary axis (the stability polynomials of scipy's tableaus).
_STABILITY = {"RK23": (2.51, 1.73), "RK45": (3.31, 0.99), "DOP853": (6.39, 5.96)}
# Stiffness test of the explicit methods, after Hairer's DOPRI5: one check (a Jacobian and its
# eigenvalues) every _STIFF_EVERY accepted steps, then at every step while checks are positive;
# _STIFF_HITS positive checks in a row make the model stiff, _STIFF_MISSES negative ones reset.
_STIFF_EVERY, _STIFF_HITS, _STIFF_MISSES = 50, 15, 6
_STIFF_SAMPLE = 8  # batch instances whose eigenvalues a check computes (bounded cost)
_AT_LIMIT = 0.7  # a step "at the stability limit": at least this fraction of the stable step
_DECAYED = 10.0  # a stiff mode decays by at least e^-10 over the rest of the span
_NEAR_AXIS = 0.087  # sin(5 degrees)


# --------------------------------------------------------------------------------------------
# Array namespaces: rhs, jacobian and outputs run on the arrays of any library that follows
# the array API standard that allow item assignment (CuPy, torch, array-api-strict), taking
# the namespace from x through array-api-compat; numpy arrays (and Python numbers) take numpy
# itself, so the numpy path needs neither array-api-compat nor any wrapper.

def _namespace(x):
    """The array namespace of x: numpy for numpy arrays and numbers, else the standard's."""
    if isinstance(x, (np.ndarray, np.generic, float, int, list, tuple)):
        return np
    try:
        import array_api_compat
    except ImportError:  # without array-api-compat, everything is numpy
        return np
    return array_api_compat.array_namespace(x)


def _device(x):
    """Where new arrays go: None (numpy's default) for numpy, else x's device."""
    if isinstance(x, np.ndarray):
        return None
    import array_api_compat

    return array_api_compat.device(x)


def _in_namespace(unpacked, xp):
    """Unpacked parameters as xp's arrays (numpy scalars as Python floats, which mix with any
    library's arrays; numpy's own scalars would turn the results back into numpy arrays)."""
    vals, bshape = unpacked
    return tuple(xp.asarray(v) if isinstance(v, np.ndarray) and v.ndim else
                 float(v) if isinstance(v, (np.ndarray, np.generic)) else v
                 for v in vals), bshape


def _error(cls, message, t, stats):
    """A SimulationError (or subclass) that carries where it happened and the counts so far."""
    err = cls(message)
    err.t, err.stats = t, dict(stats)
    return err


def _all_finite(a):
    """Every entry of a finite? Cheaply: the sum of squares (one BLAS dot) is finite when all
    entries are (nan and inf propagate through it; s - s is 0 only for a finite s); if it
    overflowed from large finite entries, the entries are looked at one by one."""
    v = a.ravel()
    s = v.dot(v)
    return (s - s) == 0.0 or bool(np.isfinite(v).all())


def _nonfinite(method, what, t, y, values, shape, stats):
    """The NonFiniteError for rhs values (flat, n * batch) or Jacobian values (n, n, batch)
    that are not all finite: the first state (or entry, row-major) that is not, its name and
    the element that owns it (STATE_NAMES, STATE_OWNERS). Only called on failure."""
    nb = int(np.prod(shape[1:]))
    values = np.asarray(values)
    if what == "jacobian":
        bad = ~np.isfinite(values.reshape(N_STATES, N_STATES, nb))
        i, j = (int(k) for k in np.argwhere(bad.any(axis=2))[0])
        b = int(np.flatnonzero(bad[i, j])[0])
        v = values.reshape(N_STATES, N_STATES, nb)[i, j, b]
        index = (i, j)
        part = (f"the Jacobian entry ({i}, {j}), d(d{STATE_NAMES[i]}/dt)/d({STATE_NAMES[j]}), "
                f"is {v:g} (the equation of state {STATE_NAMES[i]!r}, element "
                f"{STATE_OWNERS[i]!r})")
    else:
        bad = ~np.isfinite(values.reshape(N_STATES, nb))
        i = int(np.flatnonzero(bad.any(axis=1))[0])
        b = int(np.flatnonzero(bad[i])[0])
        v = values.reshape(N_STATES, nb)[i, b]
        index = i
        if what == "rhs":
            part = (f"the right-hand side is not finite: d{STATE_NAMES[i]}/dt is {v:g} (state "
                    f"{i} {STATE_NAMES[i]!r}, element {STATE_OWNERS[i]!r})")
        else:
            part = (f"the {what} is not finite: state {i} {STATE_NAMES[i]!r} (element "
                    f"{STATE_OWNERS[i]!r}) is {v:g}")
    x = np.asarray(y, dtype=float).reshape(N_STATES, nb)[:, b]
    if what != "initial state" and not np.all(np.isfinite(x)):
        k = int(np.flatnonzero(~np.isfinite(x))[0])
        part += f"; the state itself is not finite ({STATE_NAMES[k]!r} = {x[k]:g})"
    where = f" in batch instance {b}" if nb > 1 else ""
    err = _error(NonFiniteError, f"{method} failed at t = {t:.6g}{where}: {part}", t, stats)
    err.where, err.index, err.x, err.instance = what, index, x, b
    return err


#: Bounds on a run's arguments (as bgc's own limits bound a scene's): output samples (dt,
#: t_eval), instances in a batch, and values in the state trajectory (states x instances x
#: samples, 8 bytes each).
MAX_OUTPUT_SAMPLES = 1_000_000
MAX_BATCH = 1_000_000
MAX_RESULT_VALUES = 500_000_000


def _guard_solves(solver, method, stats, shape):
    """Radau and BDF solve linear systems in their Newton iterations from values the rhs
    checks never see (the iterates' combinations): a system that is not finite (a state grown
    past the double range) stops the run with a NonFiniteError naming the state's equation,
    as Rodas4 and the C backend do, where scipy's LU would raise ValueError.

    Radau's matrices c I - J (c = mu/h) are built only when they are factorised: a step held at
    max_step whose controller asked for a longer one makes scipy drop its LUs and build and
    factorise the same two matrices again (every step, in a scene whose inputs bound the
    step); the last LU of each kind is kept with its (c, J) and given back for the same pair."""
    factor, solve = getattr(solver, "lu", None), getattr(solver, "solve_lu", None)
    if factor is None or solve is None:
        return
    last = {}  # real or complex -> (c, J, LU): the last factorisation of each kind

    def checked_factor(A):
        import scipy.sparse as sps

        pending = None
        if isinstance(A, _Shifted):
            old = last.get(isinstance(A.c, complex))
            if old is not None and old[0] == A.c and old[1] is A.J:
                return old[2]
            pending, A = A, A.c * A.eye - A.J
        diag = A.diagonal() if sps.issparse(A) else np.diag(A)
        if not _all_finite(A.data if sps.issparse(A) else A):
            raise _newton_nonfinite(method, solver, diag, shape, _counts(stats, solver))
        lu = factor(A)
        if pending is not None:
            last[isinstance(pending.c, complex)] = (pending.c, pending.J, lu)
        return lu

    def checked_solve(LU, b):
        if not _all_finite(b):
            raise _newton_nonfinite(method, solver, b, shape, _counts(stats, solver))
        return solve(LU, b)

    solver.lu, solver.solve_lu = checked_factor, checked_solve
    if method == "Radau" and getattr(solver, "I", None) is not None:
        solver.I = _Identity(solver.I)


class _Identity:
    """Stands for Radau's identity I: ``c * I - J`` gives a _Shifted (built when factorised)."""

    def __init__(self, eye):
        self.eye = eye

    def __rmul__(self, c):
        return _Scaled(c, self.eye)


class _Scaled:
    def __init__(self, c, eye):
        self.c, self.eye = c, eye

    def __sub__(self, J):
        return _Shifted(self.c, J, self.eye)


class _Shifted:
    """c I - J, not yet built."""

    def __init__(self, c, J, eye):
        self.c, self.J, self.eye = c, J, eye


def _newton_nonfinite(method, solver, values, shape, stats):
    """The NonFiniteError for a linear system of the Newton iteration that is not finite."""
    nb = int(np.prod(shape[1:]))
    bad = np.flatnonzero(~np.isfinite(np.asarray(values).ravel()))
    k = int(bad[0]) if bad.size else 0
    i, b = divmod(k % (N_STATES * nb), nb)
    x = np.asarray(solver.y, dtype=float).reshape(N_STATES, nb)[:, b]
    big = int(np.argmax(np.where(np.isfinite(x), np.abs(x), np.inf)))
    where = f" in batch instance {b}" if nb > 1 else ""
    part = (f"the Newton iteration is not finite in the equation of state {i} "
            f"{STATE_NAMES[i]!r} (element {STATE_OWNERS[i]!r}): the state grows without bound "
            f"({STATE_NAMES[big]!r} = {x[big]:g})")
    err = _error(NonFiniteError, f"{method} failed at t = {solver.t:.6g}{where}: {part}",
                 solver.t, stats)
    err.where, err.index, err.x, err.instance = "rhs", i, x, b
    return err


def _batched(x0, p):
    """The initial state broadcast to (n, *batch): batch is what x0 and the parameters span."""
    x0 = initial_state(p) if x0 is None else np.asarray(x0, dtype=float)
    batch = np.broadcast_shapes(x0.shape[1:], _params(p)[1])
    if int(np.prod(batch, dtype=float)) > MAX_BATCH:
        raise ValueError(f"a batch of {int(np.prod(batch, dtype=float))} instances (shape "
                         f"{batch}) is more than the limit of {MAX_BATCH}")
    x0 = x0.reshape((N_STATES,) + (1,) * (len(batch) + 1 - x0.ndim) + x0.shape[1:])
    return np.broadcast_to(x0, (N_STATES,) + batch), batch


def _flat_atol(atol, batch):
    """atol as the solver wants it: a scalar, or one value per state flattened like the state."""
    atol = np.asarray(atol, dtype=float)
    if atol.ndim == 0:
        return float(atol)
    if atol.shape[0] != N_STATES:
        raise ValueError(f"atol: give a scalar or one value per state ({N_STATES})")
    atol = atol.reshape((N_STATES,) + (1,) * (len(batch) + 1 - atol.ndim) + atol.shape[1:])
    return np.broadcast_to(atol, (N_STATES,) + batch).ravel()


def _output_times(t0, t1, t_eval, dt):
    """The output times inside the span in the direction of integration; None: every step."""
    if not (np.isfinite(t0) and np.isfinite(t1)):
        raise ValueError(f"t_span ({t0:g}, {t1:g}) is not finite")
    if t_eval is None and dt is not None:
        dt = float(dt)
        if not (dt > 0 and np.isfinite(dt)):
            raise ValueError(f"dt must be a positive, finite step in seconds, not {dt!r}")
        if not abs(t1 - t0) / dt <= MAX_OUTPUT_SAMPLES:
            raise ValueError(f"dt = {dt:g} s over {abs(t1 - t0):g} s asks for "
                             f"{abs(t1 - t0) / dt:.3g} output samples, more than the limit of "
                             f"{MAX_OUTPUT_SAMPLES}")
        t_eval = np.linspace(t0, t1, int(round(abs(t1 - t0) / dt)) + 1)
    if t_eval is None:
        return None
    size = t_eval.size if hasattr(t_eval, "size") else len(t_eval) if hasattr(
        t_eval, "__len__") else 1
    if size > MAX_OUTPUT_SAMPLES + 1:  # (the samples of a dt and the span's start)
        raise ValueError(f"t_eval has {size} times, more than the limit of "
                         f"{MAX_OUTPUT_SAMPLES + 1}")
    # sorted, duplicates dropped (np.unique would import numpy.ma: 20 ms of a warm run)
    t = np.sort(np.asarray(t_eval, dtype=float).ravel())
    t = t[np.concatenate(([True], t[1:] != t[:-1]))] if t.size else t
    t = t[(t >= min(t0, t1)) & (t <= max(t0, t1))]
    return t if t1 >= t0 else t[::-1]


def _segments(t0, t1, breakpoints):
    """The pieces (a, c) of the span between the breakpoints inside it, in integration order."""
    inner = sorted({float(b) for b in breakpoints if min(t0, t1) < float(b) < max(t0, t1)},
                   reverse=t1 < t0)
    cuts = [t0] + inner + [t1]
    return [(a, c) for a, c in zip(cuts[:-1], cuts[1:]) if a != c]


def _one_sided(a, c):
    """t -> t held in [a, nextafter(c, a)]: inside the segment (a, c) an input that jumps at c
    (where(t < c, ...)) keeps its left value, even in a stage the solver evaluates at c."""
    lo, hi = sorted((a, float(np.nextafter(c, a))))
    return lambda t: min(max(t, lo), hi)


# --------------------------------------------------------------------------------------------
# Small batches: numpy's cost per operation on an array of 2-16 entries is several times its
# cost on one number (a 0-d value: numpy's scalar arithmetic), and a batch's rhs and Jacobian
# are thousands of such operations. Below a measured size the solver-facing wrappers evaluate
# the batch instance by instance through the single-instance path (x of shape (n,), the
# parameters split per instance once per run) and stack the results: per instance the same
# arithmetic, so the same values (bench/bench_small_batch.py, bench/RESULTS_small_batch.md).
#
#: The loop's limits (`python bench/bench_small_batch.py --span 0.1 --budget 0.3`,
#: bench/RESULTS_small_batch.md; measured on msd, rlc, pendulum, quarter_car, dc_motor, the
#: rigid double pendulum, the top, the rigid four-bar and the 3R2S). A batch of nb instances
#: is looped where 2 <= nb < SMALL_BATCH[name][k], k by the function's size: its count of local
#: names (its efforts, flows, temporaries and parameters: a count of its operations fixed when
#: the module is generated), k = 0 from SMALL_BATCH_MIN_LOCALS names, 1 from
#: SMALL_BATCH_LARGE_LOCALS. Why: one instance costs a fixed overhead plus its operations on
#: numbers; the vectorised call costs about the same overhead plus the same operations on
#: arrays, several times dearer each and nearly flat in nb up to 16 or more. The loop pays
#: while nb is below the ratio of the two, which grows with the function's size: a small
#: function (msd's, the quarter car's: under 35 names) is overhead and never pays; the top's
#: and the double pendulum's (57-363 names) pay up to 4 instances for the rhs and 6 for the
#: Jacobian (its dense n x n result is more operations per call); the 3R2S's (523 and 3920)
#: up to 7 and 9. A function that solves linear systems (derivative causality: _bgc_linsolve,
#: whose cost per call barely grows with nb) pays for 2 instances only (SMALL_BATCH_SOLVES).
#: Each limit is within 20 % of the faster path at every measured size and model.
SMALL_BATCH = {"rhs": (5, 8), "jacobian": (7, 10)}
SMALL_BATCH_MIN_LOCALS, SMALL_BATCH_LARGE_LOCALS = 50, 400
SMALL_BATCH_SOLVES = 3
# the model part's own functions (a C wrapper defines its rhs after this runtime: None here),
# and whether the model part evaluates one instance exactly as an instance of a batch: a
# nonlinear loop's Newton starts warm from the last call's solution (an instance would start
# from the one before it) and a rolled module keeps one parameter array per batch
_OWN = {"rhs": globals().get("rhs"), "jacobian": globals().get("jacobian")}
_LOOPABLE = globals().get("_NEWTON_WARM") is None and globals().get("_PARAM_ARRAY") is None


def _loop_limit(name):
    """The batch size from which rhs or jacobian (name) is vectorised: SMALL_BATCH's by the
    function's size, SMALL_BATCH_SOLVES at most for one that solves linear systems, 0 (never
    looped) for a small one, in a module that is not loopable, or for a function that is not
    the model part's own."""
    fn = _OWN[name]
    if not _LOOPABLE or fn is None or globals().get(name) is not fn:
        return 0
    code = fn.__code__
    if code.co_nlocals < SMALL_BATCH_MIN_LOCALS:
        return 0
    limit = SMALL_BATCH[name][int(code.co_nlocals >= SMALL_BATCH_LARGE_LOCALS)]
    if "_bgc_linsolve" in code.co_names:
        return min(limit, SMALL_BATCH_SOLVES)
    return limit


def _looped(name, nb):
    """Does the solver-facing wrapper of rhs or jacobian (name) loop over the nb instances of
    a batch (_loop_limit)?"""
    return 2 <= nb < _loop_limit(name)


def _split_params(p, batch):
    """The unpacked parameters p (from _params) as one unpacked tuple per instance of the
    batch (flat order), each of scalars; made once per p and batch (simulate unpacks its
    parameters once, so once per run) and kept on p itself (a run's own object: no state
    shared between threads that run at once)."""
    memo = getattr(p, "__dict__", None)
    split = None if memo is None else memo.get(("_split", batch))
    if split is not None:
        return split
    vals, bshape = p
    nb = int(np.prod(batch, dtype=int))
    if not bshape:
        split = [p] * nb
    else:
        cols = [np.broadcast_to(v, batch).reshape(nb) if np.ndim(v) else None for v in vals]
        split = [type(p)((tuple(v if c is None else c[i] for v, c in zip(vals, cols)), ()))
                 for i in range(nb)]
    if memo is not None:
        memo[("_split", batch)] = split
    return split


_INPUT_SIZES = {}  # input -> its number of components, found on first use


def _input_sizes():
    """Each input's number of components (INPUT_LABELS: a vector input's are name[k])."""
    if not _INPUT_SIZES:
        _INPUT_SIZES.update({name: sum(1 for lbl in INPUT_LABELS
                                       if lbl == name or lbl.startswith(name + "["))
                             for name in INPUT_NAMES})
    return _INPUT_SIZES


def _split_inputs(t, u, batch, nb):
    """The input overrides u at time t as one dict per instance (nb of the batch) of constant
    signals: each override called once; a scalar input's value that spans the batch is split
    per instance, other values are every instance's. Without overrides, None for each."""
    if u is None:
        return [None] * nb
    sizes = _input_sizes()
    same, each = {}, {}
    for name, f in u.items():
        if name not in sizes:
            continue  # not an input: the model part never reads it
        v = np.asarray(f(t), dtype=float)
        if sizes[name] == 1 and v.size > 1:
            each[name] = np.broadcast_to(v, batch).reshape(nb)
        elif sizes[name] == 1:
            same[name] = lambda _t, v=v.reshape(()): v
        else:
            same[name] = lambda _t, v=v: v
    return [{**same, **{name: (lambda _t, v=v[i]: v) for name, v in each.items()}}
            for i in range(nb)]


def _each(name, t, y, shape, p, u):
    """rhs (dx/dt, (n, nb)) or jacobian ((n, n, nb)) of the batch in y (flat, n * nb),
    instance by instance through the single-instance path."""
    n = shape[0]
    Y = y.reshape(n, -1)
    nb = Y.shape[1]
    ps, us = _split_params(p, shape[1:]), _split_inputs(t, u, shape[1:], nb)
    fn = rhs if name == "rhs" else jacobian
    out = np.empty((n, nb) if name == "rhs" else (n, n, nb))
    for i in range(nb):
        out[..., i] = fn(t, Y[:, i], ps[i], us[i])
    return out


def _flat_rhs(at, shape, p, u, stats, method):
    """rhs on the solver's flat state (n * batch,), at the one-sided time at(t); counts calls.
    A value that is not finite stops the run (NonFiniteError): one check per call. A small
    batch is evaluated instance by instance (_looped)."""
    looped = _looped("rhs", int(np.prod(shape[1:], dtype=int)))

    def fun(t, y):
        stats["nfev"] += 1
        if looped and y.ndim == 1:
            dy = _each("rhs", at(t), y, shape, p, u).reshape(y.shape)
        else:
            dy = rhs(at(t), y.reshape(shape + y.shape[1:]), p, u).reshape(y.shape)
        if not _all_finite(dy):
            raise _nonfinite(method, "rhs", at(t), y, dy, shape, stats)
        return dy
    return fun


def _batch_jacobian(t, y, shape, p, u):
    """The analytic Jacobian of the batch in y (flat): (n, n, nb), a small batch instance by
    instance (_looped)."""
    if _looped("jacobian", y.size // N_STATES if N_STATES else 0):
        return _each("jacobian", t, y, shape, p, u)
    return jacobian(t, y.reshape(shape), p, u).reshape(N_STATES, N_STATES, -1)


_PATTERN = []  # JAC_SPARSITY's (rows, columns), found once (a scan of n * n entries)


def _pattern():
    """The rows and columns of JAC_SPARSITY's entries, in row-major order."""
    if not _PATTERN:
        _PATTERN.append(np.nonzero(JAC_SPARSITY))
    return _PATTERN[0]


def _block_pattern(nb):
    """Rows and columns of the flat Jacobian's nonzeros: one JAC_SPARSITY block per instance."""
    rows, cols = _pattern()
    b = np.arange(nb)
    return (rows[:, None] * nb + b).ravel(), (cols[:, None] * nb + b).ravel()


#: Where sparse linear algebra pays (bench/bench_sparse.py). One instance: an implicit method
#: factorises a sparse Jacobian (scipy's splu) when it has at least SPARSE_MIN_SIZE[method]
#: states and at most SPARSE_MAX_DENSITY of its entries can be nonzero (JAC_SPARSITY); below, a
#: dense LU (LAPACK) is as fast or faster; Rodas4 factorises at every step, where splu's fixed
#: cost weighs more: its size is higher (single runs of RC ladders, bench/RESULTS_sparse.md).
#: A batch (nb >= 2): its flat Jacobian is block diagonal, so the dense LU costs ~ (n nb)**3
#: while splu's stays ~ nb x one block's, at most a few dense LUs of the block (splu on a full
#: block is a few times LAPACK's): from 2 instances the dense LU does nb**2 = 4 times the
#: block's work per instance and loses to splu whatever the block's density, once the flat
#: size (SPARSE_MIN_BATCH_SIZE[method]; Rodas4's higher, as alone) pays for splu's fixed
#: cost; under a multithreaded BLAS a dense LU of 100-400 unknowns is slower still. Measured
#: end to end on the 3R2S circle, RC ladders of 30 / 100 / 300, the rigid double pendulum and
#: the top at batches 1-64, Radau and Rodas4 (BDF follows Radau, unmeasured for batches), the
#: picked path within 15 % of the faster for every batch measured on an idle machine:
#: `python bench/bench_sparse.py --cases all --methods Radau,Rodas4 --rounds 2`
#: (bench/RESULTS_sparse_batch.md).
SPARSE_MIN_SIZE = {"Radau": 100, "BDF": 100, "Rodas4": 200}
SPARSE_MAX_DENSITY = 0.05
SPARSE_MIN_BATCH_SIZE = {"Radau": 50, "BDF": 50, "Rodas4": 150}


def _use_sparse(nb, sparse=None, method="Radau"):
    """Does an implicit method get a sparse Jacobian? sparse=True/False forces the choice;
    None decides: one instance by its size and density (SPARSE_MIN_SIZE[method],
    SPARSE_MAX_DENSITY), a batch of nb >= 2 by the flat size
    (SPARSE_MIN_BATCH_SIZE[method])."""
    if sparse is not None:
        return bool(sparse)
    size = N_STATES * nb
    if nb > 1:
        return size >= SPARSE_MIN_BATCH_SIZE.get(method, 50)
    nnz = int(np.count_nonzero(JAC_SPARSITY))
    return size >= SPARSE_MIN_SIZE.get(method, 100) and nnz <= SPARSE_MAX_DENSITY * size * size


def _csc_plan(nb):
    """The flat Jacobian's compressed-column structure, built once: (rows, cols of the
    pattern in JAC_SPARSITY, the order that sorts the gathered values by column, indices,
    indptr); a call only gathers its values and puts them in that order."""
    rows, cols = _pattern()
    R, C = _block_pattern(nb)
    order = np.lexsort((R, C))
    size = N_STATES * nb
    indptr = np.zeros(size + 1, dtype=np.int32)
    np.cumsum(np.bincount(C, minlength=size), out=indptr[1:])
    return rows, cols, order, R[order].astype(np.int32), indptr


def _flat_jacobian(at, shape, p, u, sparse, method, stats):
    """The analytic Jacobian on the flat state: block diagonal over a batch, a
    scipy.sparse.csc_matrix when ``sparse`` (its pattern JAC_SPARSITY's), else a dense array.
    An entry that is not finite stops the run (NonFiniteError): one check per call (on the
    pattern's entries only when sparse: the others are zero by construction)."""
    import scipy.sparse as sps

    nb = int(np.prod(shape[1:]))
    size = N_STATES * nb
    rows, cols, order, indices, indptr = _csc_plan(nb)
    # a vectorised module's Jacobian values at the pattern's entries, without the dense matrix
    values = globals().get("_jacobian_values") if sparse else None

    def jac(t, y):
        if values is not None:
            vals = np.asarray(values(at(t), y.reshape(shape), p, u)).reshape(-1, nb)
            vals = np.broadcast_to(vals, (len(rows), nb)).ravel()
            if not _all_finite(vals):
                raise _nonfinite(method, "jacobian", at(t), y, jacobian(
                    at(t), y.reshape(shape), p, u).reshape(N_STATES, N_STATES, nb), shape, stats)
            return sps.csc_matrix((vals[order], indices, indptr), shape=(size, size))
        J = _batch_jacobian(at(t), y, shape, p, u)
        if not sparse:
            if not _all_finite(J):
                raise _nonfinite(method, "jacobian", at(t), y, J, shape, stats)
            if nb == 1:
                return J[:, :, 0]
            M = np.zeros((size, size))
            M[indices, np.repeat(np.arange(size), np.diff(indptr))] = J[rows, cols].ravel()[order]
            return M
        vals = J[rows, cols].ravel()
        if not _all_finite(vals):
            raise _nonfinite(method, "jacobian", at(t), y, J, shape, stats)
        return sps.csc_matrix((vals[order], indices, indptr), shape=(size, size))
    return jac


def _jacobian_options(method, jac, at, shape, p, u, stats, sparse=None):
    """The solver's Jacobian: analytic (jac=True), else finite differences over JAC_SPARSITY;
    sparse or dense by _use_sparse (LSODA's always dense: it takes no sparse matrix)."""
    import scipy.sparse as sps

    nb = int(np.prod(shape[1:]))
    if method in _STABILITY:
        return {}  # explicit: no Jacobian
    use = method != "LSODA" and _use_sparse(nb, sparse, method)
    if method == "Rodas4":
        if not jac:
            raise ValueError("Rodas4 needs the analytic Jacobian (jac=True): a Rosenbrock "
                             "method's order rests on the exact Jacobian")
        return {"jac": _flat_jacobian(at, shape, p, u, use, method, stats),
                "time_dependent": bool(INPUT_NAMES) or RHS_USES_T}
    if jac:
        return {"jac": _flat_jacobian(at, shape, p, u, use, method, stats)}
    if method == "LSODA":
        return {}  # LSODA differences densely (it takes no sparsity pattern)
    # finite differences over the pattern (grouped columns: few rhs calls), at any size
    if nb == 1:
        return {"jac_sparsity": JAC_SPARSITY}
    R, C = _block_pattern(nb)
    return {"jac_sparsity": sps.csc_matrix((np.ones(len(R)), (R, C)),
                                           shape=(N_STATES * nb,) * 2)}


def _eigenvalues(t, y, shape, p, u, method, stats):
    """Eigenvalues of the analytic Jacobian at (t, y), over up to _STIFF_SAMPLE batch instances
    (a Jacobian that is not finite stops the run, as in the implicit methods)."""
    J = np.asarray(_batch_jacobian(t, y, shape, p, u))
    if not _all_finite(J):
        raise _nonfinite(method, "jacobian", t, y, J, shape, stats)
    pick = np.unique(np.linspace(0, J.shape[2] - 1, _STIFF_SAMPLE).round().astype(int))
    J = np.moveaxis(J[:, :, pick], 2, 0)
    return np.linalg.eigvals(J).ravel() if np.all(np.isfinite(J)) else np.zeros(0)


def _stiffness(method, t, t_end, lam):
    """(largest stable step, steps the rest of the span needs at it, explanation) for an explicit
    method, from the Jacobian's eigenvalues lam. Only modes that die out within the rest of the
    span count: an undamped oscillation limits the step through accuracy anyway."""
    rest = abs(t_end - t)
    lam = lam[-lam.real * rest > _DECAYED]
    if not lam.size:
        return np.inf, 0.0, ""
    real, imag = _STABILITY[method]
    # the real-axis limit holds to within ~5 degrees of the imaginary axis, then falls to the
    # imaginary-axis one (interpolated: within a third of the exact boundary)
    limit = imag + (real - imag) * np.minimum(1.0, -lam.real / np.abs(lam) / _NEAR_AXIS)
    k = int(np.argmin(limit / np.abs(lam)))
    h_max = limit[k] / abs(lam[k])
    why = (f"the analytic Jacobian's largest |eigenvalue| is {np.max(np.abs(lam)):.4g} 1/s, and "
           f"{method} is stable only for h*|lambda| <= {real:g} on the negative real axis "
           f"({imag:g} on the imaginary axis), which allows steps of at most {h_max:.3g} s "
           f"(binding: the eigenvalue {lam[k]:.4g}); the remaining {rest:.4g} s need about "
           f"{rest / h_max:.3g} steps")
    return h_max, rest / h_max, why


def _stiff_message(method, t, why, h=None):
    held = "" if h is None else f"its steps are held at the stability limit (h = {h:.3g} s); "
    return (f"the model is stiff for {method} at t = {t:.6g}: {held}{why}. Use method=\"Radau\" "
            "or method=\"Rodas4\" (L-stable) or method=\"BDF\" (they use the analytic "
            "Jacobian), or stiff_check=False.")


class _StiffnessWatch:
    """Is an explicit method's step held at its stability limit, check after check?"""

    def __init__(self, method, t_end, max_steps):
        self.method, self.t_end, self.max_steps = method, t_end, max_steps
        self.wait, self.hits, self.misses = _STIFF_EVERY, 0, 0

    def due(self):
        """Called after each accepted step: is a check due now?"""
        self.wait -= 1
        return self.hits > 0 or self.wait <= 0

    def check(self, t, h, lam):
        """Record one check at step size h; returns StiffnessError's message once stiff."""
        self.wait = _STIFF_EVERY
        h_max, steps, why = _stiffness(self.method, t, self.t_end, lam)
        if h >= _AT_LIMIT * h_max and steps > self.max_steps:
            self.hits, self.misses = self.hits + 1, 0
        elif self.hits:
            self.misses += 1
            if self.misses >= _STIFF_MISSES:
                self.hits = self.misses = 0
        return _stiff_message(self.method, t, why, h) if self.hits >= _STIFF_HITS else ""


class _Trajectory:
    """The solution at the output times, read off each step's dense output (exact at a step's
    end); without output times, the solution at every step."""

    def __init__(self, t0, t1, y0, times):
        self.times, self.d = times, 1.0 if t1 >= t0 else -1.0
        if times is None:
            self.ts, self.ys = [t0], [y0]
        else:  # by output time: a step writes whole rows (columns of a large state are
            # strided writes, one memory page per state)
            self.x = np.empty((len(times), y0.size))
            self.k = int(np.searchsorted(self.d * times, self.d * t0, side="right"))
            self.x[:self.k] = y0  # the output time t0 itself

    def add(self, solver):
        """Record the step the solver just took."""
        if self.times is None:
            self.ts.append(solver.t)
            self.ys.append(solver.y.copy())
            return
        k = self.k
        end = k + int(np.searchsorted(self.d * self.times[k:], self.d * solver.t, side="right"))
        if end > k:
            self.x[k:end] = solver.dense_output()(self.times[k:end]).T
            if self.times[end - 1] == solver.t:
                self.x[end - 1] = solver.y
        self.k = end

    def arrays(self):
        """(t, x) with x of shape (n * batch, len(t))."""
        if self.times is None:
            return np.array(self.ts), np.stack(self.ys, axis=-1)
        return self.times, self.x.T


def _counts(stats, solver):
    """The statistics so far: the finished segments' plus the running solver's."""
    return {**stats, "njev": stats["njev"] + int(solver.njev),
            "nlu": stats["nlu"] + int(solver.nlu)}


# --------------------------------------------------------------------------------------------
# Rodas4, bgc's own implicit method: the 6-stage Rosenbrock method of order 4 (embedded order
# 3) of Hairer & Wanner (Solving ODEs II, sec. IV.7; coefficients from their RODAS), L-stable
# and stiffly accurate. It solves linear systems only: each step costs one Jacobian, one LU of
# W = I/(h gamma) - J and six rhs calls (plus one for df/dt when the model has inputs). Unlike
# BDF of orders 3-5 it damps stiff modes that lie near the imaginary axis (lightly damped
# penalty joints), and it needs no Newton iteration. Its order rests on the exact Jacobian:
# it takes the analytic one only.
_RODAS_GAMMA = 0.25
_RODAS_A = (  # stage i's state: y + sum_j A[i][j] k_j (rows padded to 6x6 below)
    (),
    (1.544,),
    (0.9466785280815826, 0.2557011698983284),
    (3.314825187068521, 2.896124015972201, 0.9986419139977817),
    (1.221224509226641, 6.019134481288629, 12.53708332932087, -0.687886036105895),
    (1.221224509226641, 6.019134481288629, 12.53708332932087, -0.687886036105895, 1.0),
)
_RODAS_C = (  # stage i's right-hand side: f_i + sum_j C[i][j] k_j / h + h d_i df/dt
    (),
    (-5.6688,),
    (-2.430093356833875, -0.2063599157091915),
    (-0.1073529058151375, -9.594562251023355, -20.47028614809616),
    (7.496443313967647, -10.24680431464352, -33.99990352819905, 11.7089089320616),
    (8.083246795921522, -7.981132988064893, -31.52159432874371, 16.31930543123136,
     -6.058818238834054),
)
_RODAS_T = (0.0, 0.386, 0.21, 0.63, 1.0, 1.0)  # stage times, fractions of h
_RODAS_D = (0.25, -0.1043, 0.1035, -0.0362, 0.0, 0.0)
_RODAS_H = (  # dense output (order 3): y(t0 + s h) = (1-s) y0 + s (y1 + (1-s)(q1 + s q2))
    (10.12623508344586, -7.487995877610167, -34.80091861555747, -7.992771707568823,
     1.025137723295662),
    (-0.6762803392801253, 6.087714651680015, 16.43084320892478, 24.76722511418386,
     -6.594389125716872),
)
# as 6x6 and 2x6 arrays, zero where a stage does not enter, so a step is a few matrix products
_RODAS_A, _RODAS_C = (np.array([row + (0.0,) * (6 - len(row)) for row in table])
                      for table in (_RODAS_A, _RODAS_C))
_RODAS_H = np.array([row + (0.0,) for row in _RODAS_H])
# step-size control (Hairer's RODAS): h_new = h * clip(0.9 err^(-1/4), 1/5, 6)
_RODAS_SAFETY, _RODAS_MIN_FACTOR, _RODAS_MAX_FACTOR = 0.9, 0.2, 6.0


def _rms(x):
    return float(np.sqrt(np.mean(np.square(x)))) if x.size else 0.0


def _rodas_class():
    """The Rodas4 OdeSolver class, made on first use (scipy is imported lazily)."""
    global _RODAS4
    if _RODAS4 is not None:
        return _RODAS4
    import scipy.linalg
    import scipy.sparse as sps
    import scipy.sparse.linalg
    from scipy.integrate import DenseOutput, OdeSolver

    class RodasDense(DenseOutput):
        """The step's interpolant: third order, exact at both ends."""

        def __init__(self, t_old, t, y_old, y, q1, q2):
            super().__init__(t_old, t)
            self.h, self.y_old, self.y, self.q1, self.q2 = t - t_old, y_old, y, q1, q2

        def _call_impl(self, t):
            s = (np.asarray(t, dtype=float) - self.t_old) / self.h
            y0, y1, q1, q2 = ((v if s.ndim == 0 else v[:, None])
                              for v in (self.y_old, self.y, self.q1, self.q2))
            return (1 - s) * y0 + s * (y1 + (1 - s) * (q1 + s * q2))

    class Rodas4(OdeSolver):
        """Rosenbrock method Rodas4 (scipy OdeSolver interface). jac(t, y) -> dense array or
        sparse matrix, the exact Jacobian; time_dependent: the rhs depends on t explicitly
        (df/dt is then taken by a forward difference, one rhs call per step)."""

        def __init__(self, fun, t0, y0, t_bound, jac, rtol=1e-6, atol=1e-9, max_step=np.inf,
                     first_step=None, time_dependent=True, **extraneous):
            super().__init__(fun, t0, y0, t_bound, vectorized=False)
            eps = np.finfo(float).eps
            self.rtol, self.atol = max(float(rtol), 100 * eps), atol
            self.max_step, self.jac, self.time_dependent = max_step, jac, time_dependent
            # LAPACK's getrf/getrs directly: scipy.linalg.lu_solve's argument checks cost
            # about as much as a 100x100 solve, six times a step
            self._getrf, self._getrs = scipy.linalg.get_lapack_funcs(("getrf", "getrs"),
                                                                     (self.y,))
            self.f = self.fun(self.t, self.y)
            self.h_abs = (self._initial_step() if first_step is None
                          else float(first_step))
            self.J = self.dfdt = None
            self.dense = self._eye = None

        def _scale(self, y, y_new=None):
            size = np.abs(y) if y_new is None else np.maximum(np.abs(y), np.abs(y_new))
            return self.atol + self.rtol * size

        def _initial_step(self):
            """Hairer's starting step for order 4: an explicit Euler probe of f's change."""
            if self.n == 0 or self.t_bound == self.t:
                return np.inf
            scale = self._scale(self.y)
            d0, d1 = _rms(self.y / scale), _rms(self.f / scale)
            h0 = 1e-6 if d0 < 1e-5 or d1 < 1e-5 else 0.01 * d0 / d1
            h0 = min(h0, abs(self.t_bound - self.t))
            f1 = self.fun(self.t + self.direction * h0, self.y + self.direction * h0 * self.f)
            d2 = _rms((f1 - self.f) / scale) / h0
            h1 = (max(1e-6, h0 * 1e-3) if max(d1, d2) <= 1e-15
                  else (0.01 / max(d1, d2)) ** 0.2)
            return min(100 * h0, h1, self.max_step)

        def _jacobian(self):
            """J and df/dt at the step's start (kept through rejected attempts)."""
            t, y = self.t, self.y
            J = self.jac(t, y)
            self.njev += 1
            self.J = sps.csc_matrix(J) if sps.issparse(J) else np.asarray(J, dtype=float)
            self.dfdt = np.zeros(self.n)
            if self.time_dependent:
                delta = np.sqrt(np.finfo(float).eps) * max(1.0, abs(t))
                # forward in the direction of integration, backward when that leaves the span
                d = self.direction * delta
                if self.direction * (t + d - self.t_bound) > 0:
                    d = -d
                self.dfdt = (self.fun(t + d, y) - self.f) / d

        def _factor(self, h):
            """A solver for W x = b, W = I/(h gamma) - J."""
            self.nlu += 1
            c = 1.0 / (h * _RODAS_GAMMA)
            if sps.issparse(self.J):
                if self._eye is None:
                    self._eye = sps.identity(self.n, format="csc")
                try:
                    lu = scipy.sparse.linalg.splu(self._eye * c - self.J)
                except RuntimeError:  # exactly singular W: the step is tried smaller
                    return None
                return lu.solve
            lu, piv, info = self._getrf(np.eye(self.n) * c - self.J, overwrite_a=True)
            if info > 0:  # exactly singular W: the step is tried smaller
                return None
            return lambda b: self._getrs(lu, piv, b)[0]

        def _attempt(self, h):
            """One Rodas4 step of size h (signed): (y_new, error estimate, dense coefficients);
            (None, None, None) when W is singular."""
            t, y = self.t, self.y
            solve = self._factor(h)
            if solve is None:
                return None, None, None
            K = np.zeros((6, self.n))  # the stages k_1..k_6
            for i in range(6):
                u = y + _RODAS_A[i] @ K  # rows of A and C are zero from column i on
                fi = self.f if i == 0 else self.fun(t + _RODAS_T[i] * h, u)
                K[i] = solve(fi + (_RODAS_C[i] / h) @ K + (h * _RODAS_D[i]) * self.dfdt)
            # stiffly accurate: the last stage's state plus k_6 is the solution, k_6 the error
            return u + K[5], K[5], _RODAS_H @ K

        def _step_impl(self):
            t, y = self.t, self.y
            min_step = 10 * abs(np.nextafter(t, self.direction * np.inf) - t)
            h_abs = min(max(self.h_abs, min_step), self.max_step)
            if self.J is None:
                self._jacobian()
            rejected = False
            while True:
                if h_abs < min_step:
                    return False, "the step size fell below its minimum (10 ulp of t)"
                h = h_abs * self.direction
                t_new = t + h
                if self.direction * (t_new - self.t_bound) > 0:
                    t_new = self.t_bound
                h = t_new - t
                h_abs = abs(h)
                y_new, err, q = self._attempt(h)
                err_norm = np.inf if y_new is None else _rms(err / self._scale(y, y_new))
                if np.isfinite(err_norm) and err_norm <= 1.0:
                    break
                # rejected: shrink (hard when the attempt overflowed) and retry with the same J
                factor = (_RODAS_MIN_FACTOR if not np.isfinite(err_norm) else
                          max(_RODAS_MIN_FACTOR, _RODAS_SAFETY * err_norm ** -0.25))
                h_abs *= factor
                rejected = True
            factor = (_RODAS_MAX_FACTOR if err_norm == 0 else
                      min(_RODAS_MAX_FACTOR, _RODAS_SAFETY * err_norm ** -0.25))
            if rejected:
                factor = min(1.0, factor)  # no growth right after a rejection
            self.h_abs = h_abs * max(_RODAS_MIN_FACTOR, factor)
            self.dense = (y, q)
            self.t, self.y = t_new, y_new
            self.f = self.fun(t_new, y_new)
            self.J = None
            return True, None

        def _dense_output_impl(self):
            y_old, (q1, q2) = self.dense
            return RodasDense(self.t_old, self.t, y_old, self.y, q1, q2)

    _RODAS4 = Rodas4
    return Rodas4


_RODAS4 = None


#: a given start farther than this from a closed loop's constraints (relative to the state's
#: scale, 1 at least) is refused by simulate, unless check_constraints=False
CONSTRAINT_TOL = 1e-8


def constraint_violation(t, x, p=None):
    """None when x meets the closed loops' constraints at t (each closure, each constraint's
    flow: constraint_residuals) within CONSTRAINT_TOL of the state's scale; else the message
    that names the first constraint violated and its residual (the worst instance of a batch).
    None for a model without constraints."""
    residuals = globals().get("constraint_residuals")
    if residuals is None or x is None:
        return None
    x = np.asarray(x, dtype=float)
    pos, vel = (np.asarray(r, dtype=float) for r in residuals(t, x, p))
    tol = CONSTRAINT_TOL * max(1.0, float(np.max(np.abs(x))))
    sources = [name.split(".q")[0] for name in CONSTRAINT_STATES]
    for src in dict.fromkeys(sources):
        rows = [k for k, s in enumerate(sources) if s == src]
        for kind, vals, unit in (("positions violate its closure", pos, "displacement"),
                                 ("velocities violate it", vel, "flow")):
            r = vals[rows].reshape(len(rows), -1)
            worst = np.max(np.abs(r), axis=0)
            if not np.max(worst) > tol:
                continue
            shown = ", ".join(f"{v:.6g}" for v in r[:, int(np.argmax(worst))])
            return (f"constraint {src!r} closing a kinematic loop: the initial {kind}: the "
                    f"residual is [{shown}] (SI units of the bond's {unit})")
    return None


def _check_start(t0, x0, p, check_constraints):
    """simulate's check of a given x0 against the closed loops' constraints."""
    if not check_constraints or x0 is None:
        return
    msg = constraint_violation(t0, x0, p)
    if msg:
        raise ValueError(f"x0: {msg}; give an initial state that closes the loop, or pass "
                         "check_constraints=False to start from it on purpose (the stabilised "
                         "constraint then pulls it back)")


def simulate(t_span, t_eval=None, method="Radau", rtol=1e-6, atol=1e-9, p=None, u=None,
             x0=None, dt=None, breakpoints=(), jac=True, max_step=np.inf, max_steps=50_000,
             stiff_check=True, max_wall=None, sparse=None, check_constraints=True):
    """Integrate over t_span with one of scipy's OdeSolver classes or bgc's Rosenbrock method
    Rodas4 (L-stable, order 4; see above); returns SimResult (t, x, y).

    method: one of METHODS. rtol; atol a scalar or one value per state. p: parameter overrides;
    arrays of shape B integrate the instances of B at once (the state is flattened; implicit
    methods get the block-diagonal Jacobian, sparse). u: input overrides {name: callable(t)}.
    x0: initial state (default initial_state(p)). t_eval, or dt (a uniform grid): output
    times, read off each step's dense output (default: every step). breakpoints: instants
    where inputs jump; each segment between them is a fresh solver, and inside (a, c) the
    model sees t only in [a, c) (one-sided inputs). jac: implicit methods get the analytic
    Jacobian, or with jac=False finite differences over JAC_SPARSITY. max_step: the solver's.
    max_steps: the most accepted steps over the whole span; SimulationError beyond.
    stiff_check (explicit methods): raise StiffnessError when stability would hold the steps
    down so far that the rest of the span needs more than max_steps of them, judged from the
    Jacobian at the start and, while integrating, from steps held at the stability limit.
    max_wall: seconds; SimulationError once the wall time is exceeded. sparse: the implicit
    methods' linear algebra, sparse (scipy.sparse, splu) or dense (LAPACK); None chooses by
    one instance's size and Jacobian density, a batch's flat size (SPARSE_MIN_SIZE,
    SPARSE_MAX_DENSITY, SPARSE_MIN_BATCH_SIZE: _use_sparse).
    Statistics in result.stats: nfev (rhs calls), njev, nlu, nsteps (accepted steps), nstiff
    (stiffness checks), summed over the segments. check_constraints: a given x0 of a model
    with closed loops is checked against their constraints (ValueError naming the constraint
    and its residual); False starts from it as given.
    """
    import time

    import scipy.integrate

    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}: one of {', '.join(METHODS)}")
    _check_start(float(t_span[0]), x0, p, check_constraints)
    # numpy's floating-point warnings stay quiet here: a value that is not finite stops the
    # run with a NonFiniteError that says where, instead of a warning on the terminal
    with np.errstate(all="ignore"):
        deadline = np.inf if max_wall is None else time.perf_counter() + max_wall
        x0, batch = _batched(x0, p)
        p_raw, p = p, _params(p)  # unpacked once: the solver calls rhs thousands of times
        shape = (N_STATES,) + batch
        y = np.array(x0, dtype=float).reshape(-1)
        stats = {"nfev": 0, "njev": 0, "nlu": 0, "nsteps": 0, "nstiff": 0}
        if not np.isfinite(y).all():
            raise _nonfinite(method, "initial state", float(t_span[0]), y, y, shape, stats)
        atol = _flat_atol(atol, batch)
        t0, t1 = float(t_span[0]), float(t_span[1])
        times = _output_times(t0, t1, t_eval, dt)
        if times is not None and y.size * times.size > MAX_RESULT_VALUES:
            raise ValueError(f"the result would hold {y.size * times.size} values (states x "
                             f"instances x output times), more than the limit of "
                             f"{MAX_RESULT_VALUES}")
        path = _Trajectory(t0, t1, y, times)
        # a table input that is not smooth at its knots (linear, previous) adds them (unless u
        # replaces that input)
        breakpoints = tuple(breakpoints) + tuple(
            k for name, knots in TABLE_BREAKPOINTS.items() if u is None or name not in u
            for k in knots)
        # a smooth (pchip) table needs no breakpoints, but no step may skip its knots
        max_step = min([max_step] + [h for name, h in TABLE_MAX_STEP.items()
                                     if u is None or name not in u])
        segments = _segments(t0, t1, breakpoints)
        watch = None
        if stiff_check and method in _STABILITY and segments:
            # stiff from the start: the Jacobian at t0 asks for more than max_steps steps
            stats["nstiff"] += 1
            lam = _eigenvalues(t0, y, shape, p, u, method, stats)
            _, steps, why = _stiffness(method, t0, t1, lam)
            if steps > max_steps:
                raise _error(StiffnessError, _stiff_message(method, t0, why), t0, stats)
            watch = _StiffnessWatch(method, t1, max_steps)
        if method == "LSODA" and jac and segments:
            # LSODA may switch to its stiff mode and use the analytic Jacobian at any time:
            # one must be finite where the run starts, as for the other implicit methods
            _flat_jacobian(_one_sided(*segments[0]), shape, p, u, False, method,
                           stats)(t0, y)
        for a, c in segments:
            at = _one_sided(a, c)
            solver_class = (_rodas_class() if method == "Rodas4"
                            else getattr(scipy.integrate, method))
            solver = solver_class(
                _flat_rhs(at, shape, p, u, stats, method), a, y, c, rtol=rtol, atol=atol,
                max_step=max_step, **_jacobian_options(method, jac, at, shape, p, u, stats,
                                                       sparse))
            _guard_solves(solver, method, stats, shape)
            while solver.status == "running":
                if stats["nsteps"] >= max_steps:  # as the C step loop: a located stop
                    raise _error(SimulationError, f"{method} stopped at t = {solver.t:.17g}: "
                                 f"max_steps = {max_steps} steps (raise the scene's solver "
                                 "max_steps or --max-steps)", solver.t, _counts(stats, solver))
                message = solver.step()
                if solver.status == "failed":
                    raise _error(SimulationError, f"{method} failed at t = {solver.t:.6g}: "
                                 f"{message}", solver.t, _counts(stats, solver))
                stats["nsteps"] += 1
                path.add(solver)
                if time.perf_counter() > deadline:
                    raise _error(SimulationError, f"{method} stopped at t = {solver.t:.6g}: the "
                                 f"wall time exceeded max_wall = {max_wall:g} s", solver.t,
                                 _counts(stats, solver))
                if watch is not None and watch.due():
                    # stiff by now: the accepted steps are held at the stability limit
                    stats["nstiff"] += 1
                    lam = _eigenvalues(at(solver.t), solver.y, shape, p, u, method,
                                       _counts(stats, solver))
                    stiff = watch.check(solver.t, solver.step_size, lam)
                    if stiff:
                        raise _error(StiffnessError, stiff, solver.t, _counts(stats, solver))
            stats.update(_counts(stats, solver))
            y = solver.y
        t, X = path.arrays()
        X = X.reshape(shape + (len(t),))
        # batched parameters get a trailing axis for the output times
        pt = None if p_raw is None else {
            name: np.asarray(v)[..., None] if np.ndim(v) > _PARAM_NDIM[name] else v
            for name, v in p_raw.items()}
        return SimResult(t, X, outputs(t, X, pt, u), stats)


# --------------------------------------------------------------------------------------------
# Table inputs: data compiled into the module as numbers, evaluated by these functions.


_PCHIP_SLOPES = {}  # table index -> slopes, computed on first use


def _pchip_slopes(t, v):
    """Fritsch-Carlson slopes of the monotone piecewise cubic Hermite interpolant: weighted
    harmonic means of the neighbouring secants, zero at a local extremum; the end slopes by
    the one-sided three-point formula, limited to keep the shape."""
    h = np.diff(t)
    s = np.diff(v) / h
    d = np.zeros_like(v)
    if len(t) == 2:
        d[:] = s[0]
        return d
    w1 = 2 * h[1:] + h[:-1]
    w2 = h[1:] + 2 * h[:-1]
    same = (s[:-1] * s[1:]) > 0
    with np.errstate(divide="ignore", invalid="ignore"):
        hm = (w1 + w2) / (w1 / s[:-1] + w2 / s[1:])
    d[1:-1] = np.where(same, hm, 0.0)
    for end, (h0, h1, s0, s1) in ((0, (h[0], h[1], s[0], s[1])),
                                  (-1, (h[-1], h[-2], s[-1], s[-2]))):
        de = ((2 * h0 + h1) * s0 - h0 * s1) / (h0 + h1)
        if np.sign(de) != np.sign(s0):
            de = 0.0
        elif np.sign(s0) != np.sign(s1) and abs(de) > abs(3 * s0):
            de = 3 * s0
        d[end] = de
    return d


def _table_eval(t, k, interp, extrapolate, name):
    """The value of a table input at t (scalar or array): linear, pchip or previous
    (zero-order hold: the value at the last knot at or before t); outside the knots the end
    value is held, or ValueError with extrapolate='error'."""
    tk, vk = _TABLES[k]
    t = np.asarray(t, dtype=float)
    if extrapolate == "error" and (np.any(t < tk[0]) or np.any(t > tk[-1])):
        raise ValueError(f"input {name!r}: t = {np.min(t) if np.any(t < tk[0]) else np.max(t):g}"
                         f" is outside its table [{tk[0]:g}, {tk[-1]:g}] (extrapolate: error)")
    tc = np.clip(t, tk[0], tk[-1])
    if interp == "linear":
        return np.interp(tc, tk, vk)
    if interp == "previous":
        i = np.clip(np.searchsorted(tk, tc, side="right") - 1, 0, len(tk) - 1)
        return vk[i]
    if k not in _PCHIP_SLOPES:
        _PCHIP_SLOPES[k] = _pchip_slopes(tk, vk)
    dk = _PCHIP_SLOPES[k]
    i = np.clip(np.searchsorted(tk, tc, side="right") - 1, 0, len(tk) - 2)
    h = tk[i + 1] - tk[i]
    s = (tc - tk[i]) / h
    h00, h10 = (1 + 2 * s) * (1 - s) ** 2, s * (1 - s) ** 2
    h01, h11 = s * s * (3 - 2 * s), s * s * (s - 1)
    return h00 * vk[i] + h10 * h * dk[i] + h01 * vk[i + 1] + h11 * h * dk[i + 1]


# --------------------------------------------------------------------------------------------
# Linearisation and equilibrium, from the analytic derivatives of the model part.


def _signals(u):
    """Input overrides as callables: a number or an array is held constant."""
    if u is None:
        return None
    return {k: (v if callable(v) else (lambda t, _v=np.asarray(v, dtype=float): _v))
            for k, v in u.items()}


def linearize(t, x, u=None, p=None):
    """The linearisation at (t, x): (A, B, C, D) with dx = A x + B u, y = C x + D u,
    analytic. A: (n, n), B: (n, m), C: (ny, n), D: (ny, m), each with x's batch axes after
    them. The columns of B and D follow INPUT_LABELS (m = 0 for a model without inputs), the
    rows of C and D OUTPUT_LABELS (each output of OUTPUT_NAMES flattened row-major). u:
    {name: callable(t) or value} overrides of the inputs; p: parameter overrides."""
    u = _signals(u)
    p = _params(p)
    x = np.asarray(x, dtype=float)
    A = jacobian(t, x, p, u)
    B = input_jacobian(t, x, p, u)
    C, D = output_jacobian(t, x, p, u)
    return A, B, C, D


class EquilibriumInfo:
    """What equilibrium() found: converged (bool per batch instance), residual (max |rhs|),
    iterations, rank of the Jacobian, free: per instance, the free directions (the null
    space of the Jacobian, where the equilibrium is not unique: a position with no stiffness,
    a continuum of equilibria), each a dict {state name: component} of its largest
    components, and settled: per instance, the time the damped dynamics ran from x0 before
    Newton's polish (None where Newton alone found it). For an unbatched call, converged,
    residual, rank and settled are scalars and free is one list."""

    def __init__(self, converged, residual, iterations, rank, free, null_space, settled=None):
        self.converged, self.residual, self.iterations = converged, residual, iterations
        self.rank, self.free, self.null_space = rank, free, null_space
        self.settled = settled

    def __repr__(self):
        return (f"EquilibriumInfo(converged={self.converged!r}, residual={self.residual!r}, "
                f"iterations={self.iterations}, rank={self.rank!r}, free={self.free!r}, "
                f"settled={self.settled!r})")


def _free_directions(V, names, top=4):
    out = []
    for v in V.T:
        order = np.argsort(-np.abs(v))[:top]
        out.append({names[i]: float(v[i]) for i in order if abs(v[i]) > 1e-3})
    return out


def _hold_invariants(step, U, Vt, keep):
    """The step moved along the null space (columns N of V where S is dropped) so that it
    leaves the invariants' linearisation alone: L^T step = 0, L the left null space (columns
    of U where S is dropped), which spans the invariants' gradients at an equilibrium."""
    for b in range(step.shape[0]):
        drop = ~keep[b]
        if drop.any():
            L, N = U[b][:, drop], Vt[b][drop].T
            a = np.linalg.lstsq(L.T @ N, -(L.T @ step[b]), rcond=None)[0]
            step[b] = step[b] + N @ a
    return step


def _newton(f, jac, x, scale, tol, max_iter, rcond, hold=False):
    """Newton on f(x) = 0 from x (nb, n), minimum-norm steps (pseudo-inverse by SVD) with a
    backtracking line search on |f|^2; returns (x, max |f| per instance, iterations). hold:
    each step keeps the invariants' linearisation (_hold_invariants): a polish that stays on
    the invariant leaf it starts on."""
    nb = x.shape[0]
    r = f(x)
    res = np.max(np.abs(r), axis=1)
    done = res <= tol * scale
    it = 0
    for it in range(1, max_iter + 1):
        if np.all(done):
            it -= 1
            break
        U, S, Vt = np.linalg.svd(jac(x))
        keep = S > rcond * np.maximum(S[:, :1], 1e-300)
        Sinv = np.where(keep, 1.0 / np.where(keep, S, 1.0), 0.0)
        step = -np.einsum("bji,bj,bkj,bk->bi", Vt, Sinv, U, r)
        if hold:
            step = _hold_invariants(step, U, Vt, keep)
        step[done] = 0.0
        phi = np.sum(r * r, axis=1)
        lam = np.ones(nb)
        for _ in range(30):  # backtracking (Armijo) per instance
            xt = x + lam[:, None] * step
            rt = f(xt)
            pt = np.sum(rt * rt, axis=1)
            ok = (pt <= (1 - 1e-4 * lam) * phi) | done | ~np.isfinite(phi)
            if np.all(ok):
                break
            lam = np.where(ok, lam, lam * 0.5)
        # where no decrease is possible (a least-squares minimum), stay
        better = pt < phi
        x = np.where(better[:, None], xt, x)
        r = np.where(better[:, None], rt, r)
        res = np.max(np.abs(r), axis=1)
        small = np.max(np.abs(step), axis=1) <= 1e-14 * (1 + np.max(np.abs(x), axis=1))
        done = done | (res <= tol * scale) | ~better | small
    return x, res, it


#: The settle's accuracy (Radau's rtol; atol is SETTLE_RTOL * 1e-4), where it hands over to
#: Newton (max |rhs| below SETTLE_TOL times the scale of rhs at x0) and its budget in rhs
#: calls per instance.
SETTLE_RTOL, SETTLE_TOL, SETTLE_MAX_RHS = 1e-6, 1e-6, 200_000
#: A non-isolated answer of Newton that moved less than this from x0 (max |x - x0| over
#: 1 + max |x0|) stands without a settle: the invariants barely moved with it.
SETTLE_MOVED = 0.1


def _settle(f1, j1, x0, scale):
    """Integrate dx/dt = f1(x) (the inputs held) from x0 until it comes to rest: chunks of
    doubling length, from the longest time scale of the Jacobian at x0 (its smallest eigenvalue
    that is not zero) up. A trajectory keeps
    every invariant of the dynamics (a spring's deflection tied to the angles it closes, a
    conserved momentum), so where the model dissipates it ends on the equilibrium of x0's
    invariant leaf. Returns (x, time run), or (None, time) when it does not come to rest
    (no dissipation, no equilibrium, a failed step) within SETTLE_MAX_RHS calls."""
    import scipy.integrate as si  # lazy: only a non-isolated equilibrium settles

    x = np.array(x0, dtype=float)
    res = float(np.max(np.abs(f1(x)))) if x.size else 0.0
    if res <= SETTLE_TOL * scale:
        return x, 0.0
    lam = np.abs(np.linalg.eigvals(j1(x)))
    lam = lam[np.isfinite(lam) & (lam > 1e-9 * max(float(np.max(lam, initial=0.0)), 1e-300))]
    span = 1.0 / float(np.min(lam)) if lam.size else 1.0
    t, best, stale, calls = 0.0, res, 0, 0
    while calls < SETTLE_MAX_RHS and stale < 6:
        sol = si.solve_ivp(lambda _t, y: f1(y), (0.0, span), x, method="Radau",
                           jac=lambda _t, y: j1(y), rtol=SETTLE_RTOL, atol=SETTLE_RTOL * 1e-4)
        calls += sol.nfev
        if not sol.success or not np.all(np.isfinite(sol.y[:, -1])):
            return None, t
        x, t = sol.y[:, -1], t + span
        res = float(np.max(np.abs(f1(x))))
        if res <= SETTLE_TOL * scale:
            return x, t
        stale = 0 if res < 0.5 * best else stale + 1
        best, span = min(best, res), 2.0 * span
    return None, t


def equilibrium(u=None, p=None, x0=None, t=0.0, tol=1e-10, max_iter=100, rcond=1e-9,
                settle=True):
    """A state where rhs = 0, inputs held at their values at t: Newton's method with the
    analytic Jacobian and a backtracking line search on |rhs|^2. Where the Jacobian is
    singular (a free position: no stiffness holds it), each step is the least-squares,
    minimum-norm one (pseudo-inverse by SVD, singular values below rcond times the largest
    treated as zero), so the free directions keep their values from x0; they are reported in
    info.free by state name. Where the equilibria form a continuum (a singular Jacobian at
    Newton's answer) and Newton's answer moved far from x0 (SETTLE_MOVED), or Newton fails,
    and settle is true, the dynamics are first integrated
    from x0 until they come to rest (_settle), then Newton polishes from there: the answer is
    the equilibrium on x0's invariant leaf (a closing spring's deflection consistent with the
    angles), where the model dissipates; info.settled gives the time run. The polish's steps
    hold the invariants: each is moved along the Jacobian's null space until it is orthogonal
    to the left null space (the invariants' gradients), so the last stretch of the way to rest
    stays on the leaf too. Batched like rhs:
    x0 (n, *batch) and array parameters. Returns (x, info); converged where max |rhs| <= tol
    * (1 + max |rhs(x0)|)."""
    u = _signals(u)
    p = _params(p)
    x0 = initial_state(p) if x0 is None else np.asarray(x0, dtype=float)
    x0, batch = _batched(x0, p)
    n = N_STATES
    nb = int(np.prod(batch)) if batch else 1

    def f(xf):  # (nb, n) -> (nb, n)
        return np.moveaxis(rhs(t, np.moveaxis(xf.reshape(batch + (n,)), -1, 0), p, u)
                           .reshape((n,) + batch), 0, -1).reshape(nb, n)

    def jac(xf):  # (nb, n) -> (nb, n, n)
        J = jacobian(t, np.moveaxis(xf.reshape(batch + (n,)), -1, 0), p, u)
        J = np.broadcast_to(J, (n, n) + batch).reshape(n, n, nb)
        return np.moveaxis(J, -1, 0)

    def rank_null(x):
        _, S, Vt = np.linalg.svd(jac(x))
        keep = S > rcond * np.maximum(S[:, :1], 1e-300)
        return keep.sum(axis=1), [Vt[b][~keep[b]].T for b in range(nb)]

    start = np.moveaxis(np.array(x0, dtype=float).reshape(n, nb), 0, -1).copy()
    scale = 1.0 + np.max(np.abs(f(start)), axis=1)
    x, res, it = _newton(f, jac, start, scale, tol, max_iter, rcond)
    rank, null = rank_null(x)
    settled = [None] * nb
    if settle and n:
        again = start.copy()
        moved = np.max(np.abs(x - start), axis=1) / (1.0 + np.max(np.abs(start), axis=1))
        suspect = (res > tol * scale) | ((rank < n) & (moved > SETTLE_MOVED))
        for b in np.flatnonzero(suspect):
            def f1(y, b=b):  # one instance, the others at their start
                xb = start.copy()
                xb[b] = y
                return f(xb)[b]

            def j1(y, b=b):
                xb = start.copy()
                xb[b] = y
                return jac(xb)[b]

            xs, ts = _settle(f1, j1, start[b], scale[b])
            if xs is not None:
                again[b], settled[b] = xs, ts
        if any(s is not None for s in settled):
            # the polish aims at tol relative to where the settle stopped (the start's scale
            # may be a stiff spring's force, far above what is left), and is judged as Newton
            tight = 1.0 + np.max(np.abs(f(again)), axis=1)
            x2, res2, it2 = _newton(f, jac, again, tight, tol, max_iter, rcond, hold=True)
            use = np.array([s is not None for s in settled]) & (res2 <= tol * scale)
            settled = [s if use[b] else None for b, s in enumerate(settled)]
            x = np.where(use[:, None], x2, x)
            res = np.where(use, res2, res)
            it = max(it, it2)
            rank, null = rank_null(x)
    free = [_free_directions(V, STATE_NAMES) for V in null]
    conv = res <= tol * scale
    xs = np.moveaxis(x.reshape(batch + (n,)), -1, 0)
    if not batch:
        return xs, EquilibriumInfo(bool(conv[0]), float(res[0]), it, int(rank[0]), free[0],
                                   null[0], settled[0])
    return xs, EquilibriumInfo(conv.reshape(batch), res.reshape(batch), it,
                               rank.reshape(batch), free, null, settled)
