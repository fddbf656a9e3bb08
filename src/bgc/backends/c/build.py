"""Building the C backend's shared library with the system C compiler.

The compiler is ``$CC`` (split like a shell word list), else ``cc``; flags ``-O2 -std=c99
-fPIC`` and ``-fopenmp`` when the compiler accepts it (probed once per compiler). The model's
units and the runtime's build in parallel; the runtime's object files do not change from one
model to the next and are kept in the compile cache under a key of their sources, the
compiler's identity and the flags (they are built with hidden visibility: a library exports
only its model's functions). The FMU export builds its library here too.
"""
from __future__ import annotations

import functools
import os
import shlex
import shutil
from pathlib import Path

from bgc.base.errors import ModelError, oneline
from bgc.base.outfiles import write_output
from bgc.base.paths import templates_dir
from bgc.base.safeio import read_bytes
from bgc.base.store import Cache

CFLAGS = ("-O2", "-std=c99", "-fPIC")
#: The runtime's objects export nothing from a library (the model's units call them inside
#: it; the binding calls only the model's bgcm_ functions, an FMU only fmi2 functions).
RUNTIME_FLAGS = ("-fvisibility=hidden",)
RUNTIME_DIR = "c/runtime"
LIB_NAME = "libmodel.so"


class CompilerMissing(ModelError):
    """No working C compiler: the C backend cannot build (the numpy backend still can)."""

    def __init__(self, message: str):
        super().__init__(None, message)


class CUnsupported(ModelError):
    """The model needs something the C printer does not write yet
    (:func:`bgc.backends.c.printer.unsupported`); here, light, so that a caller can catch it
    without importing the printer (sympy)."""


class CompilerFailed(ModelError):
    """The C compiler refused the generated sources (a compiler that does not build C99, or
    a model bgc printed wrongly): one located line with the compiler's first error."""


def cc_text() -> str:
    """The compiler command as set (CC, else cc), for messages: never fails."""
    return os.environ.get("CC", "").strip() or "cc"


def compiler() -> list[str]:
    cc = cc_text()
    try:
        return shlex.split(cc)
    except ValueError as exc:  # an unbalanced quote
        raise CompilerMissing(f"no C compiler: CC={cc!r} cannot be split into a command "
                              f"({exc}); set CC, or use the numpy backend") from None


def _run_version(cc: tuple[str, ...]) -> str:
    import subprocess

    try:
        out = subprocess.run(list(cc) + ["--version"], capture_output=True, text=True,
                             timeout=30)
    except (OSError, subprocess.SubprocessError) as exc:
        raise CompilerMissing(f"no C compiler: {' '.join(cc)!r} cannot run ({exc}); set CC, or "
                              "use the numpy backend") from None
    if out.returncode != 0:
        raise CompilerMissing(f"no C compiler: `{' '.join(cc)} --version` failed; set CC, or "
                              "use the numpy backend")
    return out.stdout.strip()


def _stamp(cc: tuple[str, ...]) -> str | None:
    """The compiler executable's resolved path, size, change time and inode (ccache's
    "mtime" check): while they hold, its `--version` text is the one kept in the cache, and a
    warm run starts no compiler. None when the command is not a file on PATH."""
    exe = shutil.which(cc[0]) if cc else None
    if exe is None:
        return None
    try:
        real = os.path.realpath(exe)
        st = os.stat(real)
    except OSError:
        return None
    return "\0".join([*cc, real, str(st.st_size), str(st.st_mtime_ns), str(st.st_ctime_ns),
                      str(st.st_ino)])


@functools.lru_cache(maxsize=None)
def _identity(cc: tuple[str, ...]) -> str:
    import hashlib

    stamp = _stamp(cc)
    if stamp is not None:
        try:
            key = "cc-" + hashlib.sha256(stamp.encode()).hexdigest()[:32]
            d = Cache().get_or_build("c-runtime", key, lambda tmp: (tmp / "identity").write_text(
                _run_version(cc), encoding="utf-8"))
            text = (d / "identity").read_text(encoding="utf-8")
            if text:
                return text
        except (OSError, UnicodeError, ModelError) as exc:
            if isinstance(exc, CompilerMissing):
                raise
    return _run_version(cc)


def identity() -> str:
    """The compiler's command and `--version` text (part of every C cache key)."""
    cc = tuple(compiler())
    return " ".join(cc) + "\n" + _identity(cc)


def available() -> bool:
    try:
        identity()
        return True
    except CompilerMissing:
        return False


@functools.lru_cache(maxsize=None)
def _openmp(cc: tuple[str, ...]) -> bool:
    """Does the compiler build OpenMP code? Probed once per compiler; the answer is kept in
    the compile cache (when there is a safe one), so a warm run starts no compiler."""
    import hashlib

    ident = hashlib.sha256(_identity(cc).encode() + b"\0" + " ".join(cc).encode()).hexdigest()
    try:
        store = Cache()
        d = store.get_or_build("c-runtime", "openmp-" + ident[:32],
                               lambda tmp: (tmp / "openmp").write_text(
                                   "1" if _probe_openmp(cc) else "0"))
        return (d / "openmp").read_text() == "1"
    except (OSError, ModelError):
        return _probe_openmp(cc)


def _probe_openmp(cc: tuple[str, ...]) -> bool:
    import subprocess
    import tempfile

    with tempfile.TemporaryDirectory(prefix="bgc-omp-") as d:
        src = Path(d) / "probe.c"
        src.write_text("#include <omp.h>\nint f(void) { return omp_get_max_threads(); }\n")
        r = subprocess.run(list(cc) + ["-fopenmp", "-fPIC", "-shared", "-o",
                                       str(Path(d) / "probe.so"), str(src)],
                           capture_output=True, timeout=60)
        return r.returncode == 0


def flags() -> tuple[str, ...]:
    """The compile flags for the current compiler (with -fopenmp when it has OpenMP)."""
    cc = tuple(compiler())
    _identity(cc)
    return CFLAGS + (("-fopenmp",) if _openmp(cc) else ())


#: A model whose C units hold more than this many bytes together builds them at -O0: gcc's
#: optimiser is the cold path's largest cost there, and the units are straight-line code.
#: Measured by bench/bench_cflags.py on a 300-node RC ladder (325 KB of C in 6 units):
#: -O0 built the units 3.9x faster than -O2 (6.8 s against 26.4 s of CPU) and ran Radau
#: 3.0x slower (0.55 s against 0.18 s); -O1 built no faster than -O2. Above about 1 MB the
#: build's seconds saved outweigh a run's fractions of a second lost, for one run.
BIG_MODEL_BYTES = 1_000_000


def model_flags(srcdir: Path, files: list[str]) -> list[str]:
    """The flags of a model's own units: :func:`flags`, with -O0 for -O2 when the units
    together are larger than BIG_MODEL_BYTES (the runtime's objects keep -O2)."""
    fl = list(flags())
    if sum((Path(srcdir) / f).stat().st_size for f in files) > BIG_MODEL_BYTES:
        fl = ["-O0" if f == "-O2" else f for f in fl]
    return fl


def runtime_sources() -> list[Path]:
    d = templates_dir() / RUNTIME_DIR
    return sorted(d.glob("*.c"))


def runtime_headers() -> list[Path]:
    return sorted((templates_dir() / RUNTIME_DIR).glob("*.h"))


def runtime_key() -> str:
    import hashlib

    h = hashlib.sha256()
    for f in runtime_sources() + runtime_headers():
        h.update(f.name.encode() + b"\0" + f.read_bytes() + b"\0")
    h.update(identity().encode() + b"\0" + " ".join(flags() + RUNTIME_FLAGS).encode())
    return h.hexdigest()[:32]


def _cc(args: list[str], cwd: Path, coord=None) -> None:
    import subprocess


    cc = compiler()
    exe = shutil.which(cc[0]) if cc else None  # a relative CC (./mycc) from the caller's folder
    try:
        r = subprocess.run(([os.path.abspath(exe)] + cc[1:] if exe else cc) + args, cwd=cwd,
                           capture_output=True, text=True, errors="replace")
    except OSError as exc:
        raise CompilerFailed(coord, f"the C compiler ({' '.join(cc)}) cannot run: {exc}") from None
    if r.returncode != 0:
        what = next((ln for ln in r.stderr.splitlines() if "error" in ln.lower()),
                    r.stderr.strip().splitlines()[0] if r.stderr.strip() else
                    f"exit status {r.returncode}")
        target = args[args.index("-o") + 1] if "-o" in args else "?"
        raise CompilerFailed(coord, f"the C compiler ({' '.join(compiler())}) failed building "
                                    f"{Path(target).name}: {oneline(what, 300)}")


class _Stopped(Exception):
    """An early runtime build stopped because its compile failed (nothing is kept)."""


def _runtime_objects(cache, jobs: int, tmpdir, coord=None, stop=None) -> list[Path]:
    """The runtime's object files, compiled once per (sources, compiler, flags). ``stop`` (a
    threading.Event): set, no further source is started and the entry is not made."""
    fl = list(flags() + RUNTIME_FLAGS)
    key = runtime_key()

    def build(tmp: Path):
        from concurrent.futures import ThreadPoolExecutor

        inc = runtime_sources()[0].parent if runtime_sources() else tmp
        srcs = runtime_sources()

        def one(s):
            if stop is not None and stop.is_set():
                raise _Stopped
            _cc(fl + ["-I", str(inc), "-c", str(s), "-o", str(tmp / (s.stem + ".o"))], tmp,
                coord)
        with ThreadPoolExecutor(max_workers=jobs) as ex:
            list(ex.map(one, srcs))

    if cache is not None:
        d = cache.get_or_build("c-runtime", key, build, stop=stop)
    else:  # uncached: built beside the model's objects, removed with them
        d = Path(tmpdir) / "runtime"
        d.mkdir()
        build(d)
    return sorted(d.glob("*.o"))


#: the compile cache's folder -> (the thread building the runtime's objects there ahead, the
#: event that stops it)
_EARLY: dict = {}


def start_runtime(cache) -> None:
    """Build the runtime's objects into ``cache`` in a background thread, unless they are
    there already: a cold C compile's Python stages (parse to print, one core) run meanwhile,
    and :func:`build_library` finds the objects built (it waits for the thread first). The
    compilers run one at a time, leaving a core to the compile. A failure here is silent:
    the build then compiles them itself and reports it where it always did. A compile that
    fails stops the thread (:func:`stop_runtime`: no source started after, no entry made);
    the thread is no daemon, so a process that ends waits for its last compiler and leaves
    nothing half-built."""
    import threading

    root = str(cache.path)
    if root in _EARLY:
        return
    stop = threading.Event()

    def work():
        try:
            _runtime_objects(cache, max(1, (os.cpu_count() or 1) - 1), None, stop=stop)
        except Exception:  # noqa: BLE001 - reported by the build, which compiles them again
            pass
    t = threading.Thread(target=work, name="bgc-c-runtime", daemon=False)
    _EARLY[root] = (t, stop)
    t.start()


def stop_runtime(cache) -> None:
    """Stop :func:`start_runtime`'s thread for this cache, if no build took it (the compile
    failed, the C printer refused, another process made the entry): the compiler running
    finishes, no other starts, nothing is kept. After a build that linked: nothing to do."""
    got = _EARLY.pop(str(cache.path), None)
    if got is not None:
        got[1].set()


def _wait_runtime(cache) -> None:
    """Wait for :func:`start_runtime`'s thread for this cache, if one was started."""
    got = _EARLY.pop(str(cache.path), None) if cache is not None else None
    if got is not None:
        got[0].join()


def build_library(srcdir: Path, files: list[str], cache=None, jobs: int | None = None,
                  extra: tuple[str, ...] = (), lib_name: str = LIB_NAME, coord=None,
                  inputs=None) -> Path:
    """Compile the model's C files in srcdir (in parallel) with :func:`flags` (and ``extra``,
    for these files only: the FMU's ``-fvisibility=hidden``), link them with the runtime's
    objects (the compile cache's, when given) into srcdir/lib_name. Raises CompilerMissing
    without a compiler, CompilerFailed (at ``coord``) when it refuses the sources. The
    library goes through the checked writer: never over ``inputs``, a link or anything but
    a regular file."""
    identity()
    srcdir = Path(srcdir).resolve()  # the compiler runs in srcdir: a relative path would not
    jobs = jobs or os.cpu_count() or 1
    fl = list(flags())
    unit_fl = model_flags(srcdir, files)
    inc = str(runtime_sources()[0].parent) if runtime_sources() else str(srcdir)
    if not runtime_sources():
        raise ModelError(None, "the C runtime (templates/c/runtime/*.c) is not installed: "
                               "use the numpy backend")
    import tempfile
    from concurrent.futures import ThreadPoolExecutor

    objdir = Path(tempfile.mkdtemp(prefix="bgc-obj-"))

    def runtime():  # (those start_runtime is building: waited for beside the model's units)
        _wait_runtime(cache)
        return _runtime_objects(cache, jobs, objdir, coord)
    try:
        with ThreadPoolExecutor(max_workers=jobs) as ex:
            rt = ex.submit(runtime)
            objs = list(ex.map(
                lambda f: (_cc(unit_fl + list(extra) + ["-I", inc, "-c", str(srcdir / f), "-o",
                                                   str(objdir / (Path(f).stem + ".o"))],
                               srcdir, coord),
                           objdir / (Path(f).stem + ".o"))[1], files))
            rt_objs = rt.result()
        lib = objdir / lib_name  # linked in bgc's own temporary folder, then written checked
        _cc(fl + ["-shared", "-o", str(lib)] + [str(o) for o in objs + rt_objs] + ["-lm"],
            srcdir, coord)
        write_output(srcdir / lib_name, read_bytes(lib, 1 << 30), inputs, "-o")
    finally:
        shutil.rmtree(objdir, ignore_errors=True)
    return srcdir / lib_name
