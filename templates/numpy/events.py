"""bgc's numpy runtime for hybrid models: event location and the step loop that stops at events.

Everything below the marker line is copied, after the runtime (templates/numpy/runtime.py),
into the module of a model with events only; its ``simulate`` takes the place of the runtime's.
A model without events never contains it, so its module is what it was before events existed.

After every accepted step the guards g(t, x, u, p) of every event and every instance of a
batch are evaluated at the step's end. An event whose guard changed sign in its direction is
located on the step's dense output (Radau's collocation polynomial, Rodas4's interpolant, the
explicit methods' interpolants) by the Illinois variant of regula falsi, each instance on its
own, to a bracket of a few ulp of t. The earliest such time in the batch stops the step: the
output times up to it are read off the dense output, the instances whose events fired there get
the events' resets (in declaration order), and a fresh solver (a fresh Jacobian and LU) starts
from the state just after. Each event is logged with the states before and after.

A time event (``at``, ``every``; its guard is t minus its time) is not searched for: each
solver's end is the next time event's time (t - guard at the solver's start), a breakpoint the
solver lands on exactly, and the event fires there.
"""
# flake8: noqa: F821
from __future__ import annotations

import numpy as np

N_STATES: int
N_EVENTS: int
EVENT_NAMES: tuple
EVENT_DIRECTIONS: tuple
EVENT_TIMED: tuple
EVENT_WHERE: tuple
TABLE_BREAKPOINTS: dict
TABLE_MAX_STEP: dict
_PARAM_NDIM: dict
METHODS: tuple
event_values = apply_event = outputs = _params = _batched = _flat_atol = None
_Trajectory = _output_times = _segments = _one_sided = _flat_rhs = _counts = None
_jacobian_options = _rodas_class = _error = _nonfinite = None
SimulationError = SimResult = None

# ==== bgc numpy events runtime: copied below this line ====
# --------------------------------------------------------------------------------------------
# Events (hybrid models): location on the dense output, resets, restarts, the Zeno guard.
_EVENT_ITERATIONS = 200  # root-finder iterations per event (the bracket halves at least every 2)


class _StepEnd:
    """What _Trajectory.add reads of a solver, for a step cut short at an event at time t."""

    def __init__(self, t, y, dense):
        self.t, self.y, self._dense = t, y, dense

    def dense_output(self):
        return self._dense


class _Guards:
    """The events' guards on the solver's flat state, and the side of zero each was last on
    (per event and instance): a guard that reaches zero stays on its former side until it
    leaves zero, so touching zero is one crossing, not two. A guard zero where the run starts
    counts as before its event (a rising one as negative), an either one as on no side."""

    def __init__(self, at, shape, p, u):
        self.at, self.shape, self.p, self.u = at, shape, p, u
        self.nb = int(np.prod(shape[1:]))
        self.dirs = np.asarray(EVENT_DIRECTIONS, dtype=float)[:, None]
        self.timed = np.asarray(EVENT_TIMED, dtype=bool)[:, None]
        # a guard that starts at zero is taken to be before its event (rising: below zero)
        self.side = np.broadcast_to(-self.dirs, (N_EVENTS, self.nb)).copy()

    def values(self, t, y):
        """(N_EVENTS, nb) guard values at time t of the flat state y."""
        g = event_values(self.at(t), y.reshape(self.shape), self.p, self.u)
        return np.broadcast_to(g, (N_EVENTS,) + self.shape[1:]).reshape(N_EVENTS, self.nb)

    def start(self, t, y):
        """The guards where a solver starts: their sides, where they are not zero."""
        g = self.values(t, y)
        self.side = np.where(g != 0, np.sign(g), self.side)

    def crossed(self, g_new):
        """(events, instances) whose guard left its side in the event's direction by the step's
        end; the sides move on for every guard that left zero."""
        s = self.side
        left = (s != 0) & (np.sign(g_new) != s)
        fire = left & ((self.dirs == 0) | (self.dirs == -s)) & ~self.timed
        self.side = np.where(left & ~fire & (g_new != 0), np.sign(g_new), s)
        return np.argwhere(fire)


def _locate(guards, dense, k, i, ta, tb, side):
    """Where guard k of instance i leaves ``side`` in (ta, tb] of the step's dense output, by
    the Illinois variant of regula falsi (a bisection whenever three iterations did not halve
    the bracket): (t_before, t_after), a bracket a few ulp wide, or the guard zero at t_after."""
    g = lambda t: side * guards.values(t, dense(t))[k, i]  # noqa: E731  (> 0 before the event)
    ga, gb = max(g(ta), np.finfo(float).tiny), g(tb)
    if gb > 0:  # the dense output's end disagrees with the step's end: the event is at the end
        return tb, tb
    stale, width = 0, abs(tb - ta)
    for it in range(_EVENT_ITERATIONS):
        if abs(tb - ta) <= 4 * np.finfo(float).eps * max(1.0, abs(ta), abs(tb)) or gb == 0:
            break
        tm = ta + (tb - ta) * (ga / (ga - gb))
        if it % 3 == 2:
            if abs(tb - ta) > width / 2:
                tm = 0.5 * (ta + tb)
            width = abs(tb - ta)
        if not min(ta, tb) < tm < max(ta, tb):
            tm = 0.5 * (ta + tb)
        gm = g(tm)
        if gm > 0:
            ta, ga = tm, gm
            gb, stale = (gb / 2 if stale == 1 else gb), 1
        else:
            tb, gb = tm, gm
            ga, stale = (ga / 2 if stale == -1 else ga), -1
    if gb == 0:  # an exact zero (a guard linear in t): the bracket is that time alone, so that
        ta = tb  # _fire does not take an event that a wide bracket's start puts before t_stop
    return ta, tb


class _EventLog:
    """The events so far: (t, name, instance index, x before, x after), and the Zeno guard: at
    most max_events events of one instance within zeno_window seconds."""

    def __init__(self, shape, max_events, window):
        self.shape, self.max_events, self.window = shape, max_events, window
        self.records, self.recent = [], {}

    def add(self, t, k, i, before, after, stats):
        index = np.unravel_index(i, self.shape[1:]) if len(self.shape) > 1 else ()
        self.records.append((t, EVENT_NAMES[k], tuple(int(j) for j in index),
                             before.copy(), after.copy()))
        stats["nevents"] += 1
        times = self.recent.setdefault(i, [])
        times.append(t)
        if len(times) > self.max_events:
            del times[0]
            if abs(times[-1] - times[0]) <= self.window:
                where = f" of instance {tuple(int(j) for j in index)}" if index else ""
                raise _error(SimulationError, f"{EVENT_WHERE[k]}: event {EVENT_NAMES[k]!r} at "
                             f"t = {t:.9g}: {self.max_events + 1} events{where} within "
                             f"{abs(times[-1] - times[0]):.3g} s (Zeno behaviour or "
                             "chattering; raise max_events or change the model)", t, stats)


def _fire(guards, solver, hits, log, stats):
    """Locate the crossings of one step, stop at the earliest and apply the events that fire
    there: (t, y after) where the solver must restart, or None when nothing fired."""
    dense, d = solver.dense_output(), solver.direction
    found = []
    for k, i in hits:  # the side each guard leaves: never 0 (see _Guards.crossed)
        ta, tb = _locate(guards, dense, k, i, solver.t_old, solver.t, guards.side[k, i])
        found.append((tb, ta, int(k), int(i)))
    t_stop = min((f[0] for f in found), key=lambda t: d * t)
    tol = 8 * np.finfo(float).eps * max(1.0, abs(t_stop))
    now = sorted((f for f in found if d * (f[1] - t_stop) <= tol), key=lambda f: (f[3], f[2]))
    y_before = dense(t_stop) if t_stop != solver.t else solver.y.copy()
    y = y_before.reshape(guards.shape[0], guards.nb).copy()
    for _, _, k, i in now:
        x_i = y[:, i].copy()
        p_i = _instance_params(guards.p, guards.shape, i)
        y[:, i] = np.asarray(apply_event(k, guards.at(t_stop), x_i, p_i, guards.u),
                             dtype=float).reshape(-1)
        guards.side[k, i] = -guards.side[k, i]  # crossed: the guard is on its new side
        log.add(t_stop, k, i, x_i, y[:, i], stats)
    return t_stop, y_before, y.reshape(-1)


def _next_time(guards, t, y, c, first):
    """The solver's end from t: the earliest time event in (t, c] (at the run's first start,
    [t, c]) over the instances, else c; and the (event, instance) pairs due there."""
    if not guards.timed.any():
        return c, []
    tau = t - guards.values(t, y)  # a time event's guard is t - its time
    tol = 4 * np.finfo(float).eps * max(1.0, abs(t), abs(c))
    ahead = guards.timed & ((tau >= t) if first else (tau > t + tol)) & (tau <= c)
    if not ahead.any():
        return c, []
    end = float(np.min(tau[ahead]))
    end = c if c - end <= tol else end
    return end, [tuple(ki) for ki in np.argwhere(ahead & (tau <= end + tol))]


def _fire_timed(guards, t, y, due, log, stats):
    """The time events due at t (the solver's end): their resets, in declaration order."""
    y = y.reshape(guards.shape[0], guards.nb).copy()
    for k, i in sorted(due, key=lambda ki: (ki[1], ki[0])):
        x_i = y[:, i].copy()
        p_i = _instance_params(guards.p, guards.shape, i)
        y[:, i] = np.asarray(apply_event(k, guards.at(t), x_i, p_i, guards.u),
                             dtype=float).reshape(-1)
        log.add(t, k, i, x_i, y[:, i], stats)
    return y.reshape(-1)


def _instance_params(p, shape, i):
    """The unpacked parameters of instance i of the batch (flat index)."""
    vals, bshape = p
    if not bshape:
        return p
    index = np.unravel_index(i, shape[1:])
    pick = lambda v: np.broadcast_to(v, shape[1:])[index] if np.ndim(v) else v  # noqa: E731
    return type(p)((tuple(pick(v) for v in vals), ()))


def simulate(t_span, t_eval=None, method="Radau", rtol=1e-6, atol=1e-9, p=None, u=None,
             x0=None, dt=None, breakpoints=(), jac=True, max_step=np.inf, max_steps=50_000,
             stiff_check=True, max_wall=None, max_events=20, zeno_window=None,
             batch_events="own"):
    """Integrate a hybrid model over t_span, stopping at its events; returns SimResult (t, x, y)
    with .events, the event log: (t, event name, instance index in the batch, x before, x after)
    in the order they happened, and stats["nevents"].

    A batch (parameters or x0 spanning instances): with batch_events="own" (the default) and
    output times (t_eval or dt), each instance is integrated on its own, with its own steps,
    events and restarts, so that it is exactly its single run; with "shared" (or without
    output times) one solver advances the whole batch and every instance restarts at any
    instance's event (only those whose events fired are reset): vectorised, but each instance's
    steps are the batch's.

    The arguments are the runtime's simulate's (stiff_check is not used: a hybrid model's
    explicit methods are not watched for stiffness), plus the Zeno guard: SimulationError
    (naming the event and the time) when one instance has more than max_events events within
    zeno_window seconds (default 1e-6 of the span). Output times exactly at an event show the
    state just before it; without output times the event time appears twice, before and after.
    """
    import time

    import scipy.integrate

    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}: one of {', '.join(METHODS)}")
    with np.errstate(all="ignore"):
        deadline = np.inf if max_wall is None else time.perf_counter() + max_wall
        x0, batch = _batched(x0, p)
        if batch_events not in ("own", "shared"):
            raise ValueError(f"batch_events {batch_events!r}: 'own' or 'shared'")
        if batch and batch_events == "own" and (t_eval is not None or dt is not None):
            return _separately(dict(t_span=t_span, t_eval=t_eval, method=method, rtol=rtol,
                                    u=u, dt=dt, breakpoints=breakpoints, jac=jac,
                                    max_step=max_step, max_steps=max_steps,
                                    max_events=max_events, zeno_window=zeno_window),
                               x0, batch, p, atol, deadline)
        p_raw, p = p, _params(p)
        shape = (N_STATES,) + batch
        y = np.array(x0, dtype=float).reshape(-1)
        stats = {"nfev": 0, "njev": 0, "nlu": 0, "nsteps": 0, "nstiff": 0, "nevents": 0}
        if not np.isfinite(y).all():
            raise _nonfinite(method, "initial state", float(t_span[0]), y, y, shape, stats)
        atol = _flat_atol(atol, batch)
        t0, t1 = float(t_span[0]), float(t_span[1])
        path = _Trajectory(t0, t1, y, _output_times(t0, t1, t_eval, dt))
        breakpoints = tuple(breakpoints) + tuple(
            k for name, knots in TABLE_BREAKPOINTS.items() if u is None or name not in u
            for k in knots)
        max_step = min([max_step] + [h for name, h in TABLE_MAX_STEP.items()
                                     if u is None or name not in u])
        log = _EventLog(shape, max_events,
                        1e-6 * abs(t1 - t0) if zeno_window is None else zeno_window)
        solver_class = _rodas_class() if method == "Rodas4" else getattr(scipy.integrate, method)
        for a, c in _segments(t0, t1, breakpoints):
            at = _one_sided(a, c)
            guards = _Guards(at, shape, p, u)
            start = a
            while start < c:  # one solver from each restart to the next time event or the end
                guards.start(start, y)
                end, due = _next_time(guards, start, y, c, start == t0)
                if end == start:  # time events at the run's very start
                    y = _fire_timed(guards, start, y, due, log, stats)
                    end, due = _next_time(guards, start, y, c, False)
                solver = solver_class(
                    _flat_rhs(at, shape, p, u, stats, method), start, y, end, rtol=rtol,
                    atol=atol, max_step=max_step,
                    **_jacobian_options(method, jac, at, shape, p, u, stats))
                stop = _run_to_event(solver, guards, path, log, stats, method, deadline,
                                     max_wall, max_steps)
                stats.update(_counts(stats, solver))
                if stop is not None:
                    start, y = stop
                    continue
                start, y = end, solver.y
                if due:
                    y = _fire_timed(guards, end, y, due, log, stats)
                    if path.times is None:  # every step: the event's time twice
                        path.ts.append(end)
                        path.ys.append(y.copy())
                elif end != c:
                    raise _error(SimulationError, f"internal: a solver ended at t = {end:.17g} "
                                 "without a time event", end, stats)
        t, X = path.arrays()
        return _result(t, X.reshape(shape + (len(t),)), p_raw, u, stats, log.records)


def _result(t, X, p_raw, u, stats, records):
    pt = None if p_raw is None else {
        name: np.asarray(v)[..., None] if np.ndim(v) > _PARAM_NDIM[name] else v
        for name, v in p_raw.items()}
    res = SimResult(t, X, outputs(t, X, pt, u), stats)
    res.events = records
    return res


def _separately(kw, x0, batch, p_raw, atol, deadline):
    """A batch run instance by instance (batch_events="own"): each its own solver, steps,
    events and restarts; the results stacked as one batch, the event logs merged in time."""
    import time

    X, records, stats, t = None, [], {}, None
    atol = np.asarray(atol, dtype=float)
    for index in np.ndindex(*batch):
        p_i = None if p_raw is None else {
            name: np.broadcast_to(np.asarray(v), batch + np.shape(v)[np.ndim(v) - _PARAM_NDIM[
                name]:])[index] if np.ndim(v) > _PARAM_NDIM[name] else v
            for name, v in p_raw.items()}
        atol_i = atol if atol.ndim < 2 else np.broadcast_to(
            atol.reshape(atol.shape + (1,) * (len(batch) + 1 - atol.ndim)),
            (N_STATES,) + batch)[(slice(None),) + index]
        wall = None if deadline == np.inf else max(deadline - time.perf_counter(), 0.0)
        r = simulate(x0=np.array(x0[(slice(None),) + index]), p=p_i, atol=atol_i,
                     max_wall=wall, batch_events="own", **kw)
        if X is None:
            t, X = r.t, np.empty((N_STATES,) + batch + (len(r.t),))
        X[(slice(None),) + index] = r.x
        records += [(te, name, tuple(int(j) for j in index), xb, xa)
                    for te, name, _, xb, xa in r.events]
        for key, v in r.stats.items():
            stats[key] = stats.get(key, 0) + v
    records.sort(key=lambda rec: (rec[0], rec[2]))
    return _result(t, X, p_raw, kw["u"], stats, records)


def _run_to_event(solver, guards, path, log, stats, method, deadline, max_wall, max_steps):
    """Step the solver to its end, or to the first event: (t, state after the event) to restart
    from, or None at the end. max_steps bounds the steps of the whole run (stats["nsteps"]
    counts them over every restart), as the plain path's step loop does."""
    import time

    while solver.status == "running":
        if stats["nsteps"] >= max_steps:  # as the plain path and the C step loop
            raise _error(SimulationError, f"{method} stopped at t = {solver.t:.17g}: "
                         f"max_steps = {max_steps} steps (raise the scene's solver "
                         "max_steps or --max-steps)", solver.t, _counts(stats, solver))
        message = solver.step()
        if solver.status == "failed":
            raise _error(SimulationError, f"{method} failed at t = {solver.t:.6g}: "
                         f"{message}", solver.t, _counts(stats, solver))
        stats["nsteps"] += 1
        hits = guards.crossed(guards.values(solver.t, solver.y))
        if len(hits):
            t_stop, y_before, y_after = _fire(guards, solver, hits, log, stats)
            path.add(_StepEnd(t_stop, y_before, solver.dense_output()))
            if path.times is None:  # every step: the event's time twice, before and after
                path.ts.append(t_stop)
                path.ys.append(y_after.copy())
            return t_stop, y_after
        path.add(solver)
        if time.perf_counter() > deadline:
            raise _error(SimulationError, f"{method} stopped at t = {solver.t:.6g}: the "
                         f"wall time exceeded max_wall = {max_wall:g} s", solver.t,
                         _counts(stats, solver))
    return None
