"""Scene specialisation (effects, folded parameters, output slicing): docs/specialisation.md.

The reference for every toggle is the *full* module (every effect on, compiled from the same
model) with that effect's parameters set to zero, integrated independently over the same
scene: turning an effect off must give the same outputs (to the solver's tolerance) with fewer
states. Each comparison also checks that the full module *without* the zeroed parameters is
measurably different, so the comparison can fail.
"""
from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from conftest import bgc_in_process

from bgc.backends.load import load_module
from bgc.base.errors import Coord, ModelError
from bgc.core.specialize import plan_for
from bgc.format.parse import parse_file
from bgc.format.scene import parse_scene, scene_model
from bgc.run.driver import compile_model
from bgc.run.runner import compile_scene, explain_scene, operation_counts

ROOT = Path(__file__).resolve().parents[1]
SCENES = ROOT / "models" / "scenes"
HERE = Path(__file__).resolve().parent / "specialize"


def scene_file(tmp_path, text: str, name: str = "s", model: str | None = None) -> Path:
    """A scene file next to a copy-free reference to a model (absolute path)."""
    p = tmp_path / f"{name}.yaml"
    p.write_text(text.replace("MODEL", str(model)) if model else text)
    return p


def effects_off(scene, *names):
    """The scene with these effects turned off (as if written under `effects:`)."""
    eff = dict(scene.effects)
    for n in names:
        eff[n] = (False, Coord(scene.file, 1, 1))
    return dataclasses.replace(scene, effects=eff, plots=())


def run(mod, scene, p=None, t_end=None, rtol=None, atol=None):
    """The scene (or its first t_end seconds) with the scene's solver; returns SimResult."""
    t_span = (scene.t_span[0], t_end if t_end is not None else scene.t_span[1])
    bps = tuple(b for b in scene.breakpoints if b < t_span[1])
    return mod.simulate(t_span, dt=scene.dt, method=scene.method, rtol=rtol or scene.rtol,
                        atol=atol or scene.atol, p=p, breakpoints=bps, max_step=scene.max_step)


def only(mod, params):
    """The parameters this module still has (folded or unused ones may be gone)."""
    return {k: v for k, v in params.items() if k in mod.PARAM_DEFAULTS} or None


def compare(mod, full_mod, res, ref, other, rtol, atol):
    """The specialised run `res` against the full module's run `ref` (effect parameters zeroed):

    - every state the specialised module keeps (matched by name) agrees within 200 times the
      solver's local tolerance rtol |x| + atol (the two runs take different steps: the error
      norm runs over different state vectors);
    - every output both modules have agrees within 1000 rtol of its scale (outputs smaller
      than 10 atol are below what the solver resolves; the state check covers them);
    - the run of the full module *without* zeroed parameters (`other`) is farther than 100
      times that state bound: the comparison can tell the effect apart."""
    idx = [full_mod.STATE_NAMES.index(s) for s in mod.STATE_NAMES]
    assert res.x.shape[1:] == ref.x.shape[1:]
    xr = ref.x[idx]
    w = rtol * np.abs(xr) + atol
    err = np.max(np.abs(res.x - xr) / w)
    gap = np.max(np.abs(res.x - other.x[idx]) / w)
    assert err < 200, f"states differ by {err:.3g} local tolerances"
    assert gap > 100 * 200, f"the effect changes too little to be told apart ({gap:.3g})"
    common = [k for k in res.y if k in ref.y]
    assert common
    for k in common:
        scale = np.max(np.abs(ref.y[k]))
        if scale < 10 * atol:
            continue
        e = np.max(np.abs(res.y[k] - ref.y[k])) / scale
        assert e < 1000 * rtol, f"output {k}: differs by {e:.3g} of its scale"
    return err, gap


# ---------------------------------------------------------------------------------------------
# The DC motor with thermal winding and flexible load: whole scenes

MOTOR_TOGGLES = {  # effect -> the parameters that make its contribution zero in the full model
    "thermal": {"eta": 0.0},
    "friction": {"b_m": 0.0, "b_L": 0.0},
    "shaft_damping": {"c_s": 0.0},
    "load": {"N": 0.0},
}


@pytest.fixture(scope="module")
def motor():
    scene = parse_scene(SCENES / "motor_full.yaml")
    full, mod = compile_scene(scene, specialise=False)
    return scene, full, mod


_cache: dict = {}


def motor_on(motor):
    """The full motor module over the whole motor_full scene, every effect on (cached)."""
    if "motor_on" not in _cache:
        scene, _, mod = motor
        _cache["motor_on"] = run(mod, scene, rtol=1e-8, atol=1e-10)
    return _cache["motor_on"]


@pytest.mark.parametrize("effect", sorted(MOTOR_TOGGLES))
def test_motor_toggle_equals_full_model_with_zeroed_parameters(motor, effect):
    """The whole motor_full scene (120 s), tighter tolerances than the scene's."""
    scene, full, full_mod = motor
    c, mod = compile_scene(effects_off(scene, effect))
    assert len(mod.STATE_NAMES) <= len(full_mod.STATE_NAMES)
    kw = dict(rtol=1e-8, atol=1e-10)
    res = run(mod, scene, **kw)
    ref = run(full_mod, scene, p=MOTOR_TOGGLES[effect], **kw)
    compare(mod, full_mod, res, ref, motor_on(motor), **kw)
    assert f"effects off: {effect}" in mod.__doc__


def test_motor_thermal_off_removes_its_states_and_outputs(motor):
    scene, _, full_mod = motor
    _, mod = compile_scene(effects_off(scene, "thermal"))
    assert {"C_wind.q", "C_house.q"} <= set(full_mod.STATE_NAMES)
    assert not {"C_wind.q", "C_house.q"} & set(mod.STATE_NAMES)
    assert mod.N_STATES == len(mod.STATE_NAMES) == len(full_mod.STATE_NAMES) - 2
    assert "winding_temp" not in mod.OUTPUT_NAMES and "current" in mod.OUTPUT_NAMES
    assert "C_wind, to_housing" in mod.__doc__  # the header lists what went and why
    assert "exists only through effect 'thermal'" in mod.__doc__


def test_motor_load_off_removes_the_drivetrain(motor):
    """Turning `load` off (an instance tag) removes every element and the auxiliary state of the
    drivetrain instance; the motor then runs free: its steady speed is V/K less the loss."""
    scene, _, full_mod = motor
    _, mod = compile_scene(effects_off(scene, "load"))
    assert not [s for s in mod.STATE_NAMES if s.startswith("drivetrain.")]
    assert set(mod.STATE_NAMES) == {"winding_L.p", "rotor_J.p", "C_wind.q", "C_house.q", "E_cu"}
    y = run(mod, scene, p={"alpha": 0.0}, t_end=2.0).y
    P = mod.PARAM_DEFAULTS
    w = P["K"] * P["V0"] / (P["K"] ** 2 + P["R_a"] * P["b_m"])  # no load: closed form
    assert y["current"][-1] == pytest.approx(P["b_m"] * w / P["K"], rel=1e-4)


# ---------------------------------------------------------------------------------------------
# Slicing by outputs


def motor_scene(tmp_path, extra: str, name="s"):
    return parse_scene(scene_file(tmp_path, f"""bgc_scene: 1
model: {ROOT / 'models' / 'motor_thermal.yaml'}
duration: 120.0
inputs: {{TL: "where(t < 1, 0, tau_L)"}}
breakpoints: [1.0]
solver: {{rtol: 1.0e-9, atol: 1.0e-11, dt: 0.05}}
{extra}""", name))


THERMAL = {"C_wind.q", "C_house.q"}


def test_slicing_keeps_thermal_states_only_when_they_feed_back(tmp_path, motor):
    """Load motion only: with a resistance that does not depend on temperature (alpha folded to
    0) the thermal branch only receives heat and is sliced away; with alpha != 0 it feeds back
    through the resistance and stays; turning the thermal effect off removes it again."""
    _, _, full_mod = motor
    want = "outputs: [load_angle, load_speed]"
    const = compile_scene(motor_scene(tmp_path, want + "\nparameters: {alpha: 0.0}", "a"))[1]
    hot = compile_scene(motor_scene(tmp_path, want, "b"))[1]
    cold = compile_scene(motor_scene(tmp_path, want + "\neffects: {thermal: off}", "c"))[1]
    assert not THERMAL & set(const.STATE_NAMES)
    assert THERMAL <= set(hot.STATE_NAMES)
    assert not THERMAL & set(cold.STATE_NAMES)
    for m in (const, hot, cold):
        assert m.OUTPUT_NAMES == ("load_speed", "load_angle")
        assert "E_cu" not in m.STATE_NAMES  # needed by no requested output
    # the sliced modules reproduce the full model's load motion
    sc = motor_scene(tmp_path, want, "d")
    full0, full = run(full_mod, sc, p={"alpha": 0.0}), run(full_mod, sc)
    kw = dict(rtol=sc.rtol, atol=sc.atol)
    r_const = run(const, sc)
    compare(const, full_mod, r_const, full0, full, **kw)
    compare(hot, full_mod, run(hot, sc), full, full0, **kw)
    # alpha reads a temperature that is gone with the thermal effect: it acts no more
    compare(cold, full_mod, run(cold, sc, p={"alpha": 1.0}), full0, full, **kw)
    y_const = r_const.y
    # and the constant-resistance steady state is the closed form
    P = full_mod.PARAM_DEFAULTS
    K, R, N, TL = P["K"], P["R_a"], P["N"], P["tau_L"]
    w_m = (K * P["V0"] - R * N * TL) / (K ** 2 + R * (P["b_m"] + N ** 2 * P["b_L"]))
    assert y_const["load_speed"][-1] == pytest.approx(N * w_m, rel=1e-6)


def test_unrequested_outputs_keep_no_state_alive(tmp_path):
    """Only load_speed: the load angle (an auxiliary state only that output reads) and the
    copper energy go; asking for the angle brings its state back."""
    m1 = compile_scene(motor_scene(tmp_path, "outputs: [load_speed]", "a"))[1]
    m2 = compile_scene(motor_scene(tmp_path, "outputs: [load_speed, load_angle]", "b"))[1]
    assert "drivetrain.angle" not in m1.STATE_NAMES and "E_cu" not in m1.STATE_NAMES
    assert "drivetrain.angle" in m2.STATE_NAMES
    assert set(m2.STATE_NAMES) - set(m1.STATE_NAMES) == {"drivetrain.angle"}
    ops1, ops2 = operation_counts(m1.__loader__.get_data(m1.__file__).decode()), \
        operation_counts(m2.__loader__.get_data(m2.__file__).decode())
    assert ops1["rhs"] <= ops2["rhs"]


def test_3r2s_p3_only_slices_states(tmp_path):
    """Structure only (the p3 trajectory is compared in the slow test below): the states that
    cannot reach p3 are gone, the link-3 states and every storage element stay."""
    c, mod = compile_scene(parse_scene(SCENES / "3r2s_circle_p3only.yaml"))
    gone = {f"link{k}.rC[{i}]" for k in (1, 2, 4) for i in range(3)}
    gone |= {"pd[0]", "pd[1]", "pd[2]", "W_drive", "W_diss"}
    assert not gone & set(mod.STATE_NAMES)
    assert {"link3.rC[0]", "link3.R[0,0]", "link1.It.p[0]", "j1.C.q[0]"} <= set(mod.STATE_NAMES)
    assert mod.OUTPUT_NAMES == ("p3",)
    assert len(mod.STATE_NAMES) == 101 - len(gone)


# ---------------------------------------------------------------------------------------------
# A scene that disables nothing is the full model, byte for byte


def _but_linear(text: str) -> str:
    """The module's text without its input_jacobian and output_jacobian (a scene's module
    has only stubs there: B, C, D are left out of what its runs compile)."""
    i = min(k for k in (text.find("\ndef input_jacobian("), text.find("\n_NO_LINEAR = ("))
            if k >= 0)
    return text[:i] + text[text.index("\nclass SimulationError("):]


def test_scene_without_changes_is_the_full_module(tmp_path):
    """The full module, as `bgc compile MODEL` writes it (test_golden checks that one against
    generated/motor_thermal.py), but for B, C, D: byte for byte the model's module printed
    without them, and the golden's text but for those two functions."""
    model = ROOT / "models" / "motor_thermal.yaml"
    full = compile_model(parse_file(model)).source
    golden = compile_model(parse_file(model), linear=False).source
    assert "def input_jacobian(" in full and "_NO_LINEAR" in golden
    assert _but_linear(golden) == _but_linear(full)
    outs = ("housing_temp, current, motor_speed, load_speed, load_angle, shaft_torque, "
            "power_in, copper_loss, copper_energy, winding_temp")
    for i, extra in enumerate(["", "effects: {thermal: on, load: on}",
                               f"outputs: [{outs}]"]):  # every output, in another order
        sc = parse_scene(scene_file(tmp_path, f"bgc_scene: 1\nmodel: {model}\nduration: 1\n"
                                              f"{extra}\n", f"s{i}"))
        c, _ = compile_scene(sc)
        assert c.source == golden, extra
        assert c.notes == ()
    # a free parameter is the scene's value as the module's default: still the full model
    sc = parse_scene(scene_file(tmp_path, f"bgc_scene: 1\nmodel: {model}\nduration: 1\n"
                                          "parameters: {V0: 30.0}\nfree: [V0]\n", "s9"))
    c, mod = compile_scene(sc)
    assert c.source == compile_scene(sc, specialise=False)[0].source
    assert c.notes == () and mod.PARAM_DEFAULTS["V0"] == 30.0


def test_scene_with_only_inputs_is_the_full_model_with_its_signals():
    sc = parse_scene(SCENES / "motor_full.yaml")
    spec, _ = compile_scene(sc)
    full, _ = compile_scene(sc, specialise=False)
    assert spec.source == full.source
    assert spec.source != compile_model(parse_file(sc.model_path)).source  # the signal


def test_folded_and_free_parameters(tmp_path, motor):
    """Fixed scene parameters become constants (gone from PARAM_DEFAULTS); free ones stay and
    still act at run time, like the full model's."""
    _, _, full_mod = motor
    sc = parse_scene(SCENES / "motor_electrothermal.yaml")
    c, mod = compile_scene(sc)
    assert "tau_L" not in mod.PARAM_DEFAULTS and "V0" in mod.PARAM_DEFAULTS
    assert "tau_L = 2.0" in mod.__doc__
    kw = dict(rtol=1e-8, atol=1e-10)
    res = run(mod, sc, p={"V0": 18.0}, **kw)
    ref = run(full_mod, sc, p={"V0": 18.0, "tau_L": 2.0}, **kw)
    compare(mod, full_mod, res, ref, run(full_mod, sc, p={"tau_L": 2.0}, **kw), **kw)


# ---------------------------------------------------------------------------------------------
# Cascades: zero sources, trivial junctions, derivative causality


def test_junction_left_with_one_bond_is_a_zero_source(tmp_path):
    """rc_leak: without the leak conductance the node p is an open circuit (zero flow) in series
    with the loop, so no current flows and the capacitor keeps its charge: the full model with
    G = 0 says the same, and the leak-free closed form q = C V (1 - exp(-t / (R C))) does not."""
    model = parse_file(HERE / "rc_leak.yaml")
    from bgc.core.specialize import Plan

    c = compile_model(model, None, Plan(frozenset({"leak"}), scene="t"))
    assert "0-junction p left with one bond: a zero flow source (Sf)" in c.notes
    mod = load_module(c.source, "rc_leak_noleak")
    full = load_module(compile_model(model).source, "rc_leak_full")
    _, x0, y = mod.simulate((0, 3), dt=0.1)
    _, _, y_ref = full.simulate((0, 3), dt=0.1, p={"G": 0.0}, x0=np.array([0.0]))
    assert np.max(np.abs(y["current"])) == 0.0
    np.testing.assert_allclose(y["charge"], y_ref["charge"], atol=1e-12)
    assert "leak_current" not in mod.OUTPUT_NAMES


def test_trivial_junction_disappears(motor):
    scene, _, _ = motor
    c, mod = compile_scene(effects_off(scene, "shaft_damping"))
    assert "drivetrain.twist" not in {e.id for e in c.graph.elements}
    assert any("drivetrain.twist (drivetrain.b3 + drivetrain.b4 -> drivetrain.b3)" in n
               for n in c.notes)


def test_removed_spring_leaves_derivative_causality_located_at_the_effect(tmp_path):
    p = scene_file(tmp_path, f"""bgc_scene: 1
model: {HERE / 'two_masses.yaml'}
duration: 1
effects:
  coupling: off
""")
    with pytest.raises(ModelError) as ei:
        compile_scene(parse_scene(p))
    e = ei.value
    assert (e.coord.file, e.coord.line, e.coord.column) == (str(p), 5, 3)
    assert "'coupling'" in e.message and "derivative causality" in e.message
    assert "'M2'" in e.message and "'M1'" in e.message and "removes K" in e.message


def test_removed_state_still_read_is_located_at_the_effect(tmp_path):
    p = scene_file(tmp_path, f"""bgc_scene: 1
model: {HERE / 'shared_state.yaml'}
duration: 1
effects: {{memory: off}}
""")
    with pytest.raises(ModelError) as ei:
        compile_scene(parse_scene(p))
    e = ei.value
    assert (e.coord.line, e.coord.column) == (4, 11)
    assert "removes state 's', which R 'D' still reads" in e.message


@pytest.mark.parametrize("name", sorted(p.stem for p in SCENES.glob("motor_*.yaml")))
def test_every_requested_output_is_present(name):
    """Each motor scene's module has exactly the outputs it asks for (all when it names none,
    less those that only a removed effect provides)."""
    sc = parse_scene(SCENES / f"{name}.yaml")
    c, mod = compile_scene(sc)
    if sc.outputs:
        assert set(mod.OUTPUT_NAMES) == set(sc.outputs)
    else:
        full = compile_scene(sc, specialise=False)[1]
        assert set(mod.OUTPUT_NAMES) <= set(full.OUTPUT_NAMES)
    x = mod.X0
    y = mod.outputs(0.0, x)
    assert set(y) == set(mod.OUTPUT_NAMES)
    assert mod.rhs(0.0, x).shape == (mod.N_STATES,)


# ---------------------------------------------------------------------------------------------
# Scene mistakes: located, clear


MOTOR = ROOT / "models" / "motor_thermal.yaml"
BAD_SCENES = [  # (scene body after the model line, line, column, message fragment)
    ("duration: 1\neffects: {thermal: off, heating: off}\n", 5, 25,
     "the model has no effect 'heating'"),
    ("duration: 1\neffects: {thermal: maybe}\n", 5, 20, "write on or off"),
    ("duration: 1\nparameters: {V0: 2}\nfree: [V0, K]\n", 6, 12,
     "free parameter 'K' is not set"),
    ("duration: 1\nparameters: {V0: 2}\nfree: [V0, V0]\n", 6, 12, "listed twice"),
    ("duration: 1\noutputs: [current, speed]\n", 5, 20, "the model has no output 'speed'"),
    ("duration: 1\noutputs: [current, current]\n", 5, 20, "output 'current' is listed twice"),
    ("duration: 1\noutputs: []\n", 5, 10, "list at least one output"),
    ("duration: 1\noutputs: [current]\nplots: [{kind: time, outputs: [load_speed]}]\n", 6, 32,
     "not among the scene's outputs"),
    ("duration: 1\nparameters: {R_b: 1}\n", 5, 14, "the model has no parameter 'R_b'"),
    ("duration: 1\neffects: {thermal: off}\noutputs: [current,\n   winding_temp]\n", 7, 4,
     "output 'winding_temp' exists only through what effect 'thermal' adds"),
    ("duration: 1\neffects: {load: off}\nplots: [{kind: time, outputs: [load_speed]}]\n", 6, 9,
     "the module has no output 'load_speed'"),
]


@pytest.mark.parametrize("body,line,col,msg", BAD_SCENES, ids=[b[3][:30] for b in BAD_SCENES])
def test_scene_mistakes_are_located(tmp_path, body, line, col, msg):
    p = scene_file(tmp_path, f"bgc_scene: 1\n# a scene with a mistake\nmodel: {MOTOR}\n{body}")
    with pytest.raises(ModelError) as ei:
        compile_scene(parse_scene(p))
    e = ei.value
    assert msg in e.message
    assert (e.coord.file, e.coord.line, e.coord.column) == (str(p), line, col), e


def bgc(*args):
    """``bgc ARGS`` in this process (what ``python -m bgc`` runs: its exit status, stdout and
    stderr; these tests are about the messages and what is written, not the process)."""
    return bgc_in_process(*args)


def test_cli_compile_with_scene_writes_the_specialised_module(tmp_path):
    out = tmp_path / "m.py"
    r = bgc_in_process("compile", "-q", MOTOR, "--scene", SCENES / "motor_load_motion_cold.yaml",
                 "-o", out)
    assert r.returncode == 0, r.stderr
    text = out.read_text()
    assert "effects off: thermal" in text and "'C_wind.q'" not in text
    mod = load_module(text, "cli_cold")
    assert mod.OUTPUT_NAMES == ("load_speed", "load_angle", "shaft_torque")


def test_cli_compile_with_scene_of_another_model_is_an_error(tmp_path):
    out = tmp_path / "m.py"
    r = bgc("compile", ROOT / "models" / "msd.yaml", "--scene", SCENES / "motor_full.yaml",
            "-o", out)
    assert r.returncode == 2
    assert r.stderr.strip().splitlines()[-1].startswith(f"{SCENES / 'motor_full.yaml'}:5:8:")
    assert not out.exists() and list(tmp_path.iterdir()) == []


def test_cli_unproducible_output_exit_2_nothing_written(tmp_path):
    p = scene_file(tmp_path, f"bgc_scene: 1\nmodel: {MOTOR}\nduration: 1\n"
                             "effects: {thermal: off}\noutputs: [housing_temp]\n")
    r = bgc("compile", MOTOR, "--scene", p, "-o", tmp_path / "m.py")
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert r.stderr.strip().splitlines()[-1].startswith(f"{p}:5:11: output 'housing_temp'")
    assert not (tmp_path / "m.py").exists()


def test_cli_explain(tmp_path):
    r = bgc_in_process("explain", "-q", "--rounds", "2", SCENES / "motor_load_motion_cold.yaml")
    assert r.returncode == 0, r.stderr
    lines = r.stdout.splitlines()
    row = next(x for x in lines if x.strip().startswith("states "))
    assert row.split()[1:3] == ["8", "5"]
    assert any(x.startswith("states removed (3): C_wind.q, C_house.q, E_cu") for x in lines)
    assert any(x.strip().startswith("rhs operations") for x in lines)
    assert any(x.strip().startswith("rhs call [us]") for x in lines)


def test_explain_counts_fewer_operations_when_states_go():
    ex = explain_scene(SCENES / "motor_load_motion_constr.yaml")
    (full, spec) = ex.ops()
    assert spec["rhs"] < full["rhs"] and spec["jacobian"] < full["jacobian"]
    kept, removed = ex.states
    assert removed == ["C_wind.q", "C_house.q", "E_cu"]
    a, b = ex.rhs_cost(rounds=1)
    assert a > 0 and b > 0


# ---------------------------------------------------------------------------------------------
# 3R2S toggles (slow): the first 0.3 s of the circle


R3_TOGGLES = {
    "gravity": {"g": 0.0},
    "joint_damping": {"r_t": 0.0, "r_t5": 0.0, "r_r": 0.0},
    "rotational_couplings": {"k_r": 0.0, "r_r": 0.0},
    "drive_damping": {"r_d": 0.0},
}
#: (rtol, atol) where the scene's own are too coarse to tell the effect apart in 0.05 s: the
#: drive's 5 N s/m damper barely acts before the drive gets going (measured: the run with the
#: damper differs by 1.7e3 local tolerances at the scene's, 7e6 at these)
R3_TOLS = {"drive_damping": (1e-8, 1e-10)}


@pytest.fixture(scope="module")
def circle():
    """The circle scene (every output, so none is asked for that an effect removes), its full
    module, and that module's run over the first T_3R2S seconds with every effect on."""
    scene = dataclasses.replace(parse_scene(SCENES / "3r2s_circle.yaml"), outputs=(), plots=())
    _, full_mod = compile_scene(scene, specialise=False)
    return scene, full_mod, run(full_mod, scene, t_end=T_3R2S)


T_3R2S = 0.05


def zeroed(model, zero: dict):
    """The model with these top-level parameters' values set to zero in the file's place."""
    params = tuple(dataclasses.replace(p, value=0.0) if p.name in zero else p
                   for p in model.body.params)
    assert {p.name for p in params} >= set(zero)
    return dataclasses.replace(model, body=dataclasses.replace(model.body, params=params))


@pytest.mark.slow
@pytest.mark.parametrize("effect", sorted(R3_TOGGLES))
def test_3r2s_toggle_equals_full_model_with_zeroed_parameters(circle, effect):
    """The first 0.05 s of the circle scene (the start of the settling transient, where the
    stiff joints ring: the costliest stretch of the scene), at the scene's tolerances (tighter
    ones where R3_TOLS says so).

    The reference is the full module (compiled plainly, every parameter free) run with the
    effect's parameters set to zero, as the motor's above; the specialised module is compiled
    from the model with those parameters zero in the file (so g is zero in the energy
    output's potential term too, as in the reference run). The specialised module runs with
    its own defaults."""
    scene, full_mod, on = circle
    zero = R3_TOGGLES[effect]
    assert set(zero) <= set(full_mod.PARAM_DEFAULTS)  # the reference can zero them all
    model = zeroed(scene_model(scene), zero)
    plan = plan_for(effects_off(scene, effect), full_mod_params(model))
    mod = load_module(compile_model(model, None, plan).source, f"spec_{effect}")
    assert len(mod.STATE_NAMES) <= len(full_mod.STATE_NAMES)
    rtol, atol = R3_TOLS.get(effect, (scene.rtol, scene.atol))
    if effect in R3_TOLS:
        on = run(full_mod, scene, t_end=T_3R2S, rtol=rtol, atol=atol)
    res = run(mod, scene, t_end=T_3R2S, rtol=rtol, atol=atol)
    ref = run(full_mod, scene, p=zero, t_end=T_3R2S, rtol=rtol, atol=atol)
    compare(mod, full_mod, res, ref, on, rtol=rtol, atol=atol)
    if effect == "rotational_couplings":  # the energy's coupling terms are gone: a header note
        assert "outputs reading removed elements (their terms are zero): energy" in mod.__doc__


def full_mod_params(model):
    from bgc.core.graph import build_graph

    return build_graph(model).params


@pytest.mark.slow
def test_3r2s_p3_only_follows_the_full_model(circle):
    """The first 0.05 s of the circle: the sliced module's states and p3 equal the full
    module's (same equations for what it keeps, different step sizes)."""
    scene, full_mod, on = circle
    _, mod = compile_scene(parse_scene(SCENES / "3r2s_circle_p3only.yaml"))
    res = run(mod, scene, t_end=T_3R2S)
    idx = [full_mod.STATE_NAMES.index(s) for s in mod.STATE_NAMES]
    w = scene.rtol * np.abs(on.x[idx]) + scene.atol
    assert np.max(np.abs(res.x - on.x[idx]) / w) < 200
    scale = np.max(np.abs(on.y["p3"]))
    assert np.max(np.abs(res.y["p3"] - on.y["p3"])) < 1000 * scene.rtol * scale
