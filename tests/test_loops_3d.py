"""A planar loop written with 3-D joints (issue 24): the crank-rocker four-bar of
models/fourbar_rigid.yaml built from the library's spatial rods with full 3-D revolute joints
(tests/loops/fourbar_3dpins.yaml: a 3-D pin and a rotational lock at each of the four joints,
20 constraint components on 18 degrees of freedom). Causality closes both the translational
loop and the rotational loop of the locks; the out-of-plane components are redundant, dropped
and reported.

Answers from outside bgc: the independent Lagrange model of the four-bar
(tests/reference/fourbar_lagrange.py), the plane of the mechanism (X-Z, every joint axis Y:
out of the plane are the translations along Y and the rotations about X and Z), and the
velocity residuals of inconsistent variants computed here from the closed-form assembly.
"""
from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

import bgc  # noqa: E402
from bgc.base.errors import ModelError  # noqa: E402
from bgc.core.causality import assign_causality  # noqa: E402
from bgc.core.graph import build_graph  # noqa: E402
from bgc.format.parse import parse_file  # noqa: E402
from reference import fourbar_lagrange as fl  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
MODEL = ROOT / "tests" / "loops" / "fourbar_3dpins.yaml"
PINS = ("pivot1", "pivot2")  # the ground pins; the pins between rods are bonds
LOCKS = ("r1.lock", "r2.lock", "r3.lock", "r4.lock")  # O1, crank-coupler, coupler-rocker, O2
AXIS = 1  # every joint axis is frame 0's Y: the pins' component along it is out of the plane


def _run(m, t):
    return m.simulate((0.0, float(t[-1])), t_eval=t, method="Radau", rtol=1e-10, atol=1e-12)


def _against_reference(r, t):
    """Angles within 1e-6 rad, rates within 1e-5 rad/s of the Lagrange reference; nothing
    leaves the plane (within 1e-9)."""
    ref = fl.simulate(t)
    assert np.ptp(ref["th1"]) > 1.0  # the crank swings well
    for i in (1, 2, 3):
        th = np.unwrap(np.asarray(r.y[f"th{i}"]))  # atan2 of the rod's axis: wrapped
        assert np.abs(th - ref[f"th{i}"]).max() < 1e-6, i
        assert np.abs(np.asarray(r.y[f"w{i}"]) - ref[f"w{i}"]).max() < 1e-5, i
    assert np.abs(r.y["out_pos"]).max() < 1e-9
    assert np.abs(r.y["out_vel"]).max() < 1e-9


@pytest.fixture(scope="module")
def compiled_c():
    return bgc.compile(str(MODEL), target="c")


def test_both_loops_are_closed_by_constraints():
    """The four locks (each holds 2 of 3 components: partly determined) and one ground pin
    (the translational loop's closure) become constraints; the rods' translational momenta
    are dependent (the pins fix the rods' centres' velocities from their rotations)."""
    bg = build_graph(parse_file(MODEL))
    caus = assign_causality(bg, allow_derivative=True)
    assert set(caus.constraints) - set(PINS) == set(LOCKS)
    assert len(set(caus.constraints) & set(PINS)) == 1
    assert set(caus.derivative) == {"crank.It", "coupler.It", "rocker.It"}


def test_against_the_lagrange_reference_c(compiled_c):
    t = np.linspace(0.0, 5.0, 501)
    _against_reference(_run(compiled_c, t), t)


@pytest.mark.slow
def test_against_the_lagrange_reference_numpy(request):
    """The numpy module over the first 1 s (the C module above runs the whole 5 s): the crank
    swings through more than 1 rad there too (2.7 rad), and the bounds are the same.

    Where a C compiler works, the numpy module printed from the C fixture's compile (the C
    module's numpy twin, as bgc.run.driver.build hands it to the wrapper: the numpy
    printer's text of the same equations), not compiled a second time."""
    from bgc.api import CompiledModel
    from bgc.backends.c import build as cbuild

    if cbuild.available():
        c = request.getfixturevalue("compiled_c")
        m = CompiledModel(c.module._NUMPY_MODULE(), c.compiled, str(MODEL))
    else:
        m = bgc.compile(str(MODEL))
    assert not getattr(m.module, "C_LIBRARY", None)  # the numpy module, not the C wrapper
    t = np.linspace(0.0, 1.0, 101)
    _against_reference(_run(m, t), t)


def test_the_3d_pin_fourbar_runs_without_the_watch_warning(compiled_c):
    """bgc.run.watch (tests/test_loops_watch.py) on this model: the components dropped at the
    start are out of the plane, and nothing moves there, so a run gives no warning and their
    residuals stay at rounding level."""
    import warnings

    from bgc.run.watch import dropped_residuals

    m = compiled_c
    assert set(m.module.CONSTRAINT_DROPPED) == {"pivot1.q[1]", "r4.lock.q[0]", "r4.lock.q[1]"}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res = m.simulate((0.0, 2.0), t_eval=np.linspace(0.0, 2.0, 201), method="Radau",
                         rtol=1e-9, atol=1e-11)
    assert [str(w.message) for w in caught if issubclass(w.category, RuntimeWarning)] == []
    names, r = dropped_residuals(m.module, res[0], res[1])
    assert np.abs(r).max() < 1e-12  # out of the plane: nothing moves there


def test_check_reports_the_out_of_plane_components():
    """20 components on 18 degrees of freedom with mobility 1: rank 17, three redundant, and
    all out of the plane. The locks are kept from the ground outwards (r1, r2, r3 fix every
    rod's rotations about X and Z), so the lock that closes the chain of locks (r4, at O2)
    adds nothing, and neither does the pin's component along the joint axis Y."""
    from conftest import bgc_in_process

    out = bgc_in_process("check", str(MODEL))  # in-process
    assert out.returncode == 0, out.stderr
    text = out.stdout
    pin = re.search(r"constraint: Sf (pivot\d) ", text).group(1)
    comps = {src: n for src, n in re.findall(r"constraint: Sf (\S+) .*?, (\d) component", text)}
    assert comps == {pin: "3", **{lock: "2" for lock in LOCKS}}
    assert sum(map(int, comps.values())) + 3 * 3 == 20  # + the pins between rods (bonds)
    # out of the plane: every lock component (rotations about the rods' in-plane x and y
    # axes), and the pin's component along Y
    out_of_plane = {f"{lock}.q[{k}]" for lock in LOCKS for k in (0, 1)} | {f"{pin}.q[{AXIS}]"}
    line = re.search(r"redundant constraint components dropped \(reaction 0\): (.*)", text)
    dropped = set(line.group(1).split(", "))
    assert dropped <= out_of_plane and len(dropped) == 20 - 17
    assert dropped == {f"{pin}.q[{AXIS}]", "r4.lock.q[0]", "r4.lock.q[1]"}
    # each loop named, with its redundant components
    assert re.search(rf"loop \d through {pin}, pivot\d, rocker\.P, .*crank\.Q\n", text)
    assert f"redundant components: {pin}.q[{AXIS}]\n" in text
    assert "redundant components: r4.lock.q[0], r4.lock.q[1]\n" in text
    kept = re.search(r"coordinates kept independent: (.*)", text).group(1).split(", ")
    assert {f"{b}.Ir.p[{k}]" for b in ("crank", "coupler", "rocker") for k in range(3)} \
        <= set(kept)
    assert not any(".It." in k or ".q" in k for k in kept)


def _variant(old: str, new: str, param: str = "") -> str:
    text = MODEL.read_text()
    assert old in text
    text = text.replace(old, new)
    return text.replace("parameters:\n", f"parameters:\n{param}", 1) if param else text


def test_a_loop_with_no_flow_source_is_located(tmp_path):
    """The rods joined in a floating triangle (no ground pin: the rocker's P on the crank's Q):
    no flow source closes the translational loop; refused, located at a bond of the loop,
    with the advice."""
    text = _variant("  - {from: rocker.P, to: pivot2, n: 3}\n",
                    "  - {from: rocker.P, to: crank.Q, n: 3}\n")
    text = text.replace("  - {from: pivot1, to: crank.Q, n: 3}\n", "")
    text = re.sub(r"  pivot[12]: .*\n", "", text)
    f = tmp_path / "floating.yaml"
    f.write_text(text)
    out = subprocess.run([sys.executable, "-m", "bgc", "check", str(f)], capture_output=True,
                         text=True, timeout=600)
    assert out.returncode == 2 and "Traceback" not in out.stderr
    first = out.stderr.strip().splitlines()[0]
    where = re.match(rf"{re.escape(str(f))}:(\d+):(\d+): closed kinematic loop", first)
    assert where, first
    assert text.splitlines()[int(where.group(1)) - 1].startswith("  - {from: ")  # a bond
    assert "rocker.P" in first and "crank.Q" in first  # the loop, through the closing joint
    assert "Close the loop with one compliant coupling" in out.stderr


def test_an_inconsistent_rotation_is_located():
    """The second ground turning about X (an in-plane axis) at 0.5 rad/s: the lock at O2 is
    violated out of the plane. Its residual, in the rocker's frame (x along the rod at th3,
    y = (-sin th3, 0, cos th3)), is -(0.5, 0, 0) projected: (-0.5 cos th3, 0.5 sin th3)."""
    text = _variant('ground_w2: {type: Sf, flow: "[0, 0, 0]"}',
                    'ground_w2: {type: Sf, flow: "[spin, 0, 0]"}',
                    "  spin: {value: 0.5, unit: rad/s}\n")
    with pytest.raises(ModelError) as e:
        bgc.check(text)
    msg = e.value.message
    assert msg.startswith("element 'r4.lock' (from bgc:mechanics.spatial revolute_lock): "
                          "constraint 'r4.lock' closing the kinematic loop")
    assert "the initial velocities violate it" in msg
    res = [float(v) for v in msg.split("by [")[1].split("]")[0].split(",")]
    th3 = fl.FourBar().assemble(1.0)[2]
    assert np.allclose(res, [-0.5 * np.cos(th3), 0.5 * np.sin(th3)], rtol=1e-5)
    # at the instance `r4: {type: revolute_lock, ...}` in the user's model (one parameter line
    # added above it), not inside the library's file
    line = 1 + text.splitlines().index(next(ln for ln in text.splitlines()
                                            if ln.startswith("  r4: {type: revolute_lock")))
    assert (e.value.coord.line, e.value.coord.column) == (line, 3)
    assert str(e.value).startswith(f"<string>:{line}:3: element 'r4.lock' (from ")
    assert "\n" not in str(e.value)


def test_an_inconsistent_pin_is_located():
    """The second ground pin moving along the joint axis Y at 0.1 m/s (out of the plane):
    the translational closure's Y component is violated by exactly that; located at the pin
    that closes the loop, in the model's file."""
    text = _variant('pivot2: {type: Sf, flow: "[0, 0, 0]"}',
                    'pivot2: {type: Sf, flow: "[0, vy, 0]"}', "  vy: {value: 0.1, unit: m/s}\n")
    with pytest.raises(ModelError) as e:
        bgc.check(text)
    msg = e.value.message
    assert "the initial velocities violate it" in msg
    res = [float(v) for v in msg.split("by [")[1].split("]")[0].split(",")]
    assert np.allclose(np.abs(res), [0.0, 0.1, 0.0], atol=1e-12)
    assert e.value.coord.file == "<string>"
    assert re.match(r"  pivot[12]: ", text.splitlines()[e.value.coord.line - 1])


@pytest.mark.slow
def test_the_fmu_carries_the_3d_pin_fourbar(tmp_path, compiled_c):
    """Exported as FMI 2.0 (both kinds), validated by FMPy, and run under FMPy: Model Exchange
    (FMPy's CVode) and Co-Simulation (the unit's own solver) follow the C backend's run over
    2 s within 1e-6 rad. The unit carries the constrained ODE as it is (reactions, violation
    states, the dropped components' zero reactions)."""
    fmpy = pytest.importorskip("fmpy")
    from fmpy.validation import validate_fmu

    from bgc.run.fmu import export_fmu

    out = tmp_path / "fourbar_3dpins.fmu"
    if compiled_c.compiled is not None:  # packaged from the fixture's compile of the file:
        # export_fmu's own steps after its compile (the same unit, byte for byte)
        from bgc.backends.fmu.export import package_fmu
        from bgc.base.reach import run_inputs
        from bgc.base.store import Cache

        fmu = package_fmu(compiled_c.compiled, out, None, "both", None, Cache(),
                          inputs=run_inputs(MODEL, None))
    else:  # the fixture's module came from the compile cache: no compile to share
        fmu = export_fmu(MODEL, out, kind="both")
    assert validate_fmu(str(fmu)) == []
    t = np.linspace(0.0, 2.0, 201)
    ref = compiled_c.simulate((0.0, 2.0), t_eval=t, method="Radau", rtol=1e-11, atol=1e-13)
    assert np.ptp(np.unwrap(ref.y["th1"])) > 1.0  # the crank swings well
    for kind in ("ModelExchange", "CoSimulation"):
        r = fmpy.simulate_fmu(str(fmu), fmi_type=kind, stop_time=2.0, output_interval=0.01,
                              relative_tolerance=1e-9, output=["th1", "th2", "th3"])
        assert np.allclose(np.asarray(r["time"]), t, atol=1e-12)
        for i in (1, 2, 3):
            got = np.unwrap(np.asarray(r[f"th{i}"]))
            want = np.unwrap(np.asarray(ref.y[f"th{i}"]))
            assert np.abs(got - want).max() < 1e-6, (kind, i)
