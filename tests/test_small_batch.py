"""Small batches in the numpy runtime: below SMALL_BATCH the solver-facing wrappers evaluate a
batch instance by instance through the single-instance path (templates/numpy/runtime.py).

The references are outside the loop: the vectorised path on the same values (the same
arithmetic per instance, so equal bit for bit), single runs of each instance on their own,
an independent scipy model of the mass-spring-damper and the bouncing ball's closed form.
"""
from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

#: the loop on for any size and any function (a model under the rule's size still loops)
ALWAYS = {"SMALL_BATCH": {"rhs": (10**6, 10**6), "jacobian": (10**6, 10**6)},
          "SMALL_BATCH_MIN_LOCALS": 0, "SMALL_BATCH_SOLVES": 10**6}
#: the loop off: the vectorised path everywhere (the runtime before the loop)
NEVER = {"SMALL_BATCH": {"rhs": (0, 0), "jacobian": (0, 0)}}


def _set(monkeypatch, mod, limits):
    for name, value in limits.items():
        monkeypatch.setattr(mod, name, value)


def _spy(monkeypatch, mod):
    """Count the loop's calls (the wrappers look _each up in the module)."""
    calls = {"rhs": 0, "jacobian": 0}
    each = mod._each

    def counted(name, *args):
        calls[name] += 1
        return each(name, *args)

    monkeypatch.setattr(mod, "_each", counted)
    return calls


def _variants(mod, shape, rng):
    """Per-instance parameters (every scalar parameter scaled by 0.9-1.1) and states near
    their initial states, of batch shape ``shape``."""
    p = {k: v * rng.uniform(0.9, 1.1, shape) for k, v in mod.PARAM_DEFAULTS.items()
         if np.ndim(v) == 0}
    x0 = np.broadcast_to(np.asarray(mod.initial_state(p), dtype=float),
                         (mod.N_STATES,) + shape)
    x = x0 * (1 + 0.05 * rng.standard_normal(x0.shape)) + 0.01 * rng.standard_normal(x0.shape)
    return p, x


@pytest.mark.parametrize("name", ["msd", "quarter_car", "top", "double_pendulum_rigid",
                                  "fourbar_rigid", "mech3r2s"])
@pytest.mark.parametrize("shape", [(3,), (2, 3)])
def test_loop_and_vectorised_paths_give_the_same_values(gen, name, shape):
    mod = gen(name)
    rng = np.random.default_rng(7)
    p, x = _variants(mod, shape, rng)
    pu = mod._params(p)
    # a time-dependent override of a scalar input that differs per instance
    scalar = [k for k in mod.INPUT_NAMES if mod.INPUT_LABELS.count(k)]
    amp = rng.uniform(0.5, 1.5, shape)
    for u in [None] + ([{scalar[0]: lambda t: amp * np.sin(3 * t)}] if scalar else []):
        for fn in ("rhs", "jacobian"):
            vec = np.asarray(getattr(mod, fn)(0.4, x, pu, u))
            loop = mod._each(fn, 0.4, x.ravel(), x.shape, pu, u)
            assert loop.shape == vec.shape[:-len(shape)] + (int(np.prod(shape)),)
            assert np.array_equal(loop, vec.reshape(loop.shape)), (name, fn, u is None)
            # and each instance is its own single-instance call
            k = int(np.prod(shape)) - 1
            idx = np.unravel_index(k, shape)
            p_k = {q: float(v[idx]) for q, v in p.items()}
            u_k = None if u is None else {scalar[0]: lambda t: float(amp[idx]) * np.sin(3 * t)}
            one = getattr(mod, fn)(0.4, x[(slice(None),) + idx], p_k, u_k)
            assert np.array_equal(loop[..., k], one)


def test_the_rule_loops_large_functions_below_their_limits_only(gen, monkeypatch):
    big, small, newton = gen("mech3r2s"), gen("msd"), gen("rectifier")
    for fn in ("rhs", "jacobian"):
        limit = big._loop_limit(fn)
        assert limit > 3 and big._looped(fn, 2) and big._looped(fn, limit - 1)
        assert not big._looped(fn, limit) and not big._looped(fn, 1)  # 1: the single path
    # the 3R2S's functions are larger than the double pendulum's: their loops pay longer
    pend = gen("double_pendulum_rigid")
    assert big._loop_limit("rhs") > pend._loop_limit("rhs") > 2
    assert not small._looped("rhs", 2)  # a small function: overhead, never looped
    # a nonlinear loop's Newton starts warm from the last call: never looped
    assert not newton._LOOPABLE and not newton._looped("rhs", 2)
    # a function that solves linear systems loops for 2 instances only
    four = gen("fourbar_rigid")
    assert four._looped("jacobian", 2) and not four._looped("jacobian", 3)
    # a replaced rhs (as a C wrapper's binding replaces it) is never looped
    monkeypatch.setattr(big, "rhs", lambda t, x, p=None, u=None: big._OWN["rhs"](t, x, p, u))
    assert not big._looped("rhs", 2)


def _dp_runs(mod, p, u, kw):
    return mod.simulate((0.0, 1.0), p=p, u=u, **kw)


def _torque(amp):
    """A torque override per instance, amp cos(3 t): (nb,) at one time, (nb, T) at T times
    (the outputs' call)."""
    return lambda t: (amp * np.cos(3 * t) if np.ndim(t) == 0 else
                      np.multiply.outer(amp, np.cos(3 * np.asarray(t))))


@pytest.mark.parametrize("nb", [3, 7])  # below both limits, at or above both
@pytest.mark.parametrize("override", [False, True])
def test_batch_equals_single_runs_with_inputs(gen, monkeypatch, nb, override):
    """The rigid double pendulum (large rhs and Jacobian: the rule loops them), each instance
    with its own masses, lengths and torque amplitude; its input is a torque in t (the
    default tau0 sin(2t), or an override that differs per instance)."""
    mod = gen("double_pendulum_rigid")
    assert mod._looped("rhs", 3) and mod._looped("jacobian", 3)
    assert not mod._looped("rhs", 7) and not mod._looped("jacobian", 7)
    rng = np.random.default_rng(11)
    p = {k: mod.PARAM_DEFAULTS[k] * rng.uniform(0.8, 1.2, nb)
         for k in ("m1", "m2", "l1", "l2", "tau0")}
    amp = rng.uniform(0.1, 0.4, nb)
    u = {"tau": _torque(amp)} if override else None
    kw = dict(method="Radau", rtol=1e-8, atol=1e-10, dt=0.05)
    calls = _spy(monkeypatch, mod)
    r = _dp_runs(mod, p, u, kw)
    assert (calls["rhs"] > 0) == (nb == 3) and (calls["jacobian"] > 0) == (nb == 3)
    # the other path gives the same trajectory bit for bit (same arithmetic, same steps)
    _set(monkeypatch, mod, ALWAYS if nb == 7 else NEVER)
    other = _dp_runs(mod, p, u, kw)
    assert np.array_equal(r.x, other.x) and r.stats == other.stats
    # each instance alone (its own steps): equal to the solver's accuracy
    for i in range(nb):
        p_i = {k: float(v[i]) for k, v in p.items()}
        u_i = {"tau": _torque(float(amp[i]))} if override else None
        one = _dp_runs(mod, p_i, u_i, kw)
        err = np.max(np.abs(r.x[:, i] - one.x))
        assert err < 2e-6, (i, err)
    # the instances differ far beyond that
    assert np.ptp(r.x[2, :, -1]) > 1e-2


def test_msd_batch_with_a_per_instance_input_matches_an_independent_model(gen, monkeypatch):
    """m q'' + c q' + k q = F(t), F a different sine per instance: the loop (forced on: msd's
    rhs is under the rule's size) and the vectorised path against scipy on the hand-written
    equations."""
    mod = gen("msd")
    nb = 4
    rng = np.random.default_rng(5)
    p = {"m": rng.uniform(1.0, 3.0, nb), "k": rng.uniform(100.0, 300.0, nb),
         "c": rng.uniform(1.0, 6.0, nb)}
    amp, w = rng.uniform(5.0, 15.0, nb), rng.uniform(3.0, 12.0, nb)
    u = {"F": lambda t: amp * np.sin(w * t)}
    kw = dict(method="Radau", rtol=1e-10, atol=1e-12, dt=0.01, u=u, p=p)
    runs = {}
    for label, limits in (("loop", ALWAYS), ("vectorised", NEVER)):
        _set(monkeypatch, mod, limits)
        calls = _spy(monkeypatch, mod)
        runs[label] = mod.simulate((0.0, 1.5), **kw)
        assert (calls["rhs"] > 0) == (label == "loop")
    assert np.array_equal(runs["loop"].x, runs["vectorised"].x)
    t = runs["loop"].t
    for i in range(nb):
        m, k, c = p["m"][i], p["k"][i], p["c"][i]

        def f(s, z, m=m, k=k, c=c, a=amp[i], om=w[i]):  # z = (momentum, displacement)
            return [a * np.sin(om * s) - k * z[1] - c * z[0] / m, z[0] / m]

        ref = solve_ivp(f, (0.0, 1.5), [0.0, 0.0], method="DOP853", t_eval=t, rtol=1e-12,
                        atol=1e-14)
        assert ref.success
        # displacement amplitudes about F/k ~ 0.05 m
        np.testing.assert_allclose(runs["loop"].x[:, i], ref.y, rtol=0, atol=1e-8)


def test_params_are_split_once_per_run(gen, monkeypatch):
    mod = gen("mech3r2s")
    builds = []
    split = mod._split_params

    def counted(p, batch):
        out = split(p, batch)
        if not builds or builds[-1] is not out:
            builds.append(out)
        return out

    monkeypatch.setattr(mod, "_split_params", counted)
    p = {"m1": mod.PARAM_DEFAULTS["m1"] * np.array([0.9, 1.1])}
    r = mod.simulate((0.0, 0.002), p=p, method="Radau", rtol=1e-6, atol=1e-9)
    assert r.stats["nfev"] > 5
    assert len(builds) == 1 and len(builds[0]) == 2
    assert float(builds[0][1][0][list(mod.PARAM_DEFAULTS).index("m1")]) == pytest.approx(
        mod.PARAM_DEFAULTS["m1"] * 1.1)


def test_events_batch_through_the_loop_matches_the_closed_form(gen, monkeypatch):
    """The bouncing ball, a batch sharing one solver (batch_events="shared": every instance
    restarts at any instance's impact), looped and vectorised: equal bit for bit, and each
    instance's height on its closed form (free flight between impacts, v+ = -e_r v-)."""
    mod = gen("bouncing_ball")
    nb = 3
    # impacts accumulate at t1 + (2 v1 / g) e_r / (1 - e_r): 2.6 s at the earliest, past the
    # span
    h0, e_r = np.array([1.0, 0.7, 1.3]), np.array([0.8, 0.75, 0.9])
    kw = dict(method="Radau", rtol=1e-10, atol=1e-12, dt=0.01, p={"h0": h0, "e_r": e_r},
              batch_events="shared")
    runs = {}
    for label, limits in (("loop", ALWAYS), ("vectorised", NEVER)):
        _set(monkeypatch, mod, limits)
        calls = _spy(monkeypatch, mod)
        runs[label] = mod.simulate((0.0, 2.0), **kw)
        assert (calls["rhs"] > 0) == (label == "loop")
    assert np.array_equal(runs["loop"].x, runs["vectorised"].x)
    g = mod.PARAM_DEFAULTS["g"]
    t = runs["loop"].t
    h = np.asarray(runs["loop"].y["height"])
    for i in range(nb):
        exact = np.empty_like(t)
        t_hit, v_up = np.sqrt(2 * h0[i] / g), 0.0
        fall = t <= t_hit
        exact[fall] = h0[i] - 0.5 * g * t[fall] ** 2
        v_up = e_r[i] * np.sqrt(2 * g * h0[i])
        while t_hit < t[-1] and v_up > 1e-3:
            nxt = t_hit + 2 * v_up / g
            seg = (t > t_hit) & (t <= nxt)
            s = t[seg] - t_hit
            exact[seg] = v_up * s - 0.5 * g * s ** 2
            t_hit, v_up = nxt, e_r[i] * v_up
        np.testing.assert_allclose(h[i], exact, rtol=0, atol=1e-6)
