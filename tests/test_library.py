"""The component library (bgc/format/library, imported as ``from: "bgc:NAME"``).

Each component is checked in a small model against a closed form derived here by hand (free
motion under a constant force, harmonic and exponential responses, Kirchhoff's laws solved
by a root finder, the orifice and Hagen-Poiseuille laws, torque-free precession of an
axisymmetric body); each library file against strict units, its ports' declared domains
against the domains bgc's dimensional analysis infers; and the import's resolution against
everything that must not reach a user's file. Several independent sub-systems share one
model, so that each library file costs one compile.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import brentq

import bgc
from bgc.base.errors import ModelError
from bgc.core.graph import build_graph
from bgc.format import library
from bgc.format.catalogue import cardinality, load
from bgc.format.parse import parse_file, parse_text

HEAD = "bgc: 1\nname: {name}\nunits: strict\nimports: [{imports}]\n"


def _model(tmp_path_factory, name, imports, body):
    d = tmp_path_factory.mktemp(name)
    text = HEAD.format(name=name, imports=", ".join(f'{{from: "bgc:{i}"}}' for i in imports))
    (d / f"{name}.yaml").write_text(text + body)
    return bgc.compile(str(d / f"{name}.yaml"))


def _run(mod, t1, n=41, rtol=1e-10, **kw):
    t = np.linspace(0.0, t1, n)
    r = mod.simulate((0.0, t1), t_eval=t, rtol=rtol, atol=1e-12, **kw)
    return r.t, r.y


# ---------------------------------------------------------------------------------------------
# The import and the library's own consistency


def test_import_resolves_to_the_package_only(tmp_path):
    # a user's files named like the library, beside the model, are never read
    (tmp_path / "mechanics.translational.yaml").write_text("not: a model\n")
    (tmp_path / "bgc:mechanics.translational").write_text("not: a model\n")
    (tmp_path / "m.yaml").write_text(
        'bgc: 1\nname: m\nimports: [{from: "bgc:mechanics.translational"}]\n'
        "elements: {b: {type: mass}}\nbonds: []\n")
    model = parse_file(tmp_path / "m.yaml")
    assert model.component("mass") is not None


def test_the_compile_cache_keys_on_the_library_as_code(tmp_path):
    """A library import is no file of the user's (the run's reached files hold the model
    alone) and the library's files are part of bgc's code, which every cache key holds."""
    from bgc.base.paths import code_files
    from bgc.base.reach import reached_files

    (tmp_path / "m.yaml").write_text(
        'bgc: 1\nname: m\nimports: [{from: "bgc:thermal"}]\n'
        "elements: {h: {type: heat_capacity}, q: {type: heat_source}}\nbonds: [[q.p, h.T]]\n")
    reached = reached_files(tmp_path / "m.yaml")
    assert reached is not None and [r.path for r in reached] == [str(tmp_path / "m.yaml")]
    code = {name for name, _ in code_files()}
    assert {f"bgc/format/library/{n}.yaml" for n in library.names()} <= code


@pytest.mark.parametrize("spec, words", [
    ("bgc:../../base/x", "no such library"),
    ("bgc:/etc/passwd", "no such library"),
    ("bgc:nothing", "no such library"),
    ("bgc:Mechanics.Spatial", "no such library"),
    ("mechanics.spatial", "a library import reads 'bgc:NAME'"),
    ("./parts.yaml", "a library import reads 'bgc:NAME'"),
])
def test_bad_library_imports_are_located(spec, words):
    text = f'bgc: 1\nname: m\nimports:\n  - {{from: "{spec}"}}\nelements: {{}}\nbonds: []\n'
    with pytest.raises(ModelError) as e:
        parse_text(text, "m.yaml")
    assert str(e.value).startswith("m.yaml:4:")
    assert words in str(e.value)


def test_an_import_names_a_file_or_the_library_not_both():
    text = ('bgc: 1\nname: m\nimports:\n  - {from: "bgc:thermal", file: x.yaml}\n'
            "elements: {}\nbonds: []\n")
    with pytest.raises(ModelError, match=r"^m.yaml:4:5: an import names one of"):
        parse_text(text, "m.yaml")


def test_a_users_component_cannot_stand_in_for_the_librarys():
    text = ('bgc: 1\nname: m\nimports: [{from: "bgc:mechanics.translational"}]\n'
            "components:\n  mass:\n    ports: {p: v}\n    elements: {v: {type: \"1\"}}\n"
            "    bonds: []\nelements: {}\nbonds: []\n")
    with pytest.raises(ModelError, match=r"^m.yaml:5:3: component 'mass' is defined twice"):
        parse_text(text, "m.yaml")


def test_component_names_are_unique_across_the_library():
    seen = {}
    for name in library.names():
        for c in load(name).components:
            assert c.name not in seen, f"{c.name} in {name} and {seen[c.name]}"
            seen[c.name] = name
    assert len(seen) >= 40


#: the units of effort and flow of each port domain, and bgc check --units' name for it
DOMAIN = {"translation": ("N", "m/s", "mechanical translation"),
          "rotation": ("N*m", "rad/s", "mechanical rotation"),
          "electrical": ("V", "A", "electrical"),
          "hydraulic": ("Pa", "m^3/s", "hydraulic"),
          "thermal": ("K", "W", "thermal (temperature, heat flow)")}


def _harness(lib, comp):
    """A model holding one instance of ``comp`` with its defaults under strict units, each
    port bonded to a 0-junction of its own that holds a source of effort and a source of flow,
    the units of the port's declared domain: the dimensional analysis then checks the
    component's laws against the domains its ports declare, from both sides."""
    els, inputs, bonds = {"x": "{type: %s}" % comp.name}, [], []
    types = {e.name: e.type for e in comp.body.elements}
    seen = set()  # a two-port's first port takes the bond in, its second gives it out
    for i, (pname, target, _) in enumerate(comp.ports):
        e_unit, f_unit, _ = DOMAIN[comp.port_doc(pname)[0]]
        n = cardinality(comp, target)
        els[f"j{i}"] = '{type: "0"}'
        els[f"se{i}"] = '{type: Se, effort: "ue%d"}' % i
        els[f"sf{i}"] = '{type: Sf, flow: "uf%d"}' % i
        zero = f"{{default: {[0] * n if n > 1 else 0}, shape: {[n] if n > 1 else []}, unit: "
        inputs += [f"ue{i}: {zero}{e_unit!r}}}", f"uf{i}: {zero}{f_unit!r}}}"]
        into = types[target] in ("TF", "GY", "MTF", "MGY") and target not in seen
        seen.add(target)
        bonds += [(f"{{from: j{i}, to: x.{pname}, n: {n}}}" if into
                   else f"{{from: x.{pname}, to: j{i}, n: {n}}}"),
                  f"{{from: j{i}, to: se{i}, n: {n}}}", f"{{from: j{i}, to: sf{i}, n: {n}}}"]
    text = (HEAD.format(name="h", imports=f'{{from: "bgc:{lib}"}}')
            + f"inputs: {{{', '.join(inputs)}}}\nelements:\n"
            + "".join(f"  {k}: {v}\n" for k, v in els.items())
            + f"bonds: [{', '.join(bonds)}]\n")
    return parse_text(text, f"<{comp.name}>")


@pytest.mark.parametrize("lib", library.names())
def test_every_component_is_documented_and_checks_under_strict_units(lib):
    from bgc.core.units import check_units

    for comp in load(lib).components:
        assert comp.description and comp.laws, comp.name
        for p in comp.body.params:
            assert p.unit and p.description, f"{comp.name}.{p.name}"
        for pname, _, _ in comp.ports:
            domain, text = comp.port_doc(pname)
            assert domain in DOMAIN and text, f"{comp.name}.{pname}"
        # raises on a parameter without a unit (strict) or a law against a port's domain
        report = check_units(build_graph(_harness(lib, comp)))
        inside = [b for b in report.bonds if b.id.startswith("x.")]
        assert all(b.domain in {d[2] for d in DOMAIN.values()} for b in inside), comp.name


def test_a_port_against_its_law_is_caught():
    """The harness above can fail: a pump whose outlet is declared a translation."""
    comp = next(c for c in load("hydraulic").components if c.name == "pump")
    docs = tuple((p, "translation" if p == "p" else d, t) for p, d, t in comp.port_docs)
    from dataclasses import replace

    from bgc.core.units import check_units

    model = _harness("hydraulic", replace(comp, port_docs=docs))
    with pytest.raises(ModelError, match="TF 'x.TF': ratio 'D' is m\\^3"):
        check_units(build_graph(model))


def test_docs_library_md_is_what_the_script_writes():
    import importlib.util
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    spec = importlib.util.spec_from_file_location("library_docs",
                                                  root / "scripts" / "library_docs.py")
    script = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(script)
    assert (root / "docs" / "library.md").read_text(encoding="utf-8") == script.text(), \
        "docs/library.md is stale: run python scripts/library_docs.py"


def test_bgc_library_lists_and_shows_from_the_files_own_text():
    from click.testing import CliRunner

    from bgc.cli.commands import main

    run = CliRunner().invoke
    r = run(main, ["library"])
    assert r.exit_code == 0
    for name in library.names():
        assert f"bgc:{name}" in r.output
        for c in load(name).components:
            assert f"  {c.name} " in r.output
    r = run(main, ["library", "orifice"])
    assert r.exit_code == 0
    orifice = next(c for c in load("hydraulic").components if c.name == "orifice")
    text = " ".join(r.output.split())
    for p in orifice.body.params:
        assert f"{p.name} = " in text and f"[{p.unit}]: {p.description}" in text
    for law in orifice.laws:
        assert law in text
    assert "a (hydraulic): upstream side (bond into it)" in text
    # a hybrid component: its modes and events, guards and resets from the file's own text
    r = run(main, ["library", "ideal_diode"])
    diode = next(c for c in load("electrical").components if c.name == "ideal_diode")
    text = " ".join(r.output.split())
    assert r.exit_code == 0 and "Modes:" in text and "Events:" in text
    assert "on (initially on0): 1 conducting, 0 blocking" in text
    for ev in diode.events:
        assert f"{ev.name}: when {ev.condition.text} " in text and ev.description in text
    r = run(main, ["library", "switch"])
    assert "closing: at t = t_close, sets on = 1" in " ".join(r.output.split())
    r = run(main, ["library", "bgc:thermal"])
    assert r.exit_code == 0 and "heat_capacity (bgc:thermal)" in r.output
    r = run(main, ["library", "../../etc/passwd"])
    assert r.exit_code == 2
    assert r.output.strip().splitlines() == [
        "error: the library has no library or component named '../../etc/passwd' "
        "(bgc library lists them)"]


# ---------------------------------------------------------------------------------------------
# 1-D mechanics


TRANSLATIONAL = """
elements:
  F1: {type: force, F: 3.0}
  m1: {type: mass, m: 2.0}
  m2: {type: mass, m: 0.5}
  s2: {type: spring, k: 8.0, x0: 0.1}
  m3: {type: mass, m: 2.0, v0: 2.0}
  d3: {type: damper, d: 1.0}
  m4: {type: mass, m: 1.0, v0: 1.0}
  fr4: {type: friction, Fc: 0.5, vs: 1.0e-3}
  F5: {type: force, F: 3.0}
  lv5: {type: lever, n: 2.0}
  m5: {type: mass, m: 1.5}
  vs6: {type: velocity_source, v: 0.3}
  sd6: {type: spring_damper, k: 20.0, d: 2.0}
  m7: {type: mass, m: 1.0}
  sd7: {type: spring_damper, k: 25.0, d: 2.0, x0: 0.2}
bonds: [[F1.p, m1.p], [m2.p, s2.a], [m3.p, d3.a], [m4.p, fr4.a], [F5.p, lv5.a], [lv5.b, m5.p],
        [vs6.p, sd6.a], [m7.p, sd7.a]]
outputs:
  v1: {expr: "f(m1.I)", unit: m/s}
  x2: {expr: "q(s2.C)", unit: m}
  v3: {expr: "f(m3.I)", unit: m/s}
  v4: {expr: "f(m4.I)", unit: m/s}
  v5: {expr: "f(m5.I)", unit: m/s}
  x6: {expr: "q(sd6.C)", unit: m}
  F6: {expr: "e(sd6.J)", unit: N}
  x7: {expr: "q(sd7.C)", unit: m}
"""


@pytest.fixture(scope="module")
def translational(tmp_path_factory):
    mod = _model(tmp_path_factory, "trans", ["mechanics.translational"], TRANSLATIONAL)
    return _run(mod, 1.0)


def test_mass_under_a_force_and_a_lever(translational):
    t, y = translational
    assert np.allclose(y["v1"], 3.0 * t / 2.0, atol=1e-9)  # v = F t / m
    assert np.allclose(y["v5"], 3.0 * t / (2.0 * 1.5), atol=1e-9)  # F_b = F / n


def test_spring_mass_frequency(translational):
    t, y = translational
    assert np.allclose(y["x2"], 0.1 * np.cos(math.sqrt(8.0 / 0.5) * t), atol=1e-8)


def test_damper_decay_and_friction_deceleration(translational):
    t, y = translational
    assert np.allclose(y["v3"], 2.0 * np.exp(-t / 2.0), atol=1e-8)
    # sliding far above vs: tanh = 1 to 1e-300, so the deceleration is Fc / m
    assert np.allclose(y["v4"], 1.0 - 0.5 * t, atol=1e-8)


def test_spring_damper_driven_and_free(translational):
    t, y = translational
    assert np.allclose(y["x6"], 0.3 * t, atol=1e-9)
    assert np.allclose(y["F6"], 20.0 * 0.3 * t + 2.0 * 0.3, atol=1e-7)
    w0, zeta = 5.0, 2.0 / (2 * math.sqrt(25.0 * 1.0))
    wd = w0 * math.sqrt(1 - zeta**2)
    x = 0.2 * np.exp(-zeta * w0 * t) * (np.cos(wd * t) + zeta / math.sqrt(1 - zeta**2)
                                         * np.sin(wd * t))
    assert np.allclose(y["x7"], x, atol=1e-8)


ROTATIONAL = """
elements:
  T1: {type: torque, T: 0.6}
  J1: {type: inertia, J: 0.2}
  J2: {type: inertia, J: 0.02}
  k2: {type: torsion_spring, k: 2.0, phi0: 0.05}
  J3: {type: inertia, J: 0.5, w0: 4.0}
  d3: {type: rotational_damper, d: 0.25}
  J4: {type: inertia, J: 0.1, w0: 3.0}
  f4: {type: rotational_friction, Tc: 0.2, ws: 1.0e-3}
  T5: {type: torque, T: 0.6}
  g5: {type: gear, n: 4.0}
  J5: {type: inertia, J: 0.8}
  T6: {type: torque, T: 0.2}
  rp6: {type: rack_pinion, r: 0.05}
  m6: {type: mass, m: 2.0}
  w7: {type: speed_source, omega: 1.5}
  k7: {type: torsion_spring, k: 3.0}
bonds: [[T1.w, J1.w], [J2.w, k2.a], [J3.w, d3.a], [J4.w, f4.a], [T5.w, g5.a], [g5.b, J5.w],
        [T6.w, rp6.a], [rp6.b, m6.p], [w7.w, k7.a]]
outputs:
  w1: {expr: "f(J1.I)", unit: rad/s}
  phi2: {expr: "q(k2.C)", unit: rad}
  w3: {expr: "f(J3.I)", unit: rad/s}
  w4: {expr: "f(J4.I)", unit: rad/s}
  w5: {expr: "f(J5.I)", unit: rad/s}
  w5_in: {expr: "f(T5.Se)", unit: rad/s}
  v6: {expr: "f(m6.I)", unit: m/s}
  phi7: {expr: "q(k7.C)", unit: rad}
  T7: {expr: "e(k7.C)", unit: N*m}
"""


@pytest.fixture(scope="module")
def rotational(tmp_path_factory):
    mod = _model(tmp_path_factory, "rot", ["mechanics.rotational", "mechanics.translational"],
                 ROTATIONAL)
    return _run(mod, 1.0)


def test_inertia_spring_damper_friction(rotational):
    t, y = rotational
    assert np.allclose(y["w1"], 0.6 * t / 0.2, atol=1e-9)
    assert np.allclose(y["phi2"], 0.05 * np.cos(10.0 * t), atol=1e-8)
    assert np.allclose(y["w3"], 4.0 * np.exp(-0.25 * t / 0.5), atol=1e-8)
    assert np.allclose(y["w4"], 3.0 - 0.2 * t / 0.1, atol=1e-8)


def test_gear_ratio_and_rack_pinion(rotational):
    t, y = rotational
    assert np.allclose(y["w5"], 4.0 * 0.6 * t / 0.8, atol=1e-9)  # T_out = n T_in
    assert np.allclose(y["w5_in"], 4.0 * y["w5"], atol=1e-9)  # omega_in = n omega_out
    assert np.allclose(y["v6"], (0.2 / 0.05) * t / 2.0, atol=1e-9)  # F = T / r
    assert np.allclose(y["phi7"], 1.5 * t, atol=1e-9)
    assert np.allclose(y["T7"], 3.0 * 1.5 * t, atol=1e-8)


# ---------------------------------------------------------------------------------------------
# Electrical

ELECTRICAL = """
elements:
  vs1: {type: voltage_source, V: 5.0}
  r1: {type: resistor, R: 1000.0}
  c1: {type: capacitor, C: 1.0e-4}
  vs2: {type: voltage_source, V: 2.0}
  r2: {type: resistor, R: 10.0}
  l2: {type: inductor, L: 0.5}
  c3: {type: capacitor, C: 1.0e-3, v0: 1.0}
  l3: {type: inductor, L: 0.1}
  vs4: {type: voltage_source, V: 10.0}
  tr4: {type: transformer, n: 3.0}
  r4: {type: resistor, R: 50.0}
  vs5: {type: voltage_source, V: 5.0}
  r5: {type: resistor, R: 1000.0}
  d5: {type: diode}
  vs6: {type: voltage_source, V: 12.0}
  mot6: {type: dc_motor}
  is7: {type: current_source, I: 2.0e-3}
  c7: {type: capacitor, C: 1.0e-3}
bonds: [[vs1.p, r1.p], [r1.n, c1.p], [vs2.p, r2.p], [r2.n, l2.p], [c3.n, l3.p],
        [vs4.p, tr4.p1], [tr4.p2, r4.p], [vs5.p, r5.p], [r5.n, d5.p], [vs6.p, mot6.p],
        [is7.p, c7.p]]
outputs:
  v1: {expr: "e(c1.c)", unit: V}
  i2: {expr: "f(l2.l)", unit: A}
  v3: {expr: "e(c3.c)", unit: V}
  i4: {expr: "f(r4.r)", unit: A}
  i4_in: {expr: "f(vs4.Se)", unit: A}
  i5: {expr: "f(d5.D)", unit: A}
  w6: {expr: "f(mot6.jm)", unit: rad/s}
  v7: {expr: "e(c7.c)", unit: V}
"""


@pytest.fixture(scope="module")
def electrical(tmp_path_factory):
    mod = _model(tmp_path_factory, "elec", ["electrical"], ELECTRICAL)
    return _run(mod, 0.3, n=31, method="Radau")


def test_rc_rl_lc(electrical):
    t, y = electrical
    assert np.allclose(y["v1"], 5.0 * (1 - np.exp(-t / 0.1)), atol=1e-7)
    assert np.allclose(y["i2"], 2.0 / 10.0 * (1 - np.exp(-10.0 * t / 0.5)), atol=1e-8)
    assert np.allclose(y["v3"], np.cos(t / math.sqrt(0.1 * 1.0e-3)), atol=1e-6)
    assert np.allclose(y["v7"], 2.0e-3 * t / 1.0e-3, atol=1e-9)


def test_transformer_and_diode_operating_point(electrical):
    _, y = electrical
    assert np.allclose(y["i4"], 3.0 * 10.0 / 50.0, rtol=1e-12)  # v2 = n v1
    assert np.allclose(y["i4_in"], 3.0 * y["i4"], rtol=1e-12)  # i1 = n i2
    Is, Vt = 1.0e-12, 0.025852
    i = brentq(lambda i: 1000.0 * i + Vt * math.log(i / Is + 1) - 5.0, 0.0, 5.0e-3, xtol=1e-15)
    assert np.allclose(y["i5"], i, rtol=1e-9)


def test_dc_motor_steady_speed(electrical):
    _, y = electrical
    Ra, k, bm = 1.0, 0.05, 1.0e-6
    assert y["w6"][-1] == pytest.approx(k * 12.0 / (Ra * bm + k**2), rel=1e-6)


# ---------------------------------------------------------------------------------------------
# Hydraulics and heat

HYDRAULIC = """
elements:
  q1: {type: flow_source, Q: 2.0e-5}
  ch1: {type: chamber, V: 1.0e-3, beta: 1.0e+9}
  ps2: {type: pressure_source, P: 4.0e+6}
  or2: {type: orifice}
  ch3: {type: chamber, V: 1.0e-2, beta: 1.0e+9, p0: 1.0e+7}
  or3: {type: orifice, A: 1.0e-6}
  ps4: {type: pressure_source, P: 1.0e+6}
  cy4: {type: cylinder, A: 2.0e-3}
  m4: {type: mass, m: 100.0}
  w5: {type: speed_source, omega: 100.0}
  pu5: {type: pump, D: 1.0e-6}
  ch5: {type: chamber, V: 1.0e-3, beta: 1.0e+9}
  ps6: {type: pressure_source, P: 1.0e+5}
  pi6: {type: pipe}
  tk7: {type: tank, A: 1.0, h0: 2.0}
  rs7: {type: restriction, Rh: 3000.0}
  tk8: {type: tank, A: 0.5}
bonds: [[q1.p, ch1.p], [ps2.p, or2.a], [ch3.p, or3.a], [ps4.p, cy4.p], [cy4.rod, m4.p],
        [w5.w, pu5.shaft], [pu5.p, ch5.p], [ps6.p, pi6.a], [tk7.p, rs7.a], [rs7.b, tk8.p]]
outputs:
  p1: {expr: "e(ch1.C)", unit: Pa}
  Q2: {expr: "f(or2.R)", unit: m^3/s}
  p3: {expr: "e(ch3.C)", unit: Pa}
  v4: {expr: "f(m4.I)", unit: m/s}
  F4: {expr: "e(m4.I)", unit: N}
  p5: {expr: "e(ch5.C)", unit: Pa}
  Q6: {expr: "f(pi6.I)", unit: m^3/s}
  p7: {expr: "e(tk7.N)", unit: Pa}
  p8: {expr: "e(tk8.N)", unit: Pa}
  Q7: {expr: "f(rs7.R)", unit: m^3/s}
"""


@pytest.fixture(scope="module")
def hydraulic(tmp_path_factory):
    mod = _model(tmp_path_factory, "hyd", ["hydraulic", "mechanics.translational",
                                           "mechanics.rotational"], HYDRAULIC)
    return _run(mod, 0.5, method="Radau")


def test_chamber_build_up_and_pump(hydraulic):
    t, y = hydraulic
    assert np.allclose(y["p1"], 1.0e9 * 2.0e-5 * t / 1.0e-3, rtol=1e-9, atol=1e-3)
    assert np.allclose(y["p5"], 1.0e9 * 1.0e-6 * 100.0 * t / 1.0e-3, rtol=1e-9, atol=1e-3)


def test_orifice_flow_and_tank_drain(hydraulic):
    t, y = hydraulic
    Cd, A, rho, dpt = 0.61, 1.0e-5, 850.0, 1.0e3
    dp = 4.0e6
    exact = Cd * A * math.sqrt(2 * dp / rho)  # the square-root law
    assert np.allclose(y["Q2"], exact, rtol=(dpt / dp) ** 2)  # regularised below dp_t only
    # a chamber draining through an orifice: sqrt(p) falls linearly (p >> dp_t throughout)
    c = Cd * 1.0e-6 * math.sqrt(2 / rho)
    sq = math.sqrt(1.0e7) - 1.0e9 * c / (2 * 1.0e-2) * t
    assert sq[-1] > 30 * math.sqrt(dpt)
    assert np.allclose(np.sqrt(y["p3"]), sq, rtol=1e-5)


def test_cylinder_force_and_pipe(hydraulic):
    t, y = hydraulic
    assert np.allclose(y["F4"], 1.0e6 * 2.0e-3, rtol=1e-12)  # F = p A
    assert np.allclose(y["v4"], 1.0e6 * 2.0e-3 * t / 100.0, atol=1e-9)
    L, d, mu, rho = 1.0, 0.01, 0.03, 850.0
    R, ind = 128 * mu * L / (math.pi * d**4), rho * L / (math.pi * d**2 / 4)
    assert np.allclose(y["Q6"], 1.0e5 / R * (1 - np.exp(-R * t / ind)), rtol=1e-7, atol=1e-12)


def test_two_tanks_level_out_through_a_restriction(hydraulic):
    """Two open tanks (areas A1, A2) joined by a linear restriction Rh: the level difference
    d = h1 - h2 obeys d' = -(rho g / Rh)(1/A1 + 1/A2) d, so it decays as exp(-t/tau) with
    tau = Rh A1 A2 / (rho g (A1 + A2)), towards the common level A1 h0 / (A1 + A2) (the
    volume is kept); the bottom pressures are rho g h and the flow is their drop over Rh."""
    t, y = hydraulic
    rho, g, A1, A2, h0, Rh = 1000.0, 9.81, 1.0, 0.5, 2.0, 3000.0
    tau = Rh * A1 * A2 / (rho * g * (A1 + A2))
    d = h0 * np.exp(-t / tau)
    h_end = A1 * h0 / (A1 + A2)
    assert np.allclose(y["p7"], rho * g * (h_end + d * A2 / (A1 + A2)), rtol=1e-8)
    assert np.allclose(y["p8"], rho * g * (h_end - d * A1 / (A1 + A2)), rtol=1e-8, atol=1e-6)
    assert np.allclose(y["Q7"], (y["p7"] - y["p8"]) / Rh, rtol=1e-12, atol=1e-15)
    assert np.allclose(y["Q7"], rho * g * d / Rh, rtol=1e-8, atol=1e-12)


THERMAL = """
elements:
  h1: {type: heat_capacity, Cth: 500.0, T0: 350.0}
  g1: {type: conductance, G: 2.0}
  amb1: {type: temperature_source, T: 300.0}
  h2: {type: heat_capacity, Cth: 200.0, T0: 300.0}
  q2: {type: heat_source, Q: 50.0}
  h3: {type: heat_capacity, Cth: 100.0, T0: 400.0}
  cv3: {type: convection, h: 25.0, A: 0.2}
  amb3: {type: temperature_source, T: 290.0}
bonds: [[h1.T, g1.a], [g1.b, amb1.p], [q2.p, h2.T], [h3.T, cv3.a], [cv3.b, amb3.p]]
outputs:
  T1: {expr: "e(h1.C)", unit: K}
  T2: {expr: "e(h2.C)", unit: K}
  T3: {expr: "e(h3.C)", unit: K}
"""


def test_thermal_capacity_conductance_convection(tmp_path_factory):
    mod = _model(tmp_path_factory, "therm", ["thermal"], THERMAL)
    t, y = _run(mod, 400.0)
    assert np.allclose(y["T1"], 300.0 + 50.0 * np.exp(-2.0 * t / 500.0), atol=1e-7)
    assert np.allclose(y["T2"], 300.0 + 50.0 * t / 200.0, atol=1e-7)
    assert np.allclose(y["T3"], 290.0 + 110.0 * np.exp(-25.0 * 0.2 * t / 100.0), atol=1e-7)


# ---------------------------------------------------------------------------------------------
# Planar and spatial mechanics

PLANAR = """
parameters:
  eps: {value: 0.01, unit: rad, description: initial swing}
  F3: {value: 0.5, unit: N, description: push along the rail}
elements:
  ground1: {type: Sf, flow: "[0, 0]"}
  pin1: {type: pin}
  rod1: {type: planar_rod, m: 1.2, l: 0.8, th0: "-pi / 2 + eps"}
  tip1: {type: Se, effort: "[0, 0]"}
  rod2: {type: planar_rod, m: 1.2, l: 0.8, th0: "-pi / 2 + eps"}
  pin2: {type: pin_compliant, k: 1.0e+5, r: 300.0}
  tip2: {type: Se, effort: "[0, 0]"}
  rod3: {type: planar_rod, m: 2.0, l: 0.5, g: 0.0}
  rail3: {type: prismatic_compliant}
  push3: {type: Se, effort: "[F3, 0]"}
bonds:
  - {from: ground1, to: pin1.a, n: 2}
  - {from: pin1.b, to: rod1.A, n: 2}
  - {from: tip1, to: rod1.B, n: 2}
  - {from: rod2.A, to: pin2.a, n: 2}
  - {from: tip2, to: rod2.B, n: 2}
  - {from: rod3.A, to: rail3.a, n: 2}
  - [rod3.w, rail3.wa]
  - {from: push3, to: rod3.B, n: 2}
outputs:
  th1: {expr: "rod1.th", unit: rad}
  th2: {expr: "rod2.th", unit: rad}
  th3: {expr: "rod3.th", unit: rad}
  v3: {expr: "f(rod3.It)", unit: m/s}
"""


@pytest.mark.slow
def test_planar_rod_pendulum_and_prismatic_rail(tmp_path_factory):
    mod = _model(tmp_path_factory, "planar", ["mechanics.planar"], PLANAR)
    omega = math.sqrt(3 * 9.81 / (2 * 0.8))  # rod on a pivot at one end: J_A = m l^2 / 3
    t, y = _run(mod, 2 * 2 * math.pi / omega, method="LSODA", rtol=1e-9)
    swing = -math.pi / 2 + 0.01 * np.cos(omega * t)  # small angles: amplitude^2 / 16 = 6e-6
    assert np.allclose(y["th1"], swing, atol=2e-6)  # the rigid pin
    assert np.allclose(y["th2"], swing, atol=3e-5)  # the compliant one (1e5 N/m)
    # a rod sliding along a rail on the x axis, pushed along it: v = F t / m, no rotation
    assert np.allclose(y["v3"][0], 0.5 * t / 2.0, atol=1e-9)
    assert np.allclose(y["v3"][1], 0.0, atol=1e-9)
    assert np.allclose(y["th3"], 0.0, atol=1e-9)


SPATIAL = """
parameters:
  eps: {value: 0.02, unit: rad, description: initial swing}
  lp: {value: 0.3, unit: m, description: the pendulum's length}
  lt: {value: 0.2, unit: m, description: the twisting rod's length}
  Rtilt: "[[sin(eps), -cos(eps), 0], [0, 0, 1], [-cos(eps), -sin(eps), 0]]"
  Rhang: "[[0, -1, 0], [0, 0, 1], [-1, 0, 0]]"
  vpull: {value: 0.02, unit: m/s, description: the drive coupling's pull}
elements:
  free: {type: rigid_rod, m: 1.0, l: 0.1, rho: 0.02, g: 0.0}
  freeQ: {type: Se, effort: "[0, 0, 0]"}
  freeP: {type: Se, effort: "[0, 0, 0]"}
  pend: {type: rigid_rod, m: 0.8, l: lp, rho: 0.01, R0: Rtilt,
         rC0: "lp / 2 * [sin(eps), 0, -cos(eps)]"}
  pendP: {type: Se, effort: "[0, 0, 0]"}
  pendT: {type: translational_coupling, k: 1.0e+6, r: 200.0}
  pendR: {type: rotational_coupling, Rd: pend.R}
  tors: {type: rigid_rod, m: 1.0, l: lt, rho: 0.05, R0: Rhang, rC0: "[0, 0, -lt / 2]"}
  torsP: {type: Se, effort: "[0, 0, 0]"}
  torsT: {type: translational_coupling, k: 1.0e+6, r: 200.0}
  torsR: {type: rotational_coupling, k: 0.1, r: 0.0, Rd: tors.R}
  pull: {type: Sf, flow: "[0, vpull, 0]"}
  pullc: {type: drive_coupling}
bonds:
  - {from: freeQ, to: free.Q, n: 3}
  - {from: freeP, to: free.P, n: 3}
  - {from: pend.Q, to: pendT.a, n: 3}
  - {from: pendP, to: pend.P, n: 3}
  - {from: pend.w, to: pendR.a, n: 3}
  - {from: tors.Q, to: torsT.a, n: 3}
  - {from: torsP, to: tors.P, n: 3}
  - {from: tors.w, to: torsR.a, n: 3}
  - {from: pull, to: pullc.a, n: 3}
outputs:
  axis: {expr: "free.R[:, 0]", unit: "-"}
  h: {expr: "p(free.Ir)", unit: kg*m^2/s}
  energy: {expr: "(dot(p(free.Ir), f(free.Ir)) + dot(p(free.It), f(free.It))) / 2", unit: J}
  rC: {expr: "free.rC", unit: m}
  swing: {expr: "atan2(pend.R[0, 0], -pend.R[2, 0])", unit: rad}
  twist: {expr: "q(torsR.C)[0]", unit: rad}
  pull_force: {expr: "e(pullc.J)", unit: N}
"""


@pytest.mark.slow
def test_spatial_rigid_rod_free_pendulum_and_torsion(tmp_path_factory):
    mod = _model(tmp_path_factory, "spatial", ["mechanics.spatial"], SPATIAL)
    names = list(mod.STATE_NAMES)
    x0 = np.array(mod.initial_state(), dtype=float)
    # the free rod: spin about its axis and about y (frame 0 = body frame at t = 0), and a drift
    m, l, rho = 1.0, 0.1, 0.02
    Ixx, Iyy = m * rho**2 / 2, m * (3 * rho**2 + l**2) / 12
    h0 = np.array([Ixx * 30.0, Iyy * 4.0, 0.0])
    p0 = m * np.array([0.1, 0.0, -0.2])
    x0[names.index("free.Ir.p[0]"):names.index("free.Ir.p[0]") + 3] = h0
    x0[names.index("free.It.p[0]"):names.index("free.It.p[0]") + 3] = p0
    # the torsion rod: spinning about its own (vertical) axis, Omega0 = 0.5 rad/s
    rho_t = 0.05
    Ixx_t = 1.0 * rho_t**2 / 2
    i = names.index("tors.Ir.p[0]")
    x0[i:i + 3] = [0.0, 0.0, -Ixx_t * 0.5]  # body x is -z of frame 0
    T = 2 * math.pi * math.sqrt((0.8 * 0.3**2 / 3 + 0.8 * 0.01**2 / 4) / (0.8 * 9.81 * 0.15))
    t, y = _run(mod, 2 * T, n=61, x0=x0, method="LSODA", rtol=1e-9)
    # torque-free axisymmetric body: the symmetry axis turns about h at |h| / I_perp
    hn = np.linalg.norm(h0)
    k = h0 / hn
    e0 = np.array([1.0, 0.0, 0.0])
    ang = hn / Iyy * t[:, None]
    rot = (e0 * np.cos(ang) + np.cross(k, e0) * np.sin(ang)
           + k * np.dot(k, e0) * (1 - np.cos(ang)))
    assert np.allclose(y["axis"].T, rot, atol=1e-6)
    assert np.allclose(y["h"].T, h0, atol=1e-15)  # angular momentum: no torque acts
    e_exact = (h0[0]**2 / Ixx + h0[1]**2 / Iyy + p0 @ p0 / m) / 2
    assert np.allclose(y["energy"], e_exact, rtol=1e-7)
    assert np.allclose(y["rC"].T, t[:, None] * p0 / m, atol=1e-9)
    # the compliant revolute pendulum: I_Q = Iyy + m (l/2)^2 against m g l / 2
    assert np.allclose(y["swing"], 0.02 * np.cos(2 * math.pi * t / T), atol=2e-5)
    # the torsion about the joint's stiff x axis: I_xx phi'' = -k phi
    wt = math.sqrt(0.1 / Ixx_t)
    assert np.allclose(y["twist"], 0.5 / wt * np.sin(wt * t), atol=1e-6)
    # the drive coupling against the ground, pulled at a constant speed: F = k v t + r v
    assert np.allclose(y["pull_force"][1], 1.0e5 * 0.02 * t + 5.0 * 0.02, rtol=1e-9)
    assert np.allclose(y["pull_force"][[0, 2]], 0.0, atol=1e-12)


# ---------------------------------------------------------------------------------------------
# The 3R2S built from the library against the file it replaced (tests/data), which defined
# its own rigid body and couplings: the same module, state for state.


@pytest.mark.slow
def test_3r2s_from_the_library_equals_the_hand_written_model(gen):
    """models/3r2s.yaml (which imports its parts from the library) as its golden module,
    generated/mech3r2s.py (test_golden holds it equal to what compiling the model gives; the
    session imports it anyway), against the hand-written model compiled here."""
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    new = gen("mech3r2s")
    old = bgc.compile(str(root / "tests" / "data" / "3r2s_before_library.yaml"))
    assert sorted(new.STATE_NAMES) == sorted(old.STATE_NAMES)
    assert new.PARAM_DEFAULTS.keys() == old.PARAM_DEFAULTS.keys()
    for k, v in old.PARAM_DEFAULTS.items():
        assert np.array_equal(np.asarray(new.PARAM_DEFAULTS[k]), np.asarray(v)), k
    assert new.OUTPUT_NAMES == old.OUTPUT_NAMES
    order = [list(old.STATE_NAMES).index(s) for s in new.STATE_NAMES]  # old index of each new
    rng = np.random.default_rng(26)
    x0 = np.asarray(old.initial_state(), dtype=float)
    assert np.array_equal(np.asarray(new.initial_state(), dtype=float), x0[order])
    for _ in range(5):
        t = float(rng.uniform(0.0, 10.0))
        x_old = x0 + rng.normal(scale=1e-3, size=x0.shape)  # off the initial pose, R not unitary
        x_new = x_old[order]
        u = {"vd": (lambda t, a=rng.normal(scale=0.1, size=3): a)}
        f_old, f_new = old.rhs(t, x_old, u=u), new.rhs(t, x_new, u=u)
        scale = np.abs(f_old).max()
        assert np.abs(np.asarray(f_new) - np.asarray(f_old)[order]).max() <= 1e-12 * scale
        j_old = np.asarray(old.jacobian(t, x_old, u=u))[np.ix_(order, order)]
        j_new = np.asarray(new.jacobian(t, x_new, u=u))
        assert np.abs(j_new - j_old).max() <= 1e-12 * np.abs(j_old).max()
        y_old, y_new = old.outputs(t, x_old, u=u), new.outputs(t, x_new, u=u)
        for k in old.OUTPUT_NAMES:
            assert np.allclose(y_new[k], y_old[k], rtol=1e-12, atol=0), k
