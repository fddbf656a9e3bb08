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
JAC_SPARSITY: np.ndarray
rhs = jacobian = outputs = initial_state = _params = None  # the model's, in a generated module
xp = np  # the model part's array namespace

# ==== bgc numpy runtime: copied below this line ====
class SimulationError(RuntimeError):
    """The integrator failed or was stopped (the message says why): .t where, .stats the counts."""

    t = None
    stats = None


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


def _batched(x0, p):
    """The initial state broadcast to (n, *batch): batch is what x0 and the parameters span."""
    x0 = initial_state(p) if x0 is None else np.asarray(x0, dtype=float)
    batch = np.broadcast_shapes(x0.shape[1:], _params(p)[1])
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
    if t_eval is None and dt is not None:
        t_eval = np.linspace(t0, t1, int(round(abs(t1 - t0) / dt)) + 1)
    if t_eval is None:
        return None
    t = np.unique(np.asarray(t_eval, dtype=float))
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


def _flat_rhs(at, shape, p, u, stats):
    """rhs on the solver's flat state (n * batch,), at the one-sided time at(t); counts calls."""
    def fun(t, y):
        stats["nfev"] += 1
        return rhs(at(t), y.reshape(shape + y.shape[1:]), p, u).reshape(y.shape)
    return fun


def _block_pattern(nb):
    """Rows and columns of the flat Jacobian's nonzeros: one JAC_SPARSITY block per instance."""
    rows, cols = np.nonzero(JAC_SPARSITY)
    b = np.arange(nb)
    return (rows[:, None] * nb + b).ravel(), (cols[:, None] * nb + b).ravel()


def _flat_jacobian(at, shape, p, u, sparse):
    """The analytic Jacobian on the flat state: block diagonal over a batch (sparse or dense)."""
    import scipy.sparse as sps

    nb = int(np.prod(shape[1:]))
    rows, cols = np.nonzero(JAC_SPARSITY)
    R, C = _block_pattern(nb)

    def jac(t, y):
        J = jacobian(at(t), y.reshape(shape), p, u).reshape(N_STATES, N_STATES, nb)
        if nb == 1:
            return J[:, :, 0]
        vals = J[rows, cols].ravel()
        if sparse:
            return sps.csc_matrix((vals, (R, C)), shape=(len(y), len(y)))
        M = np.zeros((len(y), len(y)))
        M[R, C] = vals
        return M
    return jac


def _jacobian_options(method, jac, at, shape, p, u):
    """The solver's Jacobian: analytic (jac=True), else finite differences over JAC_SPARSITY."""
    import scipy.sparse as sps

    nb = int(np.prod(shape[1:]))
    if method in _STABILITY:
        return {}  # explicit: no Jacobian
    if method == "Rodas4":
        if not jac:
            raise ValueError("Rodas4 needs the analytic Jacobian (jac=True): a Rosenbrock "
                             "method's order rests on the exact Jacobian")
        return {"jac": _flat_jacobian(at, shape, p, u, sparse=True),
                "time_dependent": bool(INPUT_NAMES)}
    if jac:
        return {"jac": _flat_jacobian(at, shape, p, u, sparse=method != "LSODA")}
    if method == "LSODA":
        return {}  # LSODA differences densely (it takes no sparsity pattern)
    if nb == 1:
        return {"jac_sparsity": JAC_SPARSITY}
    R, C = _block_pattern(nb)
    return {"jac_sparsity": sps.csc_matrix((np.ones(len(R)), (R, C)),
                                           shape=(N_STATES * nb,) * 2)}


def _eigenvalues(t, y, shape, p, u):
    """Eigenvalues of the analytic Jacobian at (t, y), over up to _STIFF_SAMPLE batch instances."""
    J = np.asarray(jacobian(t, y.reshape(shape), p, u)).reshape(N_STATES, N_STATES, -1)
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
        else:
            self.x = np.empty((y0.size, len(times)))
            self.k = int(np.searchsorted(self.d * times, self.d * t0, side="right"))
            self.x[:, :self.k] = y0[:, None]  # the output time t0 itself

    def add(self, solver):
        """Record the step the solver just took."""
        if self.times is None:
            self.ts.append(solver.t)
            self.ys.append(solver.y.copy())
            return
        k = self.k
        end = k + int(np.searchsorted(self.d * self.times[k:], self.d * solver.t, side="right"))
        if end > k:
            self.x[:, k:end] = solver.dense_output()(self.times[k:end])
            if self.times[end - 1] == solver.t:
                self.x[:, end - 1] = solver.y
        self.k = end

    def arrays(self):
        """(t, x) with x of shape (n * batch, len(t))."""
        if self.times is None:
            return np.array(self.ts), np.stack(self.ys, axis=-1)
        return self.times, self.x


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
            self.dense = None

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
                try:
                    lu = scipy.sparse.linalg.splu(sps.identity(self.n, format="csc") * c
                                                  - self.J)
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


def simulate(t_span, t_eval=None, method="Radau", rtol=1e-6, atol=1e-9, p=None, u=None,
             x0=None, dt=None, breakpoints=(), jac=True, max_step=np.inf, max_steps=50_000,
             stiff_check=True, max_wall=None):
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
    stiff_check (explicit methods): raise StiffnessError when stability would hold the steps
    down so far that the rest of the span needs more than max_steps of them, judged from the
    Jacobian at the start and, while integrating, from steps held at the stability limit.
    max_wall: seconds; SimulationError once the wall time is exceeded.
    Statistics in result.stats: nfev (rhs calls), njev, nlu, nsteps (accepted steps), nstiff
    (stiffness checks), summed over the segments.
    """
    import time

    import scipy.integrate

    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}: one of {', '.join(METHODS)}")
    deadline = np.inf if max_wall is None else time.perf_counter() + max_wall
    x0, batch = _batched(x0, p)
    p_raw, p = p, _params(p)  # unpacked once: the solver calls rhs thousands of times
    shape = (N_STATES,) + batch
    y = np.array(x0, dtype=float).reshape(-1)
    atol = _flat_atol(atol, batch)
    t0, t1 = float(t_span[0]), float(t_span[1])
    path = _Trajectory(t0, t1, y, _output_times(t0, t1, t_eval, dt))
    stats = {"nfev": 0, "njev": 0, "nlu": 0, "nsteps": 0, "nstiff": 0}
    segments = _segments(t0, t1, breakpoints)
    watch = None
    if stiff_check and method in _STABILITY and segments:
        # stiff from the start: the Jacobian at t0 asks for more than max_steps steps
        stats["nstiff"] += 1
        lam = _eigenvalues(t0, y, shape, p, u)
        _, steps, why = _stiffness(method, t0, t1, lam)
        if steps > max_steps:
            raise _error(StiffnessError, _stiff_message(method, t0, why), t0, stats)
        watch = _StiffnessWatch(method, t1, max_steps)
    for a, c in segments:
        at = _one_sided(a, c)
        solver_class = _rodas_class() if method == "Rodas4" else getattr(scipy.integrate, method)
        solver = solver_class(
            _flat_rhs(at, shape, p, u, stats), a, y, c, rtol=rtol, atol=atol,
            max_step=max_step, **_jacobian_options(method, jac, at, shape, p, u))
        while solver.status == "running":
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
                lam = _eigenvalues(at(solver.t), solver.y, shape, p, u)
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
