"""The compile driver (bgc.run.driver): one compile of a scene or a model for a backend
through the cache, and the mends of issue 20 that come with it. Every answer is checked
against a closed form of a small RC circuit or against the other way of asking (the command
line against the Python API), never against the code's own output alone."""
from __future__ import annotations

import importlib.util
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import bgc
from bgc.run import driver

ROOT = Path(__file__).resolve().parents[1]

# Vs -> R in series with C: q' = (Vs - q/C) / R; at rest q = C Vs.
RC = """bgc: 1
name: rc
parameters:
  R:  {value: 2.0}
  C:  {value: 0.5}
  V0: {value: 24.0}
inputs:
  Vs: {default: "V0"}
elements:
  src:  {type: Se, effort: "Vs"}
  res:  {type: R, resistance: "R"}
  cap:  {type: C, compliance: "C"}
  loop: {type: "1"}
bonds:
  - [src, loop]
  - [loop, res]
  - [loop, cap]
outputs:
  charge: "q(cap)"
"""


def bgc_cli(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "bgc", *map(str, args)], capture_output=True,
                          text=True, cwd=cwd, timeout=600)


@pytest.fixture
def rc(tmp_path):
    model = tmp_path / "rc.yaml"
    model.write_text(RC)
    return model


@pytest.fixture
def fresh_cache(tmp_path, monkeypatch):
    """A private, empty compile cache for this test (and the processes it starts)."""
    d = tmp_path / "cache"
    d.mkdir(mode=0o700)
    monkeypatch.setenv("BGC_CACHE_DIR", str(d))
    return d


def free_v0_scene(tmp_path, model) -> Path:
    s = tmp_path / "free.yaml"
    s.write_text(f"bgc_scene: 1\nmodel: {model.name}\nduration: 20\n"
                 "parameters: {V0: 12.0}\nfree: [V0]\n")
    return s


@pytest.mark.parametrize("api_first", [True, False])
def test_a_scene_compiles_one_way_with_one_key(tmp_path, rc, fresh_cache, api_first):
    """bgc.compile(model, scene=...) and the runner (`bgc simulate`'s way) give the same
    module for a scene that sets a free V0 = 12 over the model's 24, whichever runs first,
    through one cache entry: the second is a cache hit. The module charges C to C V0 = 6."""
    from bgc.format.scene import parse_scene
    from bgc.run.runner import scene_module

    scene = free_v0_scene(tmp_path, rc)

    def api():
        m = bgc.compile(rc, scene=scene)
        return m.module, m.compiled

    def runner():
        return scene_module(parse_scene(scene))[1], "runner"

    first, second = (api, runner) if api_first else (runner, api)
    mod1, c1 = first()
    mod2, c2 = second()
    for mod in (mod1, mod2):
        assert mod.PARAM_DEFAULTS["V0"] == 12.0
        res = mod.simulate((0.0, 20.0), rtol=1e-9, atol=1e-12)
        assert res.y["charge"][-1] == pytest.approx(0.5 * 12.0, rel=1e-6)
    if api_first:
        assert c1 is not None  # compiled by the API...
    else:
        assert c2 is None  # ...and the API's call found the runner's entry
    entries = [p for p in (fresh_cache / "numpy").glob("*/*") if p.is_dir()]
    assert len(entries) == 1, entries


def test_compile_scene_on_the_command_line_is_the_same_module(tmp_path, rc, fresh_cache):
    """`bgc compile --scene` writes the module `bgc simulate` runs: the scene's V0 = 12."""
    scene = free_v0_scene(tmp_path, rc)
    out = tmp_path / "rc_free.py"
    r = bgc_cli("compile", rc, "--scene", scene, "-o", out, "-q")
    assert r.returncode == 0, r.stderr
    spec = importlib.util.spec_from_file_location("rc_free_cli", out)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    assert mod.PARAM_DEFAULTS["V0"] == 12.0
    assert mod.PARAM_DEFAULTS == bgc.compile(rc, scene=scene).PARAM_DEFAULTS


def test_linearize_starts_where_the_scene_starts(tmp_path, rc, fresh_cache):
    """A scene starting at t = 2 with a source stepping from 0 to 7 V at t = 1: the
    equilibrium is q = C * 7 = 3.5 (at t = 0 it would be 0), from `bgc linearize` and from
    bgc.linearize given the scene file or a model compiled for the scene; A = -1/(R C)."""
    scene = tmp_path / "late.yaml"
    scene.write_text(f"bgc_scene: 1\nmodel: {rc.name}\nt_span: [2.0, 4.0]\n"
                     "inputs: {Vs: \"where(t < 1, 0, 7)\"}\n")
    r = bgc_cli("linearize", scene, "--out", tmp_path / "lin", "-q")
    assert r.returncode == 0, r.stderr
    cli = np.load(next((tmp_path / "lin").glob("*.npz")))
    assert float(cli["t"]) == 2.0 and cli["x"][0] == pytest.approx(3.5, rel=1e-9)
    for target in (scene, bgc.compile(rc, scene=scene)):
        lin = bgc.linearize(target)
        assert lin.t == 2.0
        assert lin.x[0] == pytest.approx(3.5, rel=1e-9)
        assert np.allclose(lin.A, cli["A"]) and lin.A[0, 0] == pytest.approx(-1.0)
    # the bare model starts at t = 0, where the signal is 0
    bare = tmp_path / "rc_step.yaml"
    bare.write_text(RC.replace('default: "V0"', 'default: "where(t < 1, 0, 7)"'))
    assert bgc.linearize(bare).x[0] == pytest.approx(0.0, abs=1e-12)
    lin = bgc.linearize(bare, at=3.0)  # the state a run from 0 reaches at t = 3
    q = 3.5 * (1 - np.exp(-(3.0 - 1.0) / (2.0 * 0.5)))
    assert lin.t == 3.0 and lin.x[0] == pytest.approx(q, rel=1e-6)


def test_check_agrees_with_the_command_line(tmp_path):
    """`bgc check` and bgc.check run one check: the resistor-law diagnosis is an error in
    both (not a derivative-causality diagnostic in one); `causality: strict` (in the model or
    asked for) refuses derivative causality in both, with the same message; without it both
    eliminate the dependent storage element and list the same states."""
    bad = ROOT / "tests" / "bad" / "r_fixed_form.yaml"
    r = bgc_cli("check", bad)
    assert r.returncode == 2
    with pytest.raises(bgc.BgcError) as exc:
        bgc.check(bad)
    assert str(exc.value) == r.stderr.strip()

    strict = ROOT / "models" / "bad" / "derivative_causality.yaml"
    loose = tmp_path / "loose.yaml"
    loose.write_text("\n".join(ln for ln in strict.read_text().splitlines()
                               if not ln.startswith("causality:")) + "\n")
    for path, flag in ((strict, ()), (loose, ("--strict-causality",))):
        r = bgc_cli("check", path, *flag)
        assert r.returncode == 2
        res = bgc.check(path, strict_causality=bool(flag))
        assert res.diagnostics and res.diagnostics[0] in r.stderr
        assert res.derivative == ("flywheel_b",)
    r = bgc_cli("check", loose)
    assert r.returncode == 0, r.stderr
    res = bgc.check(loose)
    assert res.diagnostics == () and res.derivative == ("flywheel_b",)
    # one independent momentum: flywheel_a carries the shaft (the other follows it)
    listed = r.stdout.split("states (", 1)[1].split("\n\n", 1)[0]
    assert f"{len(res.states)} scalars" in listed and res.states == ("flywheel_a.p",)
    assert "flywheel_a.p" in listed and "flywheel_b" not in listed


def test_stages_are_timed_and_a_hit_only_loads(rc, fresh_cache):
    """build() times every stage of a compile, in the documented order; a second build is a
    cache hit: no compile, only the load."""
    b = driver.build(rc)
    names = [s for s, _ in b.times]
    assert names == ["parse", "imports", "graph", "causality", "equations", "lower", "print",
                     "load"]
    assert all(t >= 0 for _, t in b.times) and b.compile_time == pytest.approx(
        sum(t for _, t in b.times))
    assert [s for s in driver.STAGES if s in names] == names
    assert b.compiled is not None and b.compiled.times == b.times[:-1]
    hit = driver.build(rc)
    assert hit.compiled is None and [s for s, _ in hit.times] == ["load"]
    assert hit.entry[1] == b.entry[1]
    assert hit.module.PARAM_DEFAULTS == b.module.PARAM_DEFAULTS


def test_c_refusal_is_a_type_not_a_name(tmp_path, rc, fresh_cache, monkeypatch):
    """The runner falls back to numpy on the C printer's refusal by its type (a subclass
    with another name is still the refusal), and says so."""
    from bgc.backends.c import build as cbuild
    from bgc.backends.c import printer
    from bgc.format.scene import parse_scene
    from bgc.run.runner import run_scene

    if not cbuild.available():
        pytest.skip("no C compiler")

    class NotYetInC(cbuild.CUnsupported):
        pass

    def refuse(eq):
        raise NotYetInC(None, f"model {eq.name!r}: not in C (test)")

    monkeypatch.setattr(printer, "unsupported", refuse)
    said = []
    scene = free_v0_scene(tmp_path, rc)
    res = run_scene(parse_scene(scene), said.append, backend="c")
    assert res.backend == "numpy"
    assert any("not in C (test): using the numpy backend" in m for m in said)
    assert res.y["charge"][-1] == pytest.approx(0.5 * 12.0, rel=1e-4)


# ---------------------------------------------------------------------------------------------
# The trap: the compile cache and the run records fingerprint every file of bgc's code

def test_any_source_or_template_change_invalidates_cache_and_records(tmp_path, monkeypatch):
    """A copy of bgc's sources and templates stands in for the package: a change to any
    source file (one per subpackage, nested ones included) or any template changes both the
    compile cache's code digest and the run records' code stamp, and undoing it restores
    the digest."""
    from bgc.base import paths
    from bgc.run import cache, record

    src = ROOT / "src" / "bgc"
    tree = tmp_path / "tree"
    shutil.copytree(src, tree / "src" / "bgc", ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copytree(paths.templates_dir(), tree / "templates",
                    ignore=shutil.ignore_patterns("__pycache__"))
    monkeypatch.setattr(paths, "PACKAGE_DIR", str(tree / "src" / "bgc"))
    assert paths.templates_root() == str(tree / "templates")
    folders = sorted({p.parent for p in (tree / "src" / "bgc").rglob("*.py")}
                     | {p.parent for p in (tree / "templates").rglob("*") if p.is_file()})
    assert len(folders) >= 12  # bgc, its nine layers' folders, the backends' and templates'
    digest, stamp = cache._code_digest(), record.code_stamp()
    for folder in folders:
        f = next(p for p in sorted(folder.iterdir())
                 if p.is_file() and p.suffix in (".py", ".c", ".h", ".j2"))
        before = f.read_bytes()
        f.write_bytes(before + b"\n")
        assert cache._code_digest() != digest, f
        assert record.code_stamp() != stamp, f
        f.write_bytes(before)
        assert cache._code_digest() == digest, f


# ---------------------------------------------------------------------------------------------
# The FMU is built by the C backend's build

FAKE_CC = """#!/bin/sh
if [ "$1" = "--version" ]; then echo "refusing-cc 1.0"; exit 0; fi
echo "x.c:1:1: error: this compiler refuses everything" >&2
exit 1
"""


def test_fmu_compiler_failure_is_one_located_user_error(tmp_path, rc, fresh_cache):
    """A C compiler that refuses the FMU's sources: `bgc export` says so in one line at the
    model (exit 2, a user's problem, not an internal error), and writes nothing."""
    pytest.importorskip("fmpy")
    cc = tmp_path / "refusing-cc"
    cc.write_text(FAKE_CC)
    cc.chmod(0o755)
    out = tmp_path / "rc.fmu"
    env_run = subprocess.run([sys.executable, "-m", "bgc", "export", str(rc), "--fmu",
                              str(out), "-q"], capture_output=True, text=True, timeout=600,
                             env={**__import__("os").environ, "CC": str(cc)})
    assert env_run.returncode == 2, env_run.stderr
    lines = env_run.stderr.strip().splitlines()
    assert len(lines) == 1, lines
    assert lines[0].startswith(f"{rc}:") and "the C compiler" in lines[0]
    assert "refuses everything" in lines[0]
    assert not out.exists()


def test_fmu_takes_the_c_runtime_objects_from_the_compile_cache(tmp_path, rc, fresh_cache):
    """The FMU's library links the C backend's cached runtime objects (one entry per
    compiler and flags), and the FMU it makes still runs: FMPy's simulation of the RC circuit
    charges it to C V0 = 12 (closed form q = C V0 (1 - exp(-t / (R C))))."""
    fmpy = pytest.importorskip("fmpy")
    from bgc.backends.c import build as cbuild
    from bgc.run.fmu import export_fmu

    if not cbuild.available():
        pytest.skip("no C compiler")
    out = export_fmu(rc, tmp_path / "rc.fmu")
    key = cbuild.runtime_key()
    entry = fresh_cache / "c-runtime" / key[:2] / key
    objs = sorted(p.name for p in entry.glob("*.o"))
    assert objs == sorted(f.stem + ".o" for f in cbuild.runtime_sources())
    res = fmpy.simulate_fmu(str(out), fmi_type="ModelExchange", stop_time=3.0,
                            output=["charge"], output_interval=0.5)
    q = 0.5 * 24.0 * (1 - np.exp(-res["time"] / (2.0 * 0.5)))
    assert np.allclose(res["charge"], q, rtol=1e-3, atol=1e-6)
