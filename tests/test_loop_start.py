"""Consistent starts of closed kinematic loops, continued (issue 24): what the generated modules
export for a start's check and projection (constraint_residuals, kinetic_energy), the module's
own simulate refusing an inconsistent x0, a scene's `constraints: {initial: project}` on both
backends, the velocity projection in the kinetic-energy metric, and the FMU's start check.

Answers from outside bgc: the four-bar's closed-form assembly, its mass matrix and velocity map
(tests/reference/fourbar_lagrange.py, Lagrange from the rods' masses and inertias), and its
loop closure and velocity constraint written here from the geometry.
"""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

import bgc  # noqa: E402
from bgc.backends.c import build as cbuild  # noqa: E402
from bgc.base.errors import ModelError  # noqa: E402
from reference import fourbar_lagrange as fl  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
RIGID = ROOT / "models" / "fourbar_rigid.yaml"
CRANK = "  crank: {type: rod, m: m1, l: l1, g: g, th0: th1_0}"
L = (0.3, 0.9, 0.7)
TARGETS = ["numpy"] + (["c"] if cbuild.available() else [])
ANGLES = ("crank.th", "coupler.th", "rocker.th")
MOMENTA = ("crank.Ir.p", "coupler.Ir.p", "rocker.Ir.p")


def _closure(th) -> np.ndarray:
    return np.array([sum(li * np.cos(a) for li, a in zip(L, th)) - 1.0,
                     sum(li * np.sin(a) for li, a in zip(L, th))])


def _velocity_rows(th) -> np.ndarray:
    """d(closure)/d(angles): the velocity constraint G w = 0 in the angular rates."""
    return np.array([[-li * np.sin(a) for li, a in zip(L, th)],
                     [li * np.cos(a) for li, a in zip(L, th)]])


def _least_energy_crank_rate(th, w0) -> float:
    """The crank rate of the assembled mechanism closest to the rates w0 in kinetic energy:
    the velocity map K (w = K w1) and the mass matrix M of the reference,
    w1 = (K^T M w0) / (K^T M K)."""
    fb = fl.FourBar(fl.model_params())
    k, _ = fb.coefficients(np.asarray(th), 1.0)
    m = fb.mass(np.asarray(th))
    return float(k @ m @ w0 / (k @ m @ k))


@pytest.fixture(scope="module", params=TARGETS)
def fourbar(request):
    return bgc.compile(str(RIGID), target=request.param)


def _rates(mod, x):
    y = mod.outputs(0.0, x)
    return np.array([y["w1"], y["w2"], y["w3"]])


def test_constraint_residuals_are_the_geometry(fourbar):
    """Off the loop and spun, the exported residuals equal the closure and G w computed here
    from the angles and the module's own rates; the kinetic energy is quadratic in the momenta
    and its Hessian is M^-1 in momentum coordinates, M the reference's mass matrix."""
    m = fourbar
    names = list(m.STATE_NAMES)
    x = np.array(m.initial_state(), dtype=float)
    x[names.index("crank.th")] += 0.02
    x[names.index("crank.Ir.p")] += 0.003
    pos, vel = m.constraint_residuals(0.0, x)
    th = [x[names.index(n)] for n in ANGLES]
    assert np.abs(pos - _closure(th)).max() < 1e-14
    assert np.abs(vel - _velocity_rows(th) @ _rates(m, x)).max() < 1e-13
    # KE = 1/2 w^T M w with w the rates of the momenta: p = J w on the rods' own inertias
    fb = fl.FourBar(fl.model_params())
    w = _rates(m, x)
    assert m.kinetic_energy(0.0, x) == pytest.approx(0.5 * w @ fb.mass(np.array(th)) @ w,
                                                     rel=1e-12)
    # batched: one column per instance
    both = np.stack([x, np.array(m.initial_state(), dtype=float)], axis=1)
    pos2, vel2 = m.constraint_residuals(0.0, both)
    assert pos2.shape == (2, 2) and np.abs(pos2[:, 1]).max() < 1e-14
    assert np.allclose(pos2[:, 0], pos, rtol=0, atol=1e-15)


def test_module_simulate_checks_x0(fourbar):
    """The module's own simulate refuses an inconsistent x0 (ValueError naming the constraint
    and the residual, as bgc.run.consistency), unless check_constraints=False."""
    m = fourbar.module
    names = list(m.STATE_NAMES)
    x0 = np.array(m.initial_state(), dtype=float)
    x0[names.index("crank.th")] += 1e-3
    with pytest.raises(ValueError) as e:
        m.simulate((0.0, 0.01), x0=x0)
    msg = str(e.value)
    assert "constraint 'pivot2' closing a kinematic loop" in msg
    assert "positions violate its closure" in msg and "check_constraints=False" in msg
    th = [x0[names.index(n)] for n in ANGLES]
    res = [float(v) for v in msg.split("residual is [")[1].split("]")[0].split(",")]
    assert np.allclose(res, _closure(th), rtol=1e-5, atol=1e-12)
    x1 = np.array(m.initial_state(), dtype=float)
    x1[names.index("crank.Ir.p")] += 1e-3
    with pytest.raises(ValueError, match="velocities violate it"):
        m.simulate((0.0, 0.01), x0=x1)
    r = m.simulate((0.0, 0.01), x0=x0, check_constraints=False)
    assert r.t[-1] == pytest.approx(0.01)
    r = m.simulate((0.0, 0.01), x0=np.array(m.initial_state(), dtype=float))
    assert r.t[-1] == pytest.approx(0.01)


def _spun(project: bool) -> str:
    text = RIGID.read_text().replace(CRANK, CRANK.replace("th0: th1_0}", "th0: th1_0, w0: 1.0}"))
    if project:
        text = text.replace("\nparameters:", "\nconstraints: {initial: project}\nparameters:", 1)
    return text


def test_model_projection_is_the_least_kinetic_energy_one():
    """A spun crank (w0 = 1 rad/s, the others at rest) projected at compile time: the crank
    rate is (K^T M w0) / (K^T M K) from the bodies' masses and inertias (the reference), and
    the projected rates satisfy G w = 0."""
    m = bgc.compile(_spun(True))
    x = np.array(m.initial_state(), dtype=float)
    names = list(m.STATE_NAMES)
    th = [x[names.index(n)] for n in ANGLES]
    w = _rates(m, x)
    want = _least_energy_crank_rate(th, np.array([1.0, 0.0, 0.0]))
    assert abs(w[0] - want) < 1e-10
    assert np.abs(_velocity_rows(th) @ w).max() < 1e-12
    assert abs(want - 1.0) > 0.1  # the impulse shares the rate out: a real test
    note = next(n for n in m.compiled.equations.warnings if "initial momenta" in n)
    assert "least kinetic-energy change" in note and "crank.Ir.p 0.0045 -> " in note


def _scene(tmp_path, initial: str, extra: str = "constraints: {initial: project}\n") -> Path:
    f = tmp_path / "s.yaml"
    f.write_text(f"bgc_scene: 1\nname: s\nmodel: {RIGID}\nduration: 0.2\n"
                 f"initial: {initial}\n{extra}")
    return f


@pytest.mark.parametrize("backend", TARGETS)
def test_scene_projection_on_both_backends(tmp_path, backend):
    """A scene's crank turned by 0.05 rad and spun (w0 = 1 rad/s, the rest at rest) with
    `constraints: {initial: project}`: the run starts on the loop (the pose equals the
    closed-form assembly at its own crank angle, the rates the least-energy ones) and says what
    changed; without the key the same scene is refused at its `initial:`."""
    from bgc.run.runner import run_scene

    j1 = 0.6 * 0.3 ** 2 / 12  # the crank's centroidal inertia: p = J w0
    scene = _scene(tmp_path, f"{{crank.th: 1.05, crank.Ir.p: {j1!r}}}")
    said: list[str] = []
    res = run_scene(scene, progress=said.append, backend=backend, use_cache=False)
    names = list(res.module.STATE_NAMES)
    x0 = res.x[:, 0]
    th = [x0[names.index(n)] for n in ANGLES]
    ref = fl.FourBar(fl.model_params()).assemble(th[0])
    assert np.abs(np.array(th) - ref).max() < 1e-10 and abs(th[0] - 1.05) < 0.05
    w = _rates(res.module, x0)
    # the positions moved first: the reference's least-energy rate at the projected pose, of
    # the rates the momenta had (only the crank's, J w0 with w0 = 1)
    assert abs(w[0] - _least_energy_crank_rate(th, np.array([1.0, 0.0, 0.0]))) < 1e-10
    assert np.abs(_velocity_rows(th) @ w).max() < 1e-12
    pos = next(s for s in said if "initial positions projected" in s)
    assert "crank.th 1.05 -> " in pos and "coupler.th" in pos and "rocker.th" in pos
    assert any("initial momenta projected" in s and "least kinetic-energy" in s for s in said)
    bad = _scene(tmp_path, "{crank.th: 1.05}", extra="")
    with pytest.raises(ModelError) as e:
        run_scene(bad, backend=backend, use_cache=False)
    assert e.value.coord.line == 5 and "positions violate its closure" in str(e.value)
    assert "constraints: {initial: project}" in str(e.value)


def test_scene_constraints_key_is_validated(tmp_path):
    scene = _scene(tmp_path, "{crank.th: 1.0}", extra="constraints: {initial: fix}\n")
    out = subprocess.run([sys.executable, "-m", "bgc", "simulate", str(scene), "--backend",
                          "numpy"], capture_output=True, text=True, timeout=600)
    assert out.returncode == 2 and "Traceback" not in out.stderr
    head = out.stderr.strip().splitlines()[-1]
    assert head.startswith(f"{scene}:6:") and "initial must be 'check' or 'project'" in head
    scene = _scene(tmp_path, "{crank.th: 1.0}", extra="constraints: {alpha: 3}\n")
    out = subprocess.run([sys.executable, "-m", "bgc", "simulate", str(scene), "--backend",
                          "numpy"], capture_output=True, text=True, timeout=600)
    assert out.returncode == 2 and f"{scene}:6:" in out.stderr and "alpha" in out.stderr


# ---------------------------------------------------------------------------------------------
# the FMU checks its start when it leaves initialisation mode


def _fixed_assembly_model(tmp_path) -> Path:
    """The four-bar with the coupler's and the rocker's start angles as plain numbers (the
    reference's assembly at th1_0 = 1): a changed crank start angle then opens the loop."""
    th = fl.FourBar(fl.model_params()).assemble(1.0)
    lines = []
    for line in RIGID.read_text().splitlines():
        if line.startswith("  th2_0:"):
            line = f"  th2_0: {{value: {float(th[1])!r}, unit: rad}}"
        elif line.startswith("  th3_0:"):
            line = f"  th3_0: {{value: {float(th[2])!r}, unit: rad}}"
        lines.append(line)
    f = tmp_path / "fourbar_fixed.yaml"
    f.write_text("\n".join(lines) + "\n")
    return f


@pytest.mark.skipif(not cbuild.available(), reason="no C compiler")
def test_fmu_checks_its_start_values(tmp_path):
    fmpy = pytest.importorskip("fmpy")
    from bgc.run.fmu import export_fmu

    fmu = export_fmu(_fixed_assembly_model(tmp_path), tmp_path / "fb.fmu")
    messages: list[str] = []

    def logger(env, name, status, category, message):
        messages.append(message.decode() if isinstance(message, bytes) else str(message))

    r = fmpy.simulate_fmu(str(fmu), stop_time=0.1, fmi_type="CoSimulation", logger=logger)
    assert r["time"][-1] == pytest.approx(0.1)
    for fmi_type in ("CoSimulation", "ModelExchange"):
        messages.clear()
        with pytest.raises(Exception):
            fmpy.simulate_fmu(str(fmu), stop_time=0.1, fmi_type=fmi_type, logger=logger,
                              start_values={"th1_0": 1.05})
        msg = next(m for m in messages if "fmi2ExitInitializationMode" in m)
        assert "constraint 'pivot2' closing a kinematic loop" in msg
        assert "positions violate its closure" in msg
        th = fl.FourBar(fl.model_params()).assemble(1.0)
        res = [float(v) for v in msg.split("residual is [")[1].split("]")[0].split(",")]
        assert np.allclose(res, _closure([1.05, th[1], th[2]]), rtol=1e-5)
