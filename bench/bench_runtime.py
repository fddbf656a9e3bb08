"""The generated simulate() (an explicit OdeSolver step loop) against the solve_ivp path it
replaced, side by side in one process, on a scene as `bgc simulate` runs it.

    python bench/bench_runtime.py [--scene models/scenes/3r2s_circle.yaml] [--repeats 5]

Both paths integrate the same compiled module with the scene's settings, alternately, and
share one instrumentation: the time spent inside the model's rhs and jacobian is subtracted
from the wall time to give the runtime's own overhead. Compare the ratios (shared machines
are noisy).
"""
from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def legacy_simulate(mod, t_span, t_eval=None, method="Radau", rtol=1e-6, atol=1e-9, p=None,
                    u=None, dt=None, breakpoints=(), jac=True, max_step=np.inf):
    """The generated simulate() before the step loop (bgc 2e125ca): solve_ivp per segment."""
    import scipy.sparse as sps
    from scipy.integrate import solve_ivp

    n = mod.N_STATES
    _pv, bshape = mod._params(p)
    x0 = mod.initial_state(p)
    batch = np.broadcast_shapes(x0.shape[1:], bshape)
    x0 = np.broadcast_to(x0.reshape(x0.shape + (1,) * (len(batch) - x0.ndim + 1)), (n,) + batch)
    nb = int(np.prod(batch)) if batch else 1
    t0, t1 = float(t_span[0]), float(t_span[1])
    if t_eval is None and dt is not None:
        t_eval = np.linspace(t0, t1, int(round((t1 - t0) / dt)) + 1)
    stats = {"nfev": 0, "njev": 0, "nlu": 0}  # solve_ivp does not report accepted steps

    def f(t, y):
        stats["nfev"] += 1
        return mod.rhs(t, y.reshape((n,) + batch + y.shape[1:]), p, u).reshape(y.shape)

    rows, cols = np.nonzero(mod.JAC_SPARSITY)
    if nb > 1:
        b = np.arange(nb)
        R = (rows[:, None] * nb + b).ravel()
        C = (cols[:, None] * nb + b).ravel()
    kwargs = {}
    if method in ("Radau", "BDF", "LSODA") and jac:
        def jfun(t, y):
            J = mod.jacobian(t, y.reshape((n,) + batch), p, u)
            if nb == 1:
                return J.reshape(n, n)
            vals = J.reshape(n, n, nb)[rows, cols].ravel()
            return sps.csc_matrix((vals, (R, C)), shape=(n * nb, n * nb))
        kwargs["jac"] = jfun
    cuts = [t0] + sorted(float(b) for b in breakpoints if t0 < float(b) < t1) + [t1]
    ts, ys = [], []
    y = np.array(x0, dtype=float).reshape(-1)
    for k, (a, c) in enumerate(zip(cuts[:-1], cuts[1:])):
        last = k == len(cuts) - 2
        want = np.asarray(t_eval, dtype=float)
        want = want[(want >= a) & ((want <= c) if last else (want < c))]
        sol = solve_ivp(f, (a, c), y, method=method, t_eval=np.union1d(want, [c]), rtol=rtol,
                        atol=atol, max_step=max_step, **kwargs)
        if sol.status < 0:
            raise RuntimeError(f"{method} failed at t = {sol.t[-1]:.6g}: {sol.message}")
        stats["njev"] += int(sol.njev)
        stats["nlu"] += int(sol.nlu)
        mask = np.isin(sol.t, want)
        ts.append(sol.t[mask])
        ys.append(sol.y[:, mask])
        y = sol.y[:, -1]
    t = np.concatenate(ts)
    X = np.concatenate(ys, axis=1).reshape((n,) + batch + (len(t),))
    return t, X, mod.outputs(t, X, p, u), stats


class ModelClock:
    """Time spent inside the module's rhs and jacobian (wraps them in place)."""

    def __init__(self, mod):
        self.spent = 0.0
        for name in ("rhs", "jacobian"):
            setattr(mod, name, self._timed(getattr(mod, name)))

    def _timed(self, fn):
        def wrapper(*a, **k):
            t0 = time.perf_counter()
            try:
                return fn(*a, **k)
            finally:
                self.spent += time.perf_counter() - t0
        return wrapper


def compare(mod, clock, span, kw, repeats):
    """Median wall time and time outside the model of each path, alternating calls."""
    runs = {"solve_ivp (old)": lambda: legacy_simulate(mod, span, **kw)[3],
            "step loop (new)": lambda: mod.simulate(span, **kw).stats}
    walls = {k: [] for k in runs}
    outside = {k: [] for k in runs}
    stats = {}
    for _ in range(repeats):
        for name, run in runs.items():  # alternate, so drifts in machine load hit both
            clock.spent = 0.0
            t0 = time.perf_counter()
            stats[name] = run()
            walls[name].append(time.perf_counter() - t0)
            outside[name].append(walls[name][-1] - clock.spent)
    return {k: (statistics.median(walls[k]), statistics.median(outside[k]), stats[k])
            for k in runs}


def report(title, res):
    print(f"\n{title}\n")
    print("| path | wall [s] | outside rhs/jacobian [s] | steps | rhs calls | Jacobians | LU |")
    print("|---|---|---|---|---|---|---|")
    for k, (wall, outside, s) in res.items():
        print(f"| {k} | {wall:.4g} | {outside:.4g} | {s.get('nsteps', '')} | {s['nfev']} | "
              f"{s['njev']} | {s['nlu']} |")
    (w0, o0, s0), (w1, o1, s1) = res.values()
    print(f"\nratio new/old: wall {w1 / w0:.3f}; outside the model {o1 / o0:.3f}; outside the "
          f"model per rhs call {(o1 / s1['nfev']) / (o0 / s0['nfev']):.3f}")


def main():
    from bgc.format.scene import free_values, parse_scene
    from bgc.run.runner import compile_scene

    ap = argparse.ArgumentParser()
    ap.add_argument("--scene", default=str(ROOT / "models" / "scenes" / "3r2s_circle.yaml"))
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--short", type=float, default=1e-3,
                    help="span [s] of the short runs that expose the fixed cost of a call")
    args = ap.parse_args()
    sc = parse_scene(args.scene)
    _, mod = compile_scene(sc)
    clock = ModelClock(mod)
    # exactly the call bgc simulate makes (runner.run_scene)
    kw = dict(dt=sc.dt or (sc.t_span[1] - sc.t_span[0]) / 1000, method=sc.method, rtol=sc.rtol,
              atol=sc.atol, p=free_values(sc) or None, breakpoints=sc.breakpoints,
              max_step=sc.max_step)
    print(f"{Path(args.scene).name}: {mod.N_STATES} states, {sc.method} rtol {sc.rtol:g} "
          f"atol {sc.atol:g}; medians of alternating runs")
    report(f"The whole scene, t = {sc.t_span[0]:g}..{sc.t_span[1]:g} s ({args.repeats} runs "
           "each)", compare(mod, clock, sc.t_span, kw, args.repeats))
    t0 = sc.t_span[0]
    short = dict(kw, dt=args.short / 10)
    report(f"The first {args.short:g} s only: the fixed cost of a call ({20 * args.repeats} runs "
           "each)", compare(mod, clock, (t0, t0 + args.short), short, 20 * args.repeats))


if __name__ == "__main__":
    main()
