"""Table inputs: CSV data compiled into the module as numbers; interpolation checked against
independent formulas and scipy, a bump from a table against the same bump as an expression,
and the validation of file, size and shape with located errors."""
from __future__ import annotations

import ast
import os

import numpy as np
import pytest
from conftest import seed_c_runtime

from bgc.base.errors import ModelError
from bgc.format.scene import parse_scene
from bgc.run.runner import compile_scene, run_scene

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
QC = os.path.join(ROOT, "models", "quarter_car.yaml")
K_T = 160000.0


def _scene(tmp_path, inputs: str, extra: str = "", name="s.yaml"):
    path = tmp_path / name
    path.write_text(f"bgc_scene: 1\nmodel: {QC}\nduration: 2.0\ninputs:\n  zr: {inputs}\n"
                    f"solver: {{method: Radau, rtol: 1.0e-8, atol: 1.0e-10, dt: 0.01}}\n{extra}")
    return path


def _csv(tmp_path, rows, header="time,height", name="road.csv"):
    text = (header + "\n" if header else "") + "".join(f"{a},{b}\n" for a, b in rows)
    (tmp_path / name).write_text(text)
    return name


def _road(mod, t):
    """The road height the module sees: tyre force at x = 0 is -k_t z_r."""
    y = mod.outputs(np.asarray(t, dtype=float), np.zeros(4))
    return -np.asarray(y["tyre_force"]) / K_T


KNOTS = [(0.0, 0.0), (0.2, 0.01), (0.45, 0.04), (0.5, 0.03), (0.9, -0.02), (1.3, 0.0)]


def test_linear_pchip_previous_against_independent_formulas(tmp_path):
    from scipy.interpolate import PchipInterpolator

    csv = _csv(tmp_path, KNOTS)
    tk, vk = np.array(KNOTS).T
    tq = np.linspace(-0.3, 1.6, 97)
    for interp in ("linear", "pchip", "previous"):
        sc = parse_scene(_scene(tmp_path, f"{{table: {csv}, columns: [time, height], "
                                          f"interp: {interp}}}", name=f"{interp}.yaml"))
        _, mod = compile_scene(sc)
        got = _road(mod, tq)
        tc = np.clip(tq, tk[0], tk[-1])  # extrapolate: hold
        if interp == "linear":
            i = np.clip(np.searchsorted(tk, tc) - 1, 0, len(tk) - 2)
            want = vk[i] + (vk[i + 1] - vk[i]) * (tc - tk[i]) / (tk[i + 1] - tk[i])
            assert list(mod.TABLE_BREAKPOINTS["zr"]) == list(tk)
        elif interp == "pchip":
            want = PchipInterpolator(tk, vk)(tc)
            assert "zr" not in mod.TABLE_BREAKPOINTS  # C1: no breakpoints needed
        else:
            want = np.array([vk[np.nonzero(tk <= s)[0][-1]] for s in tc])
        np.testing.assert_allclose(got, want, atol=1e-15, err_msg=interp)


def test_table_bump_matches_the_expression_bump(tmp_path):
    """A triangular bump (0.5..0.7 s, 5 cm) as a linear table and as an expression, both from
    the static equilibrium: the runs agree to the solver's tolerance."""
    csv = _csv(tmp_path, [(0.0, 0.0), (0.5, 0.0), (0.6, 0.05), (0.7, 0.0), (2.0, 0.0)])
    a = run_scene(_scene(tmp_path, f"{{table: {csv}, columns: [time, height]}}",
                         "initial: equilibrium\n", "a.yaml"))
    b = run_scene(_scene(tmp_path, '"0.05*max(0, 1 - abs(t - 0.6)/0.1)"',
                         "initial: equilibrium\nbreakpoints: [0.5, 0.6, 0.7]\n", "b.yaml"))
    assert np.array_equal(a.t, b.t)
    zs = a.y["body_height"]
    assert np.ptp(zs) > 0.01  # the bump moved the body by centimetres
    np.testing.assert_allclose(zs, b.y["body_height"], atol=1e-7)
    np.testing.assert_allclose(a.y["tyre_force"], b.y["tyre_force"], rtol=1e-6, atol=1e-3)
    # before the bump the car sits still at its static deflection
    before = a.t < 0.5
    assert np.ptp(zs[before]) < 1e-9


def test_table_data_reaches_the_module_as_numbers_only(tmp_path):
    csv = _csv(tmp_path, [(0.0, 1.5), (1.0, -2.25)], header='time,"h""); import os #"')
    sc = parse_scene(_scene(tmp_path, f"{{table: {csv}, columns: [0, 1]}}"))
    c, mod = compile_scene(sc)
    line = next(ln for ln in c.source.splitlines() if ln.strip().startswith("(np.array("))
    for arg in ast.parse(line.strip().rstrip(",")).body[0].value.elts:
        assert ast.literal_eval(arg.args[0]) in ([0.0, 1.0], [1.5, -2.25])
    assert "import os" not in c.source
    np.testing.assert_allclose(_road(mod, [0.0, 0.5, 2.0]), [1.5, -0.375, -2.25])


def test_extrapolate_error_raises_outside_the_table(tmp_path):
    csv = _csv(tmp_path, [(0.0, 0.0), (1.0, 1.0)])
    _, mod = compile_scene(parse_scene(_scene(
        tmp_path, f"{{table: {csv}, columns: [time, height], extrapolate: error}}")))
    assert _road(mod, 0.5) == pytest.approx(0.5)
    with pytest.raises(ValueError, match="outside its table"):
        _road(mod, 1.5)


def test_model_level_table_input(tmp_path):
    from bgc.backends.load import load_module
    from bgc.run.driver import compile_file

    text = open(QC).read().replace('zr: {default: "0", shape: [], unit: m}',
                                   "zr: {table: road.csv, columns: [time, height], unit: m}")
    (tmp_path / "qc.yaml").write_text(text)
    _csv(tmp_path, KNOTS)
    mod = load_module(compile_file(tmp_path / "qc.yaml").source, "qc_table")
    np.testing.assert_allclose(_road(mod, [0.2, 0.475]), [0.01, 0.035])


def _err(tmp_path, spec, csv_rows=None, header="time,height"):
    if csv_rows is not None:
        _csv(tmp_path, csv_rows, header)
    with pytest.raises(ModelError) as ei:
        parse_scene(_scene(tmp_path, spec))
    return ei.value


def test_errors_are_located(tmp_path):
    spec = "{table: road.csv, columns: [time, height]}"
    # at the CSV's own line: time not increasing, not a number, not finite, short row
    e = _err(tmp_path, spec, [(0, 0), (1, 0), (0.5, 0)])
    assert e.coord.file.endswith("road.csv") and e.coord.line == 4 and "increase" in e.message
    e = _err(tmp_path, spec, [(0, 0), ("x", 0)])
    assert e.coord.line == 3 and "not a number" in e.message
    e = _err(tmp_path, spec, [(0, 0), (1, "nan")])
    assert e.coord.line == 3 and "finite" in e.message
    (tmp_path / "road.csv").write_text("time,height\n0,0\n1\n")
    e = _err(tmp_path, spec)
    assert e.coord.line == 3 and "column" in e.message
    # at the table: key (line 5 of the scene, column of 'table' inside the flow mapping)
    for rows, what in (([(0, 0)], "at least two rows"),):
        e = _err(tmp_path, spec, rows)
        assert e.coord.file.endswith("s.yaml") and e.coord.line == 5 and what in e.message
    e = _err(tmp_path, "{table: nowhere.csv}")
    assert e.coord.line == 5 and "cannot read" in e.message
    (tmp_path / "adir").mkdir()
    e = _err(tmp_path, "{table: adir}")
    assert "folder" in e.message and e.coord.line == 5
    e = _err(tmp_path, "{table: /etc/hostname}")
    assert "absolute" in e.message
    e = _err(tmp_path, "{table: road.csv, columns: [time, speed]}", KNOTS)
    assert "no column 'speed'" in e.message
    e = _err(tmp_path, "{table: road.csv, interp: cubic}", KNOTS)
    assert "interp" in e.message and e.coord.line == 5
    e = _err(tmp_path, "{table: road.csv, extrapolate: wrap}", KNOTS)
    assert "extrapolate" in e.message


def test_size_is_capped_before_reading(tmp_path, monkeypatch):
    import bgc.format.tables

    _csv(tmp_path, KNOTS)
    monkeypatch.setattr(bgc.format.tables, "MAX_BYTES", 20)
    e = _err(tmp_path, "{table: road.csv}")
    assert "limit of 20 bytes" in e.message and e.coord.line == 5
    monkeypatch.setattr(bgc.format.tables, "MAX_BYTES", 10_000)
    monkeypatch.setattr(bgc.format.tables, "MAX_ROWS", 4)
    e = _err(tmp_path, "{table: road.csv}")
    assert "more than 4 rows" in e.message and e.coord.line == 6  # header, then row 5


def test_cli_error_for_a_bad_table(tmp_path, bgc_cli):
    _csv(tmp_path, [(0, 0), (0, 1)])
    r = bgc_cli("simulate", str(_scene(tmp_path, "{table: road.csv}")), "-q")
    assert r.returncode == 2 and "road.csv:3:1:" in r.stderr and "Traceback" not in r.stderr


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs here")
def test_a_fifo_is_refused_without_blocking(tmp_path):
    os.mkfifo(tmp_path / "road.csv")
    e = _err(tmp_path, "{table: road.csv}")
    assert "not a regular file" in e.message and e.coord.line == 5


# ---------------------------------------------------------------------------------------------
# The C backend: the data as arrays in the library, the runtime's bgc_table_eval

def _c_ready():
    from bgc.backends.c import build as cbuild

    return cbuild.available() and bool(cbuild.runtime_sources())


@pytest.mark.skipif(not _c_ready(), reason="no C compiler or C runtime")
def test_c_backend_tables_against_independent_formulas_and_numpy(tmp_path, monkeypatch):
    """The C module's table inputs (linear, pchip, previous; held outside) against the same
    independent formulas as the numpy module above, and its runs (the step loop in C, the
    knots of linear and previous tables as breakpoints) against the numpy module's in
    scipy's DOP853 (the quarter car is not stiff: at rtol 1e-9 DOP853 takes a few dozen
    steps where scipy's Radau takes over a thousand).

    Built through a compile cache of the test's own that starts with the C runtime's objects
    (conftest's seed_c_runtime; uncached, each of the three builds compiled the runtime
    again): each scene's entries start empty, so every module is compiled here. The numpy
    module is printed from the C build's own compile (as bgc.run.driver.build's numpy twin
    of a C module), not compiled a second time."""
    from scipy.interpolate import PchipInterpolator

    from bgc.backends.load import load_module
    from bgc.run.driver import build

    monkeypatch.setenv("BGC_CACHE_DIR", str(seed_c_runtime(tmp_path / "cache")))
    csv = _csv(tmp_path, KNOTS)
    tk, vk = np.array(KNOTS).T
    tq = np.linspace(-0.3, 1.6, 97)
    tc = np.clip(tq, tk[0], tk[-1])
    for interp in ("linear", "pchip", "previous"):
        sc = parse_scene(_scene(tmp_path, f"{{table: {csv}, columns: [time, height], "
                                          f"interp: {interp}}}", name=f"c_{interp}.yaml"))
        b = build(scene=sc, backend="c")
        cm = b.module
        assert b.backend == "c" and cm.C_LIBRARY and b.compiled is not None
        npm = load_module(b.compiled.source, f"c_table_{interp}_numpy")
        if interp == "linear":
            i = np.clip(np.searchsorted(tk, tc) - 1, 0, len(tk) - 2)
            want = vk[i] + (vk[i + 1] - vk[i]) * (tc - tk[i]) / (tk[i + 1] - tk[i])
        elif interp == "pchip":
            want = PchipInterpolator(tk, vk)(tc)
        else:
            want = np.array([vk[np.nonzero(tk <= s)[0][-1]] for s in tc])
        np.testing.assert_allclose(_road(cm, tq), want, atol=1e-15, err_msg=interp)
        # both C methods against one run of the numpy module in scipy's DOP853 (which shares
        # no code with the C runtime), at the same tolerances
        kw = dict(dt=0.05, rtol=1e-9, atol=1e-12)
        xn = npm.simulate((0, 2), method="DOP853", **kw).x
        scale = np.max(np.abs(xn), axis=1, keepdims=True)
        for method in ("Radau", "Rodas4"):
            xc = cm.simulate((0, 2), method=method, **kw).x
            assert np.max(np.abs(xc - xn) / scale) < 1e-5, (interp, method)


@pytest.mark.skipif(not _c_ready(), reason="no C compiler or C runtime")
def test_c_backend_extrapolate_error(tmp_path, monkeypatch):
    """Outside the knots with extrapolate: error the C module raises the numpy module's
    ValueError naming the input, from outputs and from a run (with the time)."""
    from bgc.run.runner import scene_module

    monkeypatch.setenv("BGC_CACHE_DIR", str(seed_c_runtime(tmp_path / "cache")))
    csv = _csv(tmp_path, KNOTS)
    sc = parse_scene(_scene(tmp_path, f"{{table: {csv}, columns: [time, height], "
                                      "extrapolate: error}"))
    _, cm = scene_module(sc, None, "c")  # (a fresh cache: compiled here, the runtime seeded)
    assert abs(_road(cm, [0.3])[0] - (0.01 + 0.03 * 0.1 / 0.25)) < 1e-15
    with pytest.raises(ValueError, match=r"input 'zr': t .*outside its table \[0, 1.3\]"):
        _road(cm, [1.5])
    with pytest.raises(ValueError, match=r"outside its table \[0, 1.3\].*at t = 1.3"):
        cm.simulate((0, 2), dt=0.01, method="Radau")
