"""bgc's C binding: the part of every C-backend wrapper module that calls the shared library.

A wrapper module is the numpy module of the same model printed without its equations (its
constants, parameter handling and Python runtime), then the C part: a few constants and
everything below the marker line of this file, copied verbatim. The functions defined here are
the model's rhs, jacobian, outputs and initial_state, calls into the library (ctypes; no
compiler needed at run time); simulate runs Radau, Rodas4 and DOP853 in C and hands scipy's
methods to the numpy runtime's step loop with the compiled rhs and Jacobian. What only the
numpy module's equations can do (input overrides u=, the linearisation's B, C and D) runs in
the numpy module of the same model, which bgc's loader provides on first use
(``_NUMPY_MODULE``). The names the numpy part defines are declared here for readers and
linters only.
"""
# flake8: noqa: F821
from __future__ import annotations

import numpy as np

N_STATES: int
STATE_NAMES: tuple
OUTPUT_NAMES: tuple
OUTPUT_SHAPES: dict
JAC_SPARSITY: np.ndarray
TABLE_BREAKPOINTS: dict
TABLE_MAX_STEP: dict
_PARAM_NDIM: dict
C_LIBRARY: str
C_DIGEST: str
MAX_RESULT_VALUES: int
N_EVENTS = 0  # a hybrid model's numpy part defines these (templates/numpy/events.py.j2)
EVENT_NAMES = EVENT_WHERE = ()
_C_NP = _C_NNZ = _C_NOUT = _C_NWS = _C_NCONS = 0
simulate = _params = _batched = X0 = _check_start = None
_output_times = _error = SimResult = SimulationError = None

# ==== bgc C binding: copied below this line ====
import ctypes as _ct
import os as _os
import threading as _threading

_np_simulate = simulate  # the numpy runtime's step loop (it calls the compiled rhs below)
_NUMPY_MODULE = None  # () -> the numpy module of the same model: bgc's loader sets it
_NP_MOD = None


def _numpy(what):
    """The numpy module of the same model, for what only its equations compute (made on first
    use by the callable bgc's loader put in _NUMPY_MODULE)."""
    global _NP_MOD
    if _NP_MOD is None:
        if _NUMPY_MODULE is None:
            raise RuntimeError(f"{what} runs in the numpy module of this model, which this C "
                               "wrapper does not hold: load it through bgc (bgc.compile(..., "
                               "target='c')), or compile the numpy module (bgc compile MODEL)")
        _NP_MOD = _NUMPY_MODULE()
    return _NP_MOD


def input_jacobian(t, x, p=None, u=None):
    """d(rhs)/du, analytic: (n, m, *batch), from the numpy module of the same model."""
    return _numpy("input_jacobian").input_jacobian(t, x, p, u)


def output_jacobian(t, x, p=None, u=None):
    """(C, D) = (d(outputs)/dx, d(outputs)/du), analytic, from the numpy module."""
    return _numpy("output_jacobian").output_jacobian(t, x, p, u)
C_METHODS = {"Rodas4": 0, "Radau": 1, "DOP853": 2}  # the methods whose step loop runs in C
_EXPLICIT = ("DOP853",)  # C methods that need no Jacobian
_C_STATUS = {1: "non-finite value", 2: "too many steps", 3: "step size too small",
             4: "wall time exceeded", 5: "singular iteration matrix", 6: "model failure",
             7: "bad arguments", 8: "Zeno behaviour or chattering"}
_EV_CAP = 4096  # event log rows per instance and run (a run with more runs again, larger)
_N_EV = globals().get("N_EVENTS", 0)  # a hybrid model's events (its numpy part defines them)
_LIB = None
_DP = _ct.c_void_p  # arrays are passed by address (ndarray.ctypes.data)
_JAC_ROWS, _JAC_COLS = np.nonzero(JAC_SPARSITY)
_OUT_SIZES = tuple(int(np.prod(OUTPUT_SHAPES[_o], dtype=int)) for _o in OUTPUT_NAMES)


def _bind(path):
    """Load the shared library at path (the one built from this module's C sources)."""
    global _LIB
    lib = _ct.CDLL(_os.fspath(path))
    lib.bgcm_digest.restype = _ct.c_char_p
    if lib.bgcm_digest().decode("ascii") != C_DIGEST:
        raise ImportError(f"{path}: the library was built from other C sources than this "
                          "module's (rebuild it with `bgc compile --target c`)")
    ev = [_ct.c_int, _DP, _ct.c_int, _DP, _ct.c_int, _DP, _ct.c_int, _DP, _DP]
    for fn in ("bgcm_eval_rhs", "bgcm_eval_jac", "bgcm_eval_outputs"):
        getattr(lib, fn).argtypes, getattr(lib, fn).restype = ev, _ct.c_int
    if _C_NCONS:  # closed loops: their constraint values (_constraint_values)
        lib.bgcm_eval_cons.argtypes, lib.bgcm_eval_cons.restype = ev, _ct.c_int
    lib.bgcm_eval_init.argtypes = [_ct.c_int, _DP, _ct.c_int, _DP, _DP]
    lib.bgcm_eval_init.restype = _ct.c_int
    lib.bgcm_info.argtypes = [_ct.POINTER(_ct.c_int)]
    lib.bgcm_state_name.restype = _ct.c_char_p
    lib.bgcm_fail_message.argtypes, lib.bgcm_fail_message.restype = [_ct.c_int], _ct.c_char_p
    lib.bgcm_fail_is_value_error.argtypes = [_ct.c_int]
    lib.bgcm_fail_is_value_error.restype = _ct.c_int
    lib.bgcm_simulate.restype = _ct.c_int
    lib.bgcm_simulate.argtypes = [
        _ct.c_int, _ct.c_double, _DP, _ct.c_int, _ct.c_double, _ct.c_double, _ct.c_long,
        _ct.c_double, _DP, _ct.c_int, _DP, _ct.c_int, _ct.c_int, _DP, _DP, _ct.c_double,
        _ct.c_double, _DP, _DP, _ct.c_char_p, _ct.c_int]
    if _N_EV:  # a hybrid model: the event log, counts and Zeno guard
        lib.bgcm_simulate.argtypes += [_DP, _ct.c_int, _DP, _ct.c_int, _ct.c_double]
    info = (_ct.c_int * 6)()
    lib.bgcm_info(info)
    sizes = (info[0], info[1], info[2], info[3], info[5])
    if sizes != (N_STATES, _C_NP, _C_NNZ, _C_NOUT, _C_NWS):
        raise ImportError(f"{path}: the library's sizes {sizes} are not the module's")
    _LIB = lib
    global X0
    X0 = initial_state()  # the initial state at the default parameters, computed in C
    return lib


def _lib():
    if _LIB is None:
        raise RuntimeError("the C library is not loaded: import the wrapper from the folder "
                           f"that holds {C_LIBRARY}, or call _bind(path)")
    return _LIB


def _ptr(a):
    return a.ctypes.data


_WARM = _threading.local()  # per thread: batch size -> the Newton loops' warm starts


def _warm(nb):
    """The warm starts (nb, _C_NWS) of the model's Newton loops for a call on nb instances:
    the last solutions of this thread's previous call on as many instances (the library
    updates them), zero at first; None (no address) for a model without Newton loops."""
    if not _C_NWS:
        return None
    d = getattr(_WARM, "d", None)
    if d is None:
        d = _WARM.d = {}
    w = d.get(nb)
    if w is None:
        if len(d) >= 8:  # a few batch sizes are kept, not every one ever seen
            d.pop(next(iter(d)))
        w = d[nb] = np.zeros((nb, _C_NWS))
    return _ptr(w)


def _check(rc):
    """A model function's failure as the numpy module raises it: a SimulationError with its
    located message for a numeric solve (a Newton loop that did not converge, a singular
    linear system), a ValueError for a table input outside its knots (extrapolate: error)."""
    if rc:
        raise (ValueError if _lib().bgcm_fail_is_value_error(int(rc)) else SimulationError)(
            _fail_message(rc))


def _fail_message(code):
    return _lib().bgcm_fail_message(int(code)).decode("utf-8", "replace") or \
        f"model failure (code {code})"


def _c_array(a, shape):
    """a broadcast to shape, as a C-contiguous float64 array."""
    return np.ascontiguousarray(np.broadcast_to(np.asarray(a, dtype=float), shape))


def _instances(t, x, p, extra=()):
    """Flatten (t, x, p) over their broadcast batch shape B: (B, nb, T, st, X, sx, P, sp) with
    strides 0 for a value shared by every instance."""
    pv, bshape = _params(p)
    x = np.asarray(x, dtype=float)
    t = np.asarray(t, dtype=float)
    B = np.broadcast_shapes(x.shape[1:], bshape, t.shape, extra)
    nb = int(np.prod(B, dtype=int))
    if t.ndim == 0:
        T, st = np.array([float(t)]), 0
    else:
        T, st = _c_array(t, B).reshape(nb), 1
    if x.ndim == 1:
        X, sx = np.ascontiguousarray(x), 0
    else:
        X, sx = np.moveaxis(_c_array(x, (N_STATES,) + B).reshape(N_STATES, nb), 0, 1), N_STATES
        X = np.ascontiguousarray(X)
    if not bshape:
        P, sp = _P_flat(pv), 0
    else:
        P = np.empty((nb, _C_NP))
        for k, v in enumerate(pv):
            P[:, k] = np.broadcast_to(np.asarray(v, dtype=float), B).reshape(nb)
        sp = _C_NP
    return B, nb, T, st, X, sx, P, sp


def _P_flat(pv):
    flat = np.array([float(v) for v in pv], dtype=float)
    return flat if flat.size else np.zeros(1)  # no parameters: an address all the same


def _p_flat_cached(p):
    """The flat parameter values of p (no batch), kept for the last p seen: the solvers call
    rhs thousands of times with the same parameters."""
    global _P_LAST
    if _P_LAST is not None and _P_LAST[0] is p:
        return _P_LAST[1]
    pv, bshape = _params(p)
    if bshape:
        return None
    flat = _P_flat(pv)
    if p is None or type(p).__name__ == "_Unpacked":
        _P_LAST = (p, flat)
    return flat


_P_LAST = None


def rhs(t, x, p=None, u=None):
    """dx/dt at time t, computed in C. x: (n,) or (n, *batch). Input overrides u run in the
    numpy code (the C functions compute the scene's signals themselves)."""
    if u is not None:
        return _numpy("input overrides (u=)").rhs(t, x, p, u)
    if type(x) is np.ndarray and x.shape == (N_STATES,) and x.dtype == np.float64 and np.ndim(t) == 0:
        P = _p_flat_cached(p)
        if P is not None:  # one instance: the fast path
            x = np.ascontiguousarray(x)
            dx = np.empty(N_STATES)
            T = np.array([float(t)])  # kept alive across the call: _ptr gives a bare address
            _check(_lib().bgcm_eval_rhs(1, _ptr(T), 0, _ptr(x), 0, _ptr(P), 0, _ptr(dx),
                                        _warm(1)))
            return dx
    B, nb, T, st, X, sx, P, sp = _instances(t, x, p)
    DX = np.empty((nb, N_STATES))
    _check(_lib().bgcm_eval_rhs(nb, _ptr(T), st, _ptr(X), sx, _ptr(P), sp, _ptr(DX),
                                _warm(nb)))
    return np.moveaxis(DX, 0, 1).reshape((N_STATES,) + B) if B else DX[0]


def jacobian(t, x, p=None, u=None):
    """d(rhs)/dx, analytic, computed in C: (n, n, *batch)."""
    if u is not None:
        return _numpy("input overrides (u=)").jacobian(t, x, p, u)
    B, nb, T, st, X, sx, P, sp = _instances(t, x, p)
    JV = np.empty((nb, max(_C_NNZ, 1)))
    _check(_lib().bgcm_eval_jac(nb, _ptr(T), st, _ptr(X), sx, _ptr(P), sp, _ptr(JV), _warm(nb)))
    J = np.zeros((N_STATES, N_STATES, nb))
    J[_JAC_ROWS, _JAC_COLS] = JV[:, :_C_NNZ].T
    return J.reshape((N_STATES, N_STATES) + B)


def outputs(t, x, p=None, u=None):
    """The model's outputs, computed in C: name -> array of shape (*output_shape, *batch)."""
    if u is not None:
        return _numpy("input overrides (u=)").outputs(t, x, p, u)
    B, nb, T, st, X, sx, P, sp = _instances(t, x, p)
    Y = np.empty((nb, max(_C_NOUT, 1)))
    _check(_lib().bgcm_eval_outputs(nb, _ptr(T), st, _ptr(X), sx, _ptr(P), sp, _ptr(Y),
                                    _warm(nb)))
    out, k = {}, 0
    for name, size in zip(OUTPUT_NAMES, _OUT_SIZES):
        out[name] = np.moveaxis(Y[:, k:k + size], 0, 1).reshape(OUTPUT_SHAPES[name] + B)
        k += size
    return out


def _constraint_values(t, x, p=None, u=None):
    """The closed loops' position residuals, velocity residuals and the kinetic energy,
    stacked (2 m + 1, *batch), computed in C (constraint_residuals and kinetic_energy read it)."""
    if u is not None:
        return _numpy("input overrides (u=)")._constraint_values(t, x, p, u)
    B, nb, T, st, X, sx, P, sp = _instances(t, x, p)
    R = np.empty((nb, max(_C_NCONS, 1)))
    _check(_lib().bgcm_eval_cons(nb, _ptr(T), st, _ptr(X), sx, _ptr(P), sp, _ptr(R),
                                 _warm(nb)))
    return np.moveaxis(R[:, :_C_NCONS], 0, 1).reshape((_C_NCONS,) + B)


def initial_state(p=None):
    """The initial state x0 (n, *batch) from the parameters, computed in C."""
    B, nb, T, st, X, sx, P, sp = _instances(0.0, np.zeros(N_STATES), p)
    X0 = np.empty((nb, N_STATES))
    _check(_lib().bgcm_eval_init(nb, _ptr(P), sp, _ptr(X0), _warm(nb)))
    return np.moveaxis(X0, 0, 1).reshape((N_STATES,) + B)


def simulate(t_span, t_eval=None, method="Radau", rtol=1e-6, atol=1e-9, p=None, u=None,
             x0=None, dt=None, breakpoints=(), jac=True, max_step=np.inf, max_steps=50_000,
             stiff_check=True, max_wall=None, h0=0.0, nthreads=None, max_events=20,
             zeno_window=None, check_constraints=True):
    """Integrate over t_span; returns SimResult (t, x, y) as the numpy module's simulate.

    method "Rodas4", "Radau" (Radau IIA of order 5) or "DOP853" (explicit, order 8, for
    non-stiff models): the whole step loop runs in C, one call per run; a batch (parameters or x0 spanning a batch shape) integrates each instance with
    its own step size, spread over nthreads threads (default: every CPU) when the library has
    OpenMP. max_steps counts steps per instance. Other methods, input overrides u and
    jac=False run in the numpy module's Python step loop (with the compiled rhs and Jacobian
    where they apply). Without t_eval and dt the output times are 1001 uniform points
    (the C loop writes output times only, not every step). Statistics in result.stats: nfev,
    njev, nlu, nsteps (accepted steps), nrejected, nstiff, summed over a batch. A hybrid
    model's events are located in C, each instance on its own (result.events, stats["nevents"],
    max_events and zeno_window: as the numpy module's simulate). check_constraints: a given
    x0 of a model with closed loops is checked against their constraints, as the numpy
    module's simulate does.
    """
    _check_start(float(t_span[0]), x0, p, check_constraints)
    if method not in C_METHODS or u is not None or (not jac and method not in _EXPLICIT):
        kw = dict(max_events=max_events, zeno_window=zeno_window) if _N_EV else \
            dict(check_constraints=False)  # checked above
        run = _np_simulate if u is None else _numpy("input overrides (u=)").simulate
        return run(t_span, t_eval=t_eval, method=method, rtol=rtol, atol=atol, p=p,
                            u=u, x0=x0, dt=dt, breakpoints=breakpoints, jac=jac,
                            max_step=max_step, max_steps=max_steps, stiff_check=stiff_check,
                            max_wall=max_wall, **kw)
    t0, t1 = float(t_span[0]), float(t_span[1])
    if not t1 > t0:
        raise ValueError("the C integrators run forward in time: give t_span with t1 > t0")
    x0, batch = _batched(x0, p)
    pv, bshape = _params(p)
    nb = int(np.prod(batch, dtype=int))
    X0 = np.ascontiguousarray(np.moveaxis(np.asarray(x0, dtype=float).reshape(N_STATES, nb), 0, 1))
    P = np.empty((nb, max(_C_NP, 1)))
    for k, v in enumerate(pv):
        P[:, k] = np.broadcast_to(np.asarray(v, dtype=float), batch).reshape(nb)
    times = _output_times(t0, t1, t_eval, dt)
    if times is None:
        times = np.linspace(t0, t1, 1001)
    if N_STATES * nb * times.size > MAX_RESULT_VALUES:
        raise ValueError(f"the result would hold {N_STATES * nb * times.size} values (states x "
                         f"instances x output times), more than the limit of "
                         f"{MAX_RESULT_VALUES}")
    times = np.ascontiguousarray(times, dtype=float)
    a = np.asarray(atol, dtype=float)
    if a.ndim == 0:
        A = np.array([float(a)])
    elif a.shape == (N_STATES,):
        A = np.ascontiguousarray(a)
    else:
        raise ValueError(f"atol: give a scalar or one value per state ({N_STATES}) for the C "
                         "integrators")
    # as the numpy module's simulate: the knots of a table input that is not smooth there
    # (linear, previous) are breakpoints; no step may skip a smooth (pchip) table's knots
    breakpoints = tuple(breakpoints) + tuple(
        k for knots in TABLE_BREAKPOINTS.values() for k in knots)
    max_step = min([max_step] + list(TABLE_MAX_STEP.values()))
    bps = np.array(sorted({float(b) for b in breakpoints if t0 < float(b) < t1}) or [0.0])
    nbps = len(bps) if any(t0 < float(b) < t1 for b in breakpoints) else 0
    Y = np.empty((nb, len(times), N_STATES))
    S = np.zeros((nb, 10))
    msg = _ct.create_string_buffer(256)
    wall = 0.0 if max_wall is None else float(max_wall)
    ms = float(max_step) if np.isfinite(max_step) else 0.0
    threads = int(nthreads or _os.cpu_count() or 1)
    args = (C_METHODS[method], float(rtol), _ptr(A), len(A), float(h0), ms, int(max_steps), wall,
            _ptr(times), len(times), _ptr(bps), nbps, nb, _ptr(P), _ptr(X0), t0, t1, _ptr(Y),
            _ptr(S), msg, threads)
    cap, log = _EV_CAP, None
    while _N_EV:  # the log: nb x cap rows (t, event, x before, x after)
        log, counts = np.zeros((nb, cap, 2 * N_STATES + 2)), np.zeros(nb, dtype=np.intc)
        window = 1e-6 * (t1 - t0) if zeno_window is None else float(zeno_window)
        _lib().bgcm_simulate(*args, _ptr(log), cap, _ptr(counts), int(max_events), window)
        if counts.max(initial=0) <= cap:
            break
        cap = int(counts.max())
    if not _N_EV:
        _lib().bgcm_simulate(*args)
    stats = {"nfev": int(S[:, 3].sum()), "njev": int(S[:, 4].sum()), "nlu": int(S[:, 5].sum()),
             "nsteps": int(S[:, 1].sum()), "nrejected": int(S[:, 2].sum()), "nstiff": 0}
    if _N_EV:
        stats["nevents"] = int(counts.sum())
    failed = np.nonzero(S[:, 6])[0]
    if failed.size:
        k = int(failed[0])
        if int(S[k, 6]) == 6 and int(S[k, 9]) == 2 and \
                _lib().bgcm_fail_is_value_error(int(S[k, 8])):  # a table input, as numpy says
            raise ValueError(_c_message(method, S, failed, msg.value, batch, max_steps))
        raise _error(SimulationError, _c_message(method, S, failed, msg.value, batch, max_steps),
                     float(S[failed[0], 7]), stats)
    X = Y.transpose(2, 0, 1).reshape((N_STATES,) + batch + (len(times),))
    pt = None if p is None else {
        name: np.asarray(v)[..., None] if np.ndim(v) > _PARAM_NDIM[name] else v
        for name, v in p.items()}
    res = SimResult(times, X, outputs(times, X, pt), stats)
    if _N_EV:
        res.events = _event_log(log, counts, batch)
    return res


def _event_log(log, counts, batch):
    """(t, event name, instance index, x before, x after) of every instance, in time order."""
    rows = []
    for k in range(len(counts)):
        index = tuple(int(i) for i in np.unravel_index(k, batch)) if batch else ()
        for r in log[k, :counts[k]]:
            rows.append((r[0], EVENT_NAMES[int(r[1])], index, r[2:2 + N_STATES].copy(),
                         r[2 + N_STATES:].copy()))
    rows.sort(key=lambda row: (row[0], row[2]))
    return rows


def _c_message(method, S, failed, raw, batch, max_steps=0):
    """The located diagnostic of the first failed instance: state name and time, as the numpy
    module gives them."""
    k = int(failed[0])
    status, t, bad, where = int(S[k, 6]), float(S[k, 7]), int(S[k, 8]), int(S[k, 9])
    inst = ""
    if batch:
        inst = (f" (batch instance {tuple(int(i) for i in np.unravel_index(k, batch))}, "
                f"{failed.size} of {S.shape[0]} failed)")
    if status == 1 and 0 <= bad < N_STATES:
        what = "right-hand side" if where == 0 else "Jacobian row"
        return (f"{method} failed at t = {t:.6g}: non-finite value in the {what} of state "
                f"{STATE_NAMES[bad]!r}{inst}")
    if status == 8 and 0 <= bad < _N_EV:  # the Zeno guard: located at the event
        rest = raw.decode("utf-8", "replace").split(": ", 1)[-1]
        return (f"{EVENT_WHERE[bad]}: event {EVENT_NAMES[bad]!r} at t = {t:.9g}: {rest}; raise "
                f"max_events or change the model{inst}")
    if status == 2:  # max_steps: the numpy module's words (its plain and events paths)
        return (f"{method} stopped at t = {t:.17g}: max_steps = {int(max_steps)} steps (raise "
                f"the scene's solver max_steps or --max-steps){inst}")
    if status == 6 and where == 2 and bad > 0:  # a numeric solve failed: located first
        return f"{_fail_message(bad)} ({method}, at t = {t:.6g}){inst}"
    detail = raw.decode("utf-8", "replace") or _C_STATUS.get(status, f"status {status}")
    return f"{method} failed at t = {t:.6g}: {detail}{inst}"


def _autobind():
    """Bind the library beside this module's file, when imported from a folder that holds it."""
    here = globals().get("__file__")
    if here and _os.path.isfile(here):
        path = _os.path.join(_os.path.dirname(_os.path.abspath(here)), C_LIBRARY)
        if _os.path.isfile(path):
            _bind(path)


_autobind()
