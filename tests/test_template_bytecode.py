"""The numpy templates' compiled code kept beside bgc's bytecode
(bgc.backends.numpy.printer.TemplateBytecode): used only for the very template text it came
from, rewritten when damaged, written only where Python writes bytecode, and the module it
renders is the one a fresh compile of the template renders (msd's golden)."""
from __future__ import annotations

import sys
from pathlib import Path

import jinja2
import pytest

from bgc.backends.numpy import printer
from bgc.run.driver import compile_file

ROOT = Path(__file__).resolve().parent.parent


def _env(folder: Path, loader=None) -> jinja2.Environment:
    env = printer.make_environment(folder)
    if loader is not None:
        env.loader = loader
    return env


def _no_compiling(monkeypatch):
    """Compiling a template from its text fails from now on."""
    def refuse(*a, **k):
        raise AssertionError("the template was compiled from its text")
    monkeypatch.setattr(jinja2.Environment, "_parse", refuse)


def test_kept_code_is_used_and_renders_the_same(tmp_path, monkeypatch):
    monkeypatch.setattr(sys, "dont_write_bytecode", False)
    folder = tmp_path / "__pycache__"
    first = _env(folder).get_template("numpy/module.py.j2")
    kept = list(folder.iterdir())
    assert len(kept) == 1 and kept[0].name.endswith(f".jinja2-{jinja2.__version__}.cache")
    _no_compiling(monkeypatch)
    second = _env(folder).get_template("numpy/module.py.j2")  # from the kept code
    assert second is not first
    # the module rendered through the kept code is msd's golden, byte for byte
    monkeypatch.setattr(printer, "_environment", lambda: _env(folder))
    c = compile_file(ROOT / "models" / "msd.yaml")
    assert c.source == (ROOT / "generated" / "msd.py").read_text(encoding="utf-8")


def test_a_changed_template_is_compiled_again(tmp_path, monkeypatch):
    monkeypatch.setattr(sys, "dont_write_bytecode", False)
    folder = tmp_path / "__pycache__"
    (tmp_path / "t").mkdir()
    tpl = tmp_path / "t" / "x.j2"
    tpl.write_text("one {{ a }}\n")
    loader = jinja2.FileSystemLoader(str(tmp_path / "t"))
    assert _env(folder, loader).get_template("x.j2").render(a=1) == "one 1\n"
    tpl.write_text("two {{ a }}\n")  # the same name and path, another text
    assert _env(folder, loader).get_template("x.j2").render(a=1) == "two 1\n"


@pytest.mark.parametrize("damage", [b"", b"garbage", b"j2" + b"\x00" * 40])
def test_a_damaged_entry_is_compiled_again_and_rewritten(tmp_path, monkeypatch, damage):
    monkeypatch.setattr(sys, "dont_write_bytecode", False)
    folder = tmp_path / "__pycache__"
    _env(folder).get_template("numpy/module.py.j2")
    (entry,) = folder.iterdir()
    good = entry.read_bytes()
    entry.write_bytes(damage)
    t = _env(folder).get_template("numpy/module.py.j2")
    assert t.render  # compiled again from the text
    assert entry.read_bytes() == good  # and written again


def test_nothing_written_without_bytecode(tmp_path, monkeypatch):
    monkeypatch.setattr(sys, "dont_write_bytecode", True)
    folder = tmp_path / "__pycache__"
    _env(folder).get_template("numpy/module.py.j2")
    assert not folder.exists()
    blocked = tmp_path / "blocked"  # a file where the folder would be: it cannot be made
    blocked.write_text("mine")
    monkeypatch.setattr(sys, "dont_write_bytecode", False)
    t = _env(blocked).get_template("numpy/module.py.j2")  # still compiled, nothing raised
    assert t.render and blocked.read_text() == "mine"


def test_c_templates_kept_code_renders_the_c_golden(tmp_path, monkeypatch):
    """The C templates' environment keeps its compiled code the same way: written once, then
    used without compiling the template text, and the C sources rendered through it are msd's
    C goldens, byte for byte."""
    from bgc.backends.c import printer as cprinter
    from bgc.backends.load import c_files

    monkeypatch.setattr(sys, "dont_write_bytecode", False)
    folder = tmp_path / "__pycache__"
    env = cprinter.make_template_env(folder)
    for name in ("c/model.c.j2", "c/part.c.j2", "c/newton.c.j2", "c/tables.c.j2",
                 "c/wrapper.py.j2"):
        env.get_template(name)
    assert len(list(folder.iterdir())) == 5
    _no_compiling(monkeypatch)
    monkeypatch.setattr(cprinter, "template_env", lambda: cprinter.make_template_env(folder))
    files, _ = c_files(compile_file(ROOT / "models" / "msd.yaml"))
    golden = ROOT / "generated" / "c" / "msd"
    assert files and {n: (golden / n).read_text(encoding="utf-8") for n in files} == files
