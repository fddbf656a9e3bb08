"""Backends: from a compiled model to a loaded module (numpy, or C through a shared library),
through the compile cache.

``load(...)`` is what `bgc simulate` uses: on a cache hit it reads the entry and imports the
module without importing sympy or the compiler; on a miss it compiles (the caller's
``compile_fn``), writes the entry atomically and loads it.
"""
from __future__ import annotations

import shutil
import sys
import time
from pathlib import Path

from bgc.backends.c import build as cbuild
from bgc.backends.c.build import LIB_NAME
from bgc.base import (
    BACKENDS,  # noqa: F401 (the one list, re-exported)
    __version__,
)
from bgc.base.collector import gc_paused
from bgc.base.outfiles import write_output
from bgc.base.safeio import read_bytes
from bgc.base.store import Cache, UnsafeCache

MODULE_FILE = "module.py"
CODE_FILE = "module.code"
ENTRY_BYTES = 256 << 20  # the largest module (text or code) read from a cache entry


def _timed(times, stage: str, t0: float) -> float:
    """Append (stage, seconds since t0) to times (a list, or None: nothing kept); now."""
    now = time.perf_counter()
    if times is not None:
        times.append((stage, now - t0))
    return now


def c_files(compiled, times: list | None = None) -> tuple[dict, str]:
    """(C sources by file name, wrapper text) of a compiled model; ``times`` (a list) gets
    the stages' seconds ("print C", "wrapper"). The collector is paused while they print."""
    with gc_paused():
        return _c_files(compiled, times)


def _c_files(compiled, times: list | None) -> tuple[dict, str]:
    # lazy: the compile path, which a warm run never loads
    from bgc.backends.c.printer import render_c, render_wrapper

    m = compiled.model
    t0 = time.perf_counter()
    csrc = render_c(compiled.lowered, source=Path(m.file).name, source_hash=m.source_hash,
                    description=m.description, header_notes=compiled.notes)
    # the wrapper's numpy part: names, parameters and the runtime, without the equations
    # (the library computes them); checked once, as part of the whole wrapper
    t0 = _timed(times, "print C", t0)
    numpy_part = compiled.module_text(equations=False, check=False)
    wrapper = render_wrapper(compiled.lowered, numpy_part, csrc, LIB_NAME)
    _timed(times, "wrapper", t0)
    return dict(csrc.files), wrapper


def write_c(compiled, outdir, cache=None, progress=None, inputs=None) -> Path:
    """Write the C sources, the runtime's sources, the wrapper (``<name>.py``) and the built
    library into outdir; returns the wrapper's path. Every file through the checked writer
    (bgc.base.outdirs): never over ``inputs`` (the run's model, imports, scene), never through
    a link (a linked ``runtime/`` is refused), never over anything but a regular file."""
    # lazy: the compile path, which a warm run never loads
    from bgc.base.outdirs import check_in, copy_file, out_folder, write_in

    say = progress or (lambda msg: None)
    files, wrapper = c_files(compiled)
    names = [*files, f"{compiled.model.name}.py", cbuild.LIB_NAME,
             *(f"runtime/{f.name}" for f in cbuild.runtime_sources() + cbuild.runtime_headers())]
    out = out_folder(outdir, "-o", create=False)
    for name in names:  # every refusal before anything is written
        check_in(out, name, inputs, "-o")
    made = [p for p in [out, out / "runtime"] + [out / n for n in names] if not p.exists()]
    try:
        out = out_folder(outdir, "-o")
        for name, text in files.items():
            write_in(out, name, text, inputs, "-o")
        for f in cbuild.runtime_sources() + cbuild.runtime_headers():
            copy_file(f, out, f"runtime/{f.name}", inputs, "-o")
        say(f"building the C library ({len(files)} model units)")
        cbuild.build_library(out, sorted(files), cache=cache, inputs=inputs)
        return write_in(out, f"{compiled.model.name}.py", wrapper, inputs, "-o")
    except BaseException:  # a compiler that fails leaves nothing it wrote (what was there stays)
        for p in reversed(made):
            try:
                p.rmdir() if p.is_dir() and not p.is_symlink() else p.unlink()
            except OSError:
                pass
        raise


def _code_file(tmp: Path, text: str, name: str, wrapper: bool = False) -> None:
    """The module's compiled code beside its text: a warm load skips parsing and compiling
    (the cache key includes the Python version). The text is checked here, or was when it was
    rendered: either way parsed once, and compiled from that tree (skeleton.checked_code)."""
    import marshal

    # lazy: the compile path, which a warm run never loads
    from bgc.backends.skeleton import checked_code

    code = checked_code(text, f"<bgc {name}>", wrapper)
    (tmp / CODE_FILE).write_bytes(marshal.dumps(code))


def _build_entry(compiled, backend, cache, progress, name, times=None):
    def build(tmp: Path):
        if backend == "numpy":
            write_output(tmp / MODULE_FILE, compiled.source)
            _code_file(tmp, compiled.source, name)
            return
        files, wrapper = c_files(compiled, times)
        c_entry_builder(files, wrapper, name, cache, progress, times)(tmp)
    return build


def c_entry_builder(files: dict, wrapper: str, name: str, cache=None, progress=None,
                    times: list | None = None):
    """build(tmp): write the C sources (file name -> text) and the wrapper into tmp and build
    the library there with the system compiler (a compile-cache entry for ``load_entry``);
    ``times`` gets the seconds of "build C" (the compiler) and "wrapper code"."""
    def build(tmp: Path):
        t0 = time.perf_counter()
        for fname, text in files.items():
            write_output(tmp / fname, text)
        (progress or (lambda m: None))(f"building the C library ({len(files)} model units)")
        cbuild.build_library(tmp, sorted(files), cache=cache)
        t0 = _timed(times, "build C", t0)
        write_output(tmp / MODULE_FILE, wrapper)
        _code_file(tmp, wrapper, name, wrapper=True)
        _timed(times, "wrapper code", t0)
    return build


def c_key(files: dict, wrapper: str) -> str:
    """The compile-cache key of a C entry made from these texts (as `bgc sweep` ships them):
    the texts, the C runtime's sources, the compiler's identity and flags, bgc's and Python's
    versions (the entry keeps the wrapper's compiled code). Raises CompilerMissing without a
    compiler."""
    import hashlib
    import sys

    h = hashlib.sha256(f"bgc {__version__}\0python {sys.version}\0c-texts\0".encode())
    for fname in sorted(files):
        h.update(fname.encode() + b"\0" + files[fname].encode() + b"\0")
    h.update(b"wrapper\0" + wrapper.encode() + b"\0")
    h.update(cbuild.runtime_key().encode())  # runtime sources, compiler identity and flags
    return h.hexdigest()


def load_c(files: dict, wrapper: str, name: str, key: str | None = None, progress=None):
    """The C wrapper module of shipped texts (C sources by file name, wrapper text), its
    library built through the compile cache: a process that finds the entry loads it, one
    that does not builds it (the system compiler) and keeps it for the next. The wrapper text
    is checked before anything of it is kept or run. An unusable cache (unsafe, unwritable):
    built in a temporary folder instead. Raises CompilerMissing without a compiler."""
    import tempfile

    # lazy: the compile path, which a warm run never loads
    from bgc.backends.skeleton import check_wrapper

    check_wrapper(wrapper)
    key = key or c_key(files, wrapper)
    try:
        store = Cache()
        entry = store.get_or_build("c", key, c_entry_builder(files, wrapper, name, store,
                                                             progress))
        return load_entry(entry, "c", name, trusted=True)
    except (UnsafeCache, PermissionError) as exc:
        (progress or (lambda m: None))(f"compile cache not used ({exc})")
    d = Path(tempfile.mkdtemp(prefix="bgc-c-"))
    try:
        c_entry_builder(files, wrapper, name, None, progress)(d)
        return load_entry(d, "c", name)  # loaded (the mapping outlives the file)
    finally:
        shutil.rmtree(d, ignore_errors=True)


def load_entry(entry: Path, backend: str, name: str, trusted: bool = False):
    """Import the module of a cache entry (or a folder holding module.py). ``trusted``: the
    entry is in a checked cache directory and was checked when written; its compiled code
    (module.code) is used as it is."""
    entry = Path(entry)

    text = read_bytes(entry / MODULE_FILE, ENTRY_BYTES).decode("utf-8")
    code = None
    if trusted and (entry / CODE_FILE).is_file():
        import marshal

        try:
            code = marshal.loads(read_bytes(entry / CODE_FILE, ENTRY_BYTES))
        except (ValueError, EOFError, TypeError):
            code = None
    if backend == "numpy":
        return load_module(text, name, code=code)

    # compiled code comes from a checked entry; text is checked first
    mod = load_module(text, name, code=code, wrapper=True)
    mod._bind(Path(entry) / LIB_NAME)
    return mod


def load_module(source: str, name: str, code=None, wrapper: bool = False):
    """Import generated source as a module, from memory: nothing is written to disk. The code
    is compiled under a recognisable file name (``<bgc NAME>``) registered with ``linecache``,
    so tracebacks and ``inspect`` still show the generated lines. Without ``code`` (compiled
    from checked text: a trusted cache entry) the text is checked first (``wrapper``: as a C
    wrapper), parsed once for the check and the compile."""
    modname = f"bgc_generated_{name}"
    filename = f"<bgc {name}>"
    if code is None:
        # lazy: the compile path, which a warm run never loads
        from bgc.backends.skeleton import checked_code

        # never execute a module whose top level is not the template's
        code = checked_code(source, filename, wrapper)
    loader = _SourceLoader(modname, filename, source, code)
    import importlib.util
    import linecache

    spec = importlib.util.spec_from_loader(modname, loader, origin=filename)
    mod = importlib.util.module_from_spec(spec)
    mod.__file__ = filename
    linecache.cache[filename] = (len(source), None, source.splitlines(True), filename)
    sys.modules[modname] = mod
    try:
        loader.exec_module(mod)
    except BaseException:
        sys.modules.pop(modname, None)
        raise
    return mod


class _SourceLoader:
    """A loader for generated source held in memory (``get_source`` serves tracebacks,
    ``get_data`` the module's own text). It has importlib.abc.Loader's methods without
    subclassing it: importing importlib.abc costs a warm run 8 ms (importlib.resources)."""

    def __init__(self, modname: str, filename: str, source: str, code=None):
        self.modname, self.filename, self.source, self.code = modname, filename, source, code

    def create_module(self, spec):
        return None

    def exec_module(self, module):
        code = self.code if self.code is not None else compile(self.source, self.filename,
                                                                 "exec")
        exec(code, module.__dict__)

    def get_source(self, fullname):
        return self.source

    def get_data(self, path):
        return self.source.encode("utf-8")


def _cached(cache, backend: str, key: str, name: str, say):
    """The module of the cache entry under key, or None: none there, or a corrupt one (it is
    discarded, with a note, and the caller builds it again)."""
    entry = cache.get(backend, key)
    if entry is None:
        return None
    say(f"cache hit ({backend} {key[:12]})")
    try:
        return load_entry(entry, backend, name, trusted=True)
    except Exception as exc:  # noqa: BLE001 - any failure of a cached entry: rebuild it
        from bgc.base.errors import oneline

        print(f"note: discarded a corrupt compile-cache entry ({backend} {key[:12]}: "
              f"{oneline(type(exc).__name__ + ': ' + str(exc), 160)}); compiling it again",
              file=sys.stderr)
        cache.discard(backend, key)
        return None


def load(name: str, backend: str, key: str | None, compile_fn, cache=None, progress=None,
         times: list | None = None):
    """(compiled or None, module): from the cache when key hits, else compiled now.

    compile_fn() -> Compiled. cache: a bgc.run.cache.Cache, or None (no caching: the C library is
    built in a temporary folder). ``times`` (a list) gets the C stages' seconds ("print C",
    "wrapper", "build C", "wrapper code")."""
    say = progress or (lambda msg: None)
    if cache is not None and key is not None:
        mod = _cached(cache, backend, key, name, say)
        if mod is not None:
            return None, mod
    early = backend == "c" and cache is not None and key is not None
    if early:
        cbuild.start_runtime(cache)  # gcc on the runtime while the compile runs
    try:
        return _compiled_and_loaded(name, backend, key, compile_fn, cache, progress, times)
    finally:
        # a build that got as far as linking has taken the early build (waited for it): this
        # then does nothing. Otherwise (a user's error, the C printer's refusal and the run
        # going on in numpy, an entry another process built meanwhile) its compiler stops
        # and no entry is left behind for this cache.
        if early:
            cbuild.stop_runtime(cache)


def _compiled_and_loaded(name, backend, key, compile_fn, cache, progress, times):
    """:func:`load` past the cache lookup: compile, then build and load. Through the cache,
    the compile runs inside the entry's build (under its lock, bgc.base.store): a process
    that waited for another's build of the same entry loads that one (compiled None, as on
    a hit) and compiles nothing."""
    if cache is not None and key is not None:
        made = []

        def build(tmp: Path):
            made.append(compile_fn())
            _build_entry(made[0], backend, cache, progress, name, times)(tmp)
        entry = cache.get_or_build(backend, key, build)
        if not made:
            (progress or (lambda m: None))(
                f"cache hit ({backend} {key[:12]}: built meanwhile by another process)")
        return (made[0] if made else None), load_entry(entry, backend, name, trusted=True)
    compiled = compile_fn()
    if backend == "numpy":
        return compiled, load_module(compiled.source, name)
    import tempfile

    d = Path(tempfile.mkdtemp(prefix="bgc-c-"))  # uncached C: built in a temporary folder
    try:
        _build_entry(compiled, backend, None, progress, name, times)(d)
        # loaded (the mapping outlives the file): nothing is left behind
        return compiled, load_entry(d, backend, name)
    finally:
        shutil.rmtree(d, ignore_errors=True)
