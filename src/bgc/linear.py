"""Linear analysis of a generated module: modes, frequency responses, Bode plots, and a
python-control ``StateSpace`` when that package is installed (``bgc linearize``)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bgc.base.errors import ModelError
from bgc.base.limits import LIMITS
from bgc.base.outfiles import write_output
from bgc.base.safeio import read_text_bounded
from bgc.format.scene import parse_scene
from bgc.run.driver import build
from bgc.run.plots import plain_text
from bgc.run.runner import runtime_params


@dataclass(frozen=True)
class Mode:
    eigenvalue: complex
    wn: float  # natural frequency [rad/s] = |lambda|
    zeta: float  # damping ratio = -Re(lambda) / |lambda| (1 for a real pole, nan at 0)
    states: tuple  # ((state name, |component| relative to the largest), ...)

    @property
    def hz(self) -> float:
        return self.wn / (2 * np.pi)


def modes(A, state_names, top: int = 3, basis=None) -> list[Mode]:
    """The eigenvalues of A (one per complex pair), slowest first, with natural frequency,
    damping ratio and the states that dominate it: the largest participation factors
    |v_ik w_ki| (right and left eigenvectors), relative to the largest. ``basis``: A is the
    reduction N^T A N of a model's A onto the columns of N (x = N z, :func:`on_manifold`); the
    dominant states are then read in x."""
    lam, V = np.linalg.eig(np.asarray(A, dtype=float))
    # participation factors |v_ik w_ki| (right and left eigenvectors): unlike the raw
    # eigenvector they do not depend on the states' units
    try:
        W = np.linalg.inv(V)
        if basis is not None:
            V, W = basis @ V, W @ basis.T
        part = np.abs(V * W.T)
    except np.linalg.LinAlgError:  # defective A: fall back to the eigenvectors
        part = np.abs(V if basis is None else basis @ V)
    out = []
    for k in np.argsort(np.abs(lam), kind="stable"):
        if lam[k].imag < 0:
            continue
        wn = float(abs(lam[k]))
        zeta = float(-lam[k].real / wn) if wn > 0 else float("nan")
        v = part[:, k]
        big = np.argsort(-v, kind="stable")[:top]
        vmax = v[big[0]] if v[big[0]] > 0 else 1.0
        out.append(Mode(complex(lam[k]), wn, zeta,
                        tuple((state_names[i], float(v[i] / vmax)) for i in big
                              if v[i] >= 0.05 * vmax)))
    return out


@dataclass(frozen=True)
class Reduced:
    """A linearisation reduced to a closed loop's constraint manifold: x = N z, with
    A_r = N^T A N, B_r = N^T B, C_r = C N (N orthonormal, its range invariant under A)."""

    N: object
    A: object
    B: object
    C: object
    note: str


def on_manifold(mod, A, B, C) -> Reduced | None:
    """The linearisation of a model with constraints (closed kinematic loops) reduced to the
    constraint manifold, None without constraints. With q the constraints' violation states,
    V = dq'/dx = A[q, :] the velocity constraints' rows and V A their accelerations' (which,
    under the stabilised law q'' + 2 alpha q' + alpha^2 Phi = 0, span the position constraints
    Phi with V), the states with q = 0, V x = 0 and V A x = 0 form a subspace that A maps into
    itself; its orthonormal basis N (the null space of those rows, by SVD, each row scaled to
    unit length) eliminates the constraint coordinates and with them the stabilisation's modes
    at -alpha, which are not the mechanism's."""
    names = tuple(getattr(mod, "CONSTRAINT_STATES", ()))
    idx = [i for i, s in enumerate(mod.STATE_NAMES) if s in names]
    if not idx:
        return None
    A = np.asarray(A, dtype=float)
    n = A.shape[0]
    V = A[idx, :]
    rows = np.vstack([np.eye(n)[idx], V, V @ A])
    norms = np.linalg.norm(rows, axis=1)
    rows = rows[norms > 0] / norms[norms > 0, None]
    _, s, vt = np.linalg.svd(rows)
    rank = int((s > 1e-9 * s[0]).sum()) if s.size else 0
    N = vt[rank:].T
    Ar = N.T @ A @ N
    scale = max(np.abs(A).max(), 1e-300)
    if np.abs(A @ N - N @ Ar).max() > 1e-6 * scale:
        return None  # not invariant here (off the manifold): leave A as it is
    note = (f"reduced to the constraint manifold of {len({s.split('.q')[0] for s in names})} "
            f"closed-loop constraint(s): {rank} constraint coordinates eliminated (the "
            f"violation states, the velocity and position constraints), {n - rank} left; the "
            "stabilisation's modes at -alpha are not the mechanism's")
    return Reduced(N, Ar, N.T @ np.asarray(B, dtype=float), np.asarray(C, dtype=float) @ N,
                   note)


def frequency_response(A, B, C, D, i_in: int, i_out: int, w):
    """H(jw) = C (jw I - A)^-1 B + D for one input column and one output row, at the angular
    frequencies w [rad/s]."""
    A = np.asarray(A, dtype=float)
    n = A.shape[0]
    b = np.asarray(B, dtype=float)[:, i_in]
    c = np.asarray(C, dtype=float)[i_out, :]
    d = float(np.asarray(D, dtype=float)[i_out, i_in])
    out = np.empty(len(w), dtype=complex)
    for k, wk in enumerate(np.asarray(w, dtype=float)):
        out[k] = c @ np.linalg.solve(1j * wk * np.eye(n) - A, b) + d
    return out


def to_statespace(module, A, B, C, D):
    """A python-control StateSpace with the module's state, input and output names (needs
    the optional package ``control``)."""
    import control

    return control.ss(A, B, C, D, states=list(module.STATE_NAMES),
                      inputs=list(module.INPUT_LABELS) or None,
                      outputs=list(module.OUTPUT_LABELS))


#: Eigenvalues below this fraction of the largest |eigenvalue| are taken as zero (rigid-body
#: modes, integrators, round-off) when the Bode plot chooses its frequencies.
NEAR_ZERO = 1e-9


def bode_range(A) -> tuple[float, float]:
    """The frequencies (Hz) a Bode plot shows by default: two decades either side of the
    natural frequencies of A's modes, ignoring eigenvalues that are zero up to round-off (a
    free integrator or a rigid-body mode would otherwise start the axis at 1e-21 Hz)."""
    wn = np.abs(np.linalg.eigvals(np.asarray(A, dtype=float))) if np.size(A) else np.zeros(0)
    wn = wn[np.isfinite(wn)]
    top = float(wn.max()) if wn.size else 0.0
    wn = wn[wn > NEAR_ZERO * top] if top > 0 else np.array([2 * np.pi])
    return float(wn.min() / (2 * np.pi) / 100), float(wn.max() / (2 * np.pi) * 100)


def unstable_modes(A, tol: float = 1e-9) -> list[complex]:
    """The eigenvalues of A with a positive real part (beyond round-off): growing modes."""
    lam = np.linalg.eigvals(np.asarray(A, dtype=float)) if np.size(A) else np.zeros(0)
    scale = max(float(np.max(np.abs(lam))) if lam.size else 0.0, 1.0)
    return [complex(v) for v in lam if v.real > tol * scale and v.imag >= 0]


def bode_plot(path, lin, i_in, i_out, in_label, out_label, in_unit="", out_unit="",
              f_range=None) -> None:
    """Magnitude (dB) and phase (degrees) against frequency (Hz, logarithmic) as a PNG, to
    ``path`` (written by bgc's checked writer) or a binary file object."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt


    A = np.asarray(lin[0])
    if f_range is None:
        f_range = bode_range(A)
    f = np.logspace(np.log10(f_range[0]), np.log10(f_range[1]), 400)
    H = frequency_response(*lin, i_in, i_out, 2 * np.pi * f)
    with np.errstate(divide="ignore"):
        mag = 20 * np.log10(np.abs(H))
    phase = np.degrees(np.unwrap(np.angle(H)))
    fig, (a1, a2) = plt.subplots(2, 1, sharex=True, figsize=(7, 6))
    ref = f" re 1 {out_unit}/{in_unit}" if out_unit and in_unit else ""
    a1.semilogx(f, mag)
    a1.set_ylabel(plain_text(f"|{out_label}/{in_label}| [dB{ref}]"))
    a1.grid(True, which="both", alpha=0.3)
    a2.semilogx(f, phase)
    a2.set_ylabel("phase [deg]")
    a2.set_xlabel("frequency [Hz]")
    a2.grid(True, which="both", alpha=0.3)
    a1.set_title(plain_text(f"Bode: {in_label} -> {out_label}"))
    fig.tight_layout()
    if hasattr(path, "write"):  # a file object the caller opened
        fig.savefig(path, dpi=100, format="png")
    else:  # a path: through the checked writer (never a link, a device or a folder; atomic)
        import io


        buf = io.BytesIO()
        fig.savefig(buf, dpi=100, format="png")
        write_output(path, buf.getvalue(), None, "bode plot")
    plt.close(fig)


# ---------------------------------------------------------------------------------------------
# Where to linearise: one answer for `bgc linearize` and bgc.linearize

def load_target(path, progress=None):
    """(module, run-time parameters, start time, scene or None) of a scene file (its
    specialised module, as `bgc simulate` runs it) or a model file (t0 = 0)."""
    head = read_text_bounded(path, None, "model or scene file", LIMITS.model_bytes)[:4096]

    if "bgc_scene" in head:
        sc = parse_scene(path)
        # numpy, through the cache; with B, C, D (a scene's runs leave them out)
        mod = build(scene=sc, progress=progress, linear=True).module
        return (mod,) + scene_start(sc, mod)
    b = build(path, None, "numpy", progress=progress)
    if b.compiled is not None:  # compiled now: a zero mass, a root of a negative parameter
        from bgc.run.runner import check_module_start

        check_module_start(b.compiled)
    return b.module, None, 0.0, None


def scene_start(scene, mod) -> tuple:
    """(run-time parameters, start time, scene): where a scene's runs start."""
    return runtime_params(scene, mod), scene.t_span[0], scene


def operating_point(mod, at, p=None, u=None, t0: float = 0.0, progress=None,
                    hint: str = "", x0=None, on_equilibrium=None) -> tuple:
    """(t, x, words) of the operating point ``at``: "equilibrium" (inputs held at their values
    at t0; Newton starts from ``x0``, default the initial state) or a time, the state a run
    from the initial state (or ``x0``) at t0 reaches then. ``on_equilibrium(info)`` sees the
    equilibrium solver's report (free directions, residual) once it has converged."""
    say = progress or (lambda msg: None)
    if at == "equilibrium":
        say("finding the equilibrium")
        x, info = mod.equilibrium(u=u, p=p, t=t0, x0=x0)
        if not info.converged:
            raise ModelError(None, f"no equilibrium found (max |dx/dt| = {info.residual:.3g}"
                                   f"{hint}")
        if on_equilibrium is not None:
            on_equilibrium(info)
        return t0, x, "the equilibrium"
    try:
        t = float(at)
    except (TypeError, ValueError):
        raise ModelError(None, f"--at {at!r}: 'equilibrium' or a time in seconds") from None
    tmax = LIMITS.time_magnitude
    if not t0 <= t <= tmax:  # false for nan: a run forward from the start, within the limit
        raise ModelError(None, f"--at {at!r}: a time from the start, {t0:g} s, to {tmax:g} s "
                               "(the limit of times)")
    start = mod.initial_state(p) if x0 is None else x0
    if t == t0:
        return t, start, f"t = {t:g} s"
    say(f"simulating to t = {t:g} s")
    try:
        res = mod.simulate((t0, t), t_eval=[t], p=p, x0=start, rtol=1e-8, atol=1e-10)
    except mod.SimulationError as exc:
        raise ModelError(None, f"simulation to t = {t:g} failed: {exc}") from None
    return t, res.x[..., -1], f"t = {t:g} s"


# ---------------------------------------------------------------------------------------------
# What to say about an operating point before linearising there

#: A point whose max |dx/dt| exceeds this times (1 + max |x|) is not an equilibrium.
RESIDUAL_TOL = 1e-8
#: An equilibrium this far from its guess (max |x - x0| / (1 + max |x0|)) whose Jacobian's
#: condition number exceeds COND_WARN may not be the one the model's geometry means.
MOVED_WARN = 0.1
COND_WARN = 1e8


def point_warnings(mod, t, x, p=None, u=None, guess=None, equilibrium=False,
                   settled=None) -> list[str]:
    """Warnings (text) about the point (t, x) a model is linearised at: not an equilibrium
    (max |dx/dt| and its state); an equilibrium found far from its initial guess ``guess`` with
    an ill-conditioned Jacobian (a near-free direction: the solve may have moved angles while a
    spring's deflection did not, inconsistent with the geometry), unless the equilibrium was
    ``settled`` (reached by the dynamics from the guess, which keep the geometry)."""
    x = np.asarray(x, dtype=float).reshape(-1)
    names = list(mod.STATE_NAMES)
    with np.errstate(all="ignore"):
        dx = np.asarray(mod.rhs(t, x, p, u), dtype=float).reshape(-1)
    out = []
    if dx.size and np.all(np.isfinite(dx)):
        k = int(np.argmax(np.abs(dx)))
        r = float(abs(dx[k]))
        if r > RESIDUAL_TOL * (1.0 + float(np.max(np.abs(x)))):
            what = "the equilibrium found" if equilibrium else f"t = {t:g} s"
            out.append(f"{what} is not an equilibrium: max |dx/dt| = {r:.3g} (in "
                       f"{names[k]}); the linearisation describes deviations from a moving "
                       "state")
    if equilibrium and guess is not None and x.size and settled is None:
        g = np.asarray(guess, dtype=float).reshape(-1)
        moved = np.abs(x - g)
        rel = float(np.max(moved)) / (1.0 + float(np.max(np.abs(g))))
        if rel > MOVED_WARN:
            with np.errstate(all="ignore"):
                J = np.asarray(mod.jacobian(t, x, p, u), dtype=float).reshape(x.size, x.size)
            cond = float(np.linalg.cond(J)) if np.all(np.isfinite(J)) else np.inf
            if cond > COND_WARN:
                far = ", ".join(names[i] for i in np.argsort(-moved)[:3] if moved[i] > 0)
                out.append(f"the equilibrium is far from its initial guess ({far} moved by up "
                           f"to {float(np.max(moved)):.3g}) and its Jacobian is ill-conditioned "
                           f"(condition number {cond:.2g}): it may not be the equilibrium the "
                           "model's geometry means (a state tied to others by the geometry, "
                           "such as a spring's deflection, may not have moved with them); give "
                           "a consistent guess (bgc.linearize(..., x0=...), `bgc linearize "
                           "--x0 NAME=VALUE`, or the scene's `initial:`)")
    return out


def start_guess(mod, p, assignments, base=None):
    """The initial state with ``NAME=VALUE`` assignments set (NAME a state of STATE_NAMES),
    or ``base`` (default: the module's initial state) when there are none."""
    x = np.array(mod.initial_state(p) if base is None else base, dtype=float).reshape(-1)
    names = list(mod.STATE_NAMES)
    for text in assignments:
        name, sep, val = text.partition("=")
        name = name.strip()
        try:
            v = float(val)
        except ValueError:
            v = float("nan")
        if not sep or name not in names or not np.isfinite(v):
            raise ModelError(None, f"--x0 {text!r}: give NAME=VALUE with NAME one of "
                                   f"{', '.join(names[:12])}{', ...' if len(names) > 12 else ''}"
                                   " and a finite VALUE")
        x[names.index(name)] = v
    return x
