"""The Python API: docs/api.md's examples (doctest), compiling from text and from a path,
errors as exceptions with locations, nothing left on disk, a light `import bgc`."""
from __future__ import annotations

import doctest
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest

import bgc

ROOT = Path(__file__).resolve().parents[1]


def test_docs_api_md_examples(monkeypatch):
    monkeypatch.chdir(ROOT)
    res = doctest.testfile(str(ROOT / "docs" / "api.md"), module_relative=False,
                           optionflags=doctest.NORMALIZE_WHITESPACE)
    assert res.attempted > 15 and res.failed == 0


def test_compile_from_text_and_path_agree_and_leave_nothing(tmp_path, monkeypatch):
    # /tmp is shared with other processes: give this one its own temporary directory
    own = tmp_path / "tmp"
    own.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(own))
    monkeypatch.setenv("TMPDIR", str(own))
    cwd_before = set(os.listdir(ROOT))
    text = (ROOT / "models" / "msd.yaml").read_text()
    a = bgc.compile(text)
    b = bgc.compile(ROOT / "models" / "msd.yaml")
    c = bgc.compile(str(ROOT / "models" / "msd.yaml"))
    assert a.STATE_NAMES == b.STATE_NAMES == c.STATE_NAMES
    x = np.array([0.3, -0.01])
    np.testing.assert_array_equal(a.rhs(0.0, x), b.rhs(0.0, x))
    # the closed form of the mass-spring-damper: m x'' = F0 - k x - c x'
    m, k, cc, F0 = 2.0, 200.0, 4.0, 10.0
    assert a.rhs(0.0, x)[0] == pytest.approx(F0 - k * x[1] - cc * x[0] / m)
    assert list(own.iterdir()) == [] and set(os.listdir(ROOT)) == cwd_before
    assert a.module.__file__.startswith("<bgc")


def test_compile_with_a_scene():
    mod = bgc.compile(ROOT / "models" / "msd.yaml", scene=ROOT / "models" / "scenes" /
                      "msd_step.yaml")
    assert set(mod.OUTPUT_NAMES) == {"position", "velocity"}
    with pytest.raises(bgc.BgcError) as ei:
        bgc.compile(ROOT / "models" / "dc_motor.yaml",
                    scene=ROOT / "models" / "scenes" / "msd_step.yaml")
    assert ei.value.coord.line == 3 and "msd.yaml" in ei.value.message


@pytest.mark.parametrize("text, line, col, words", [
    ("bgc: 1\nname: demo\nelements:\n  m: {type: Q}\nbonds: []\n", 4, None, "type"),
    ("bgc: 1\nname: demo\nparameters: {k: 1.0}\nelements:\n  c: {type: C, stiffness: \"k*\"}\n"
     "  j: {type: \"1\"}\nbonds: [[j, c]]\n", 5, None, "syntax"),
    ("bgc: 1\nname: [\n", 3, None, "YAML"),  # where the stream ends unclosed
])
def test_errors_raise_one_type_with_a_location(text, line, col, words):
    with pytest.raises(bgc.BgcError) as ei:
        bgc.compile(text)
    err = ei.value
    assert isinstance(err, bgc.ModelError) and err.coord.file == "<string>"
    assert err.coord.line == line and words.lower() in err.message.lower()


def test_missing_file_and_bad_target():
    with pytest.raises(bgc.BgcError) as ei:
        bgc.compile("no/such/model.yaml")
    assert ei.value.coord.file == "no/such/model.yaml"
    with pytest.raises(bgc.BgcError, match="unknown target"):
        bgc.compile(ROOT / "models" / "msd.yaml", target="fortran")


def test_check_reports_derivative_causality_as_data():
    res = bgc.check(ROOT / "models" / "bad" / "derivative_causality.yaml")
    assert not res.all_integral and res.derivative and res.diagnostics
    ok = bgc.check(ROOT / "models" / "dc_motor.yaml")
    assert ok.all_integral and ok.states == ("winding_L.p", "rotor.p")
    # every bond's effort is set by one of its two ends, the stroke sits at the other
    for b in ok.bonds:
        assert {b.effort_by, b.stroke_at} == {b.src, b.dst}
    with pytest.raises(Exception):
        res.states = ()  # frozen


def test_equations_match_the_hand_derived_dc_motor():
    import sympy as sp

    eq = bgc.equations(ROOT / "models" / "dc_motor.yaml")
    L, R, K, J, b = sp.symbols("L_a R_a K J_r b", real=True)
    lam, h, V, TL = sp.symbols("p_winding_L p_rotor u_V u_TL", real=True)
    i, w = lam / L, h / J
    want = sp.Matrix([V - R * i - K * w, K * i - b * w - TL])
    assert sp.simplify(eq.explicit() - want) == sp.zeros(2, 1)  # 2x2: small
    assert r"\dot{p_{rotor}}" in eq.latex()


def test_html_repr_escapes_model_text():
    from bgc.api import _html

    # a unit is parsed since issue 26: markup there is refused at its parameter...
    text = (ROOT / "models" / "msd.yaml").read_text().replace(
        "unit: kg", 'unit: "<script>alert(1)</script>"')
    with pytest.raises(bgc.BgcError, match="parameter 'm': unit '<script>"):
        bgc.compile(text)
    # ...and the table escapes whatever text it is given
    html = _html("bgc model msd", [("parameters", "m = 2.0 [<script>alert(1)</script>]")], None)
    assert "<script>" not in html and "&lt;script&gt;" in html
    html = bgc.compile(ROOT / "models" / "msd.yaml")._repr_html_()
    assert "mass.p" in html and "bgc model msd" in html and "m = 2.0 [kg]" in html


def test_import_bgc_is_light():
    code = ("import sys, bgc; heavy = [m for m in ('numpy', 'sympy', 'networkx', 'jinja2', "
            "'yaml', 'scipy', 'matplotlib') if m in sys.modules]; print(heavy); "
            "bgc.BgcError; print(callable(bgc.compile))")
    env = dict(os.environ, PYTHONPATH=str(ROOT / "src"))
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env,
                         timeout=120)
    assert out.stdout.split() == ["[]", "True"], out.stderr


def test_cli_equations_and_examples(bgc_cli, tmp_path):
    r = bgc_cli("equations", "models/msd.yaml", "--latex", "--explicit")
    assert r.returncode == 0 and r"\dot{q_{spring}} &= \frac{p_{mass}}{m}" in r.stdout
    r = bgc_cli("examples", str(tmp_path / "ex"))
    assert r.returncode == 0
    assert (tmp_path / "ex" / "models" / "quarter_car.yaml").read_text() == (
        ROOT / "models" / "quarter_car.yaml").read_text()
    assert (tmp_path / "ex" / "models" / "scenes" / "road_bump.csv").is_file()
    assert (tmp_path / "ex" / "docs" / "model-format.md").is_file()
    before = sorted(p.name for p in (tmp_path / "ex" / "models").iterdir())
    r = bgc_cli("examples", str(tmp_path / "ex"))
    assert r.returncode == 2 and "exist" in r.stderr and "Traceback" not in r.stderr
    assert sorted(p.name for p in (tmp_path / "ex" / "models").iterdir()) == before
    r = bgc_cli("linearize", "--help")
    assert "Example:" in r.stdout and "docs/" in r.stdout


def test_bond_graph_display(monkeypatch):
    """SVG through Graphviz when its `dot` is installed; without it no SVG, and the HTML
    summary still shows the model."""
    import shutil

    mod = bgc.compile(ROOT / "models" / "msd.yaml")
    svg = mod._repr_svg_()
    if shutil.which("dot"):
        assert svg.lstrip().startswith("<?xml") or "<svg" in svg
    else:
        assert svg is None
    monkeypatch.setattr(shutil, "which", lambda name: None)
    assert mod._repr_svg_() is None
    html = mod._repr_html_()
    assert "<svg" not in html and "spring.q" in html and "position" in html
    chk = bgc.check(ROOT / "models" / "msd.yaml")
    assert "digraph" in chk.dot and "bgc check msd" in chk._repr_html_()
