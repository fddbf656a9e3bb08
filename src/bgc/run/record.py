"""Run records: a warm `bgc simulate` that replays a checked run without parsing anything.

ccache's "direct mode" for scenes. Once `bgc simulate` has run a scene through the compile
cache, it keeps a *record* of the run: every file the run read (the model, the files it
imports, the tables) with a digest of its bytes, the compile-cache entry of the module, the
compiler's stamp (C), and the module's ``simulate`` arguments as the scene resolved them (time
span, output step, method, tolerances, breakpoints, run-time parameters, initial state).

A later `bgc simulate` with the same scene file (same path and bytes), the same options, the
same bgc and the same Python looks the record up *before* importing click, PyYAML or bgc's
parser. It reads every file the record names again and compares digests; when all agree and
the module's entry is still in the (checked) cache, it loads the module and runs it: the run is
the one the full way would make, argument for argument. Anything else (no record, a changed or
missing file, another compiler, an option or spelling it does not know, ``--plot``,
``--no-cache``, an unsafe cache) goes the full way, which decides every message. A run that
fails numerically is diagnosed by the full way's code (its located message, exit status 1).

The record key: bgc's version, a stamp of bgc's sources and templates (name, size, mtime),
Python's version, the installed sympy, the scene's absolute and resolved paths and bytes, the
options that shape the run, and ``CC`` and ``PATH`` (which compiler). Each file the run read
is kept as reached (the path the parser opened), as resolved and by the digest of its bytes:
a replay needs all three to agree (bgc.base.reach, read with the bounded reader), so a
re-pointed link or a moved folder goes the full way. A record that cannot be decoded or whose
fields are out of range is discarded with a note. Records are marshal data in the
checked cache directory (``<cache>/run``), each written to a temporary file and renamed over
its place, so a reader sees a whole record or none, and the newest run's record wins.
"""
from __future__ import annotations

import marshal
import os
import stat
import sys
import time
from pathlib import Path

from bgc.backends.c import build as cbuild
from bgc.backends.load import load_entry
from bgc.base import __version__
from bgc.base.limits import LIMITS
from bgc.base.outfiles import Inputs, check_output, write_output
from bgc.base.paths import code_files
from bgc.base.reach import MAX_BYTES
from bgc.base.safeio import read_bytes
from bgc.base.store import UnsafeCache, check_dir
from bgc.run.cache import Cache, tool_versions
from bgc.run.event_log import event_arrays
from bgc.run.progress import Progress, simulating_line, summary_line

#: Record format; bump when the record's fields change.
FORMAT = 2
#: The largest scene a replay reads (larger ones go the full way, which refuses them).
SCENE_BYTES = 16 << 20
TARGET = "run"

#: `bgc simulate` options a record replays: (name, takes a value). Output options (``--out``,
#: ``-q``) are not part of the key; anything else (``--plot``, ``--no-cache``, ``--help``, an
#: unknown option) goes the full way.
_VALUED = {"--out": "out", "--method": "method", "--rtol": "rtol", "--atol": "atol",
           "--max-wall": "max_wall", "--backend": "backend", "--t-end": "t_end",
           "--max-steps": "max_steps"}
_FLAGS = {"-q": "quiet", "--quiet": "quiet", "--strict-causality": "strict_causality"}


def _blake():
    try:
        from _blake2 import blake2b  # CPython's own: no OpenSSL to load
    except ImportError:  # pragma: no cover - other Pythons
        from hashlib import blake2b
    return blake2b(digest_size=32)


def digest(data: bytes) -> str:
    h = _blake()
    h.update(data)
    return h.hexdigest()


# ---------------------------------------------------------------------------------------------
# The key

def code_stamp() -> str:
    """bgc's sources, in every subpackage, and templates by name, size and modification time
    (as Python's own byte code cache checks its sources): an edit anywhere in bgc invalidates
    every record."""
    out: list[str] = []
    for name, path in code_files():
        try:
            st = os.stat(path)
        except OSError:
            continue
        out.append(f"{name}:{st.st_size}:{st.st_mtime_ns}")
    return "\n".join(out)


def options_text(method, rtol, atol, max_wall, backend, strict_causality, t_end=None,
                 max_steps=None) -> str:
    """The options that shape a run, one spelling per value (floats by repr)."""
    f = lambda v: "" if v is None else repr(float(v))  # noqa: E731
    return (f"method={method or ''};rtol={f(rtol)};atol={f(atol)};max_wall={f(max_wall)};"
            f"backend={backend or ''};strict={bool(strict_causality)};t_end={f(t_end)};"
            f"max_steps={'' if max_steps is None else int(max_steps)}")


def record_key(scene_path: str, scene_bytes: bytes, options: str) -> str:
    h = _blake()
    for part in (f"bgc run record {FORMAT}", __version__, sys.version, tool_versions(),
                 code_stamp(), os.path.abspath(scene_path), os.path.realpath(scene_path),
                 options,
                 os.environ.get("CC", ""), os.environ.get("PATH", "")):
        h.update(part.encode("utf-8", "surrogateescape") + b"\0")
    h.update(scene_bytes)
    return h.hexdigest()


# ---------------------------------------------------------------------------------------------
# Storage (in the compile cache's checked directory)

def _path(store, key: str) -> str:
    return os.path.join(str(store.path), TARGET, key[:2], key)


def _plain(v):
    """v as marshal-safe plain data (floats, ints, strings, lists, dicts), else ValueError."""
    if v is None or isinstance(v, (bool, int, float, str)):
        return v
    if hasattr(v, "tolist") and not isinstance(v, (list, tuple, dict)):
        return _plain(v.tolist())
    if isinstance(v, (list, tuple)):
        return [_plain(x) for x in v]
    if isinstance(v, dict) and all(isinstance(k, str) for k in v):
        return {k: _plain(x) for k, x in v.items()}
    raise ValueError(f"not plain data: {type(v).__name__}")


def save(store, key: str, record: dict) -> bool:
    """Write a record (replacing an older one under the key); False when it cannot be kept
    (an unsafe or unwritable cache, data that is not plain)."""
    try:
        data = marshal.dumps(_plain(record))
        top = store._ensure()
        parent = os.path.join(str(top), TARGET, key[:2])
        os.makedirs(parent, mode=0o700, exist_ok=True)
        for sub in (Path(top) / TARGET, Path(parent)):
            check_dir(sub)
        tmp = os.path.join(parent, f".{key[:16]}.{os.getpid()}.{os.urandom(6).hex()}.tmp")
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0),
                     0o600)
        try:
            with os.fdopen(fd, "wb") as fh:
                fh.write(data)
            os.replace(tmp, os.path.join(parent, key))
        except BaseException:
            try:
                os.unlink(tmp)
            except OSError:
                pass
            raise
        return True
    except (OSError, ValueError, UnsafeCache):
        return False


def load(store, key: str) -> dict | None:
    """The record under key, or None (none, unreadable, not the user's, writable by others)."""
    p = _path(store, key)
    try:
        st = os.lstat(p)
        if not stat.S_ISREG(st.st_mode) or (hasattr(os, "getuid") and st.st_uid != os.getuid()) \
                or st.st_mode & (stat.S_IWGRP | stat.S_IWOTH) or st.st_size > (64 << 20):
            return None
        for sub in (store.path, store.path / TARGET, Path(p).parent):
            check_dir(Path(sub))
        data = read_bytes(p, 64 << 20, follow=False)
    except (OSError, UnsafeCache):
        return None
    try:
        rec = marshal.loads(data)
        why = None if isinstance(rec, dict) and rec.get("format") != FORMAT else _invalid(rec)
    except (ValueError, EOFError, TypeError, RecursionError, MemoryError) as exc:
        why = f"{type(exc).__name__}"
    if why is not None:
        _discard(p, why)
        return None
    if rec.get("format") != FORMAT:
        return None
    return rec


def _discard(path: str, why: str) -> None:
    """A corrupt record: removed (the full way runs and writes a new one), with a note."""
    print(f"note: discarded a corrupt record of an earlier run ({why}); running the scene the "
          "full way", file=sys.stderr)
    try:
        os.unlink(path)
    except OSError:
        pass


def _finite(v, positive: bool = False) -> bool:
    import math

    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and \
        (v > 0 or not positive)


def _invalid(rec) -> str | None:
    """Why a decoded record cannot be replayed (None: it can): every field has the type and
    range the full way writes, so a damaged record never reaches the module's simulate."""
    if not isinstance(rec, dict):
        return "not a record"
    run = rec.get("run")
    if not isinstance(run, dict):
        return "no run arguments"
    span = run.get("t_span")
    if not (isinstance(span, list) and len(span) == 2 and all(_finite(v) for v in span)
            and span[1] > span[0]):
        return "bad t_span"
    dt = run.get("dt")
    if dt is not None and not (_finite(dt, True) and
                               (span[1] - span[0]) / dt <= LIMITS.output_samples):
        return "bad dt"
    for k in ("rtol", "atol"):
        if not _finite(run.get(k), True):
            return f"bad {k}"
    ms, mw = run.get("max_step"), run.get("max_wall")
    if not (isinstance(ms, (int, float)) and ms > 0) or not (mw is None or _finite(mw, True)):
        return "bad max_step or max_wall"
    if not isinstance(run.get("method"), str) or not isinstance(run.get("breakpoints"), list):
        return "bad method or breakpoints"
    files = rec.get("files")
    if not (isinstance(files, list) and all(
            isinstance(f, list) and len(f) == 3 and all(isinstance(x, str) for x in f)
            for f in files)):
        return "bad file list"
    for k in ("backend", "key", "name", "scene_name", "scene_digest"):
        if not isinstance(rec.get(k), str):
            return f"bad {k}"
    if rec["backend"] not in ("numpy", "c") or not isinstance(rec.get("inputs"), list):
        return "bad backend or inputs"
    return None


# ---------------------------------------------------------------------------------------------
# Writing a record (the full way, after a successful run)

def keep(scene_path, options: str, result) -> bool:
    """Record a completed run (a bgc.run.runner.SceneResult) of the scene file ``scene_path``
    under ``options`` (options_text). The digests are of the very bytes the module's cache key
    was made of; a scene that changed since is not recorded."""
    if result.cache_entry is None or result.run_args is None:
        return False

    backend, mkey, files, scene_bytes = result.cache_entry
    try:
        if scene_bytes is None or read_bytes(scene_path, SCENE_BYTES) != scene_bytes:
            return False
    except OSError:
        return False
    comp = None
    if backend == "c":
        comp = cbuild._stamp(tuple(cbuild.compiler()))
        if comp is None:
            return False
    rec = {"format": FORMAT, "files": [[f.path, f.resolved, digest(f.data)] for f in files],
           "scene_digest": digest(scene_bytes), "inputs": [f.resolved for f in files],
           "backend": backend, "key": mkey, "name": result.module_name, "compiler": comp,
           "scene_name": result.scene.name, "run": result.run_args,
           "why": result.backend_why}
    try:  # a record is an optimisation: a file of bgc's that vanished meanwhile skips it
        key = record_key(scene_path, scene_bytes, options)
    except OSError:
        return False
    return save(Cache(), key, rec)


# ---------------------------------------------------------------------------------------------
# Replaying one (the fast way)

def _parse(argv: list[str]) -> dict | None:
    """`bgc simulate` arguments as the record replays them, or None for anything else."""
    opts: dict = {"scene": None}
    i = 0
    while i < len(argv):
        a = argv[i]
        if a in _FLAGS:
            name = _FLAGS[a]
            if name in opts:
                return None
            opts[name] = True
        elif a.split("=", 1)[0] in _VALUED:
            head, eq, val = a.partition("=")
            if not eq:
                i += 1
                if i >= len(argv):
                    return None
                val = argv[i]
            name = _VALUED[head]
            if name in opts:
                return None
            opts[name] = val
        elif a.startswith("-") or opts["scene"] is not None:
            return None  # --plot, --no-cache, --help, "--", a second argument: the full way
        else:
            opts["scene"] = a
        i += 1
    if not opts["scene"] or ("out" in opts and not opts["out"]):  # "--out=": the full way
        return None
    try:
        for k in ("rtol", "atol", "max_wall", "t_end"):
            if k in opts:
                opts[k] = float(opts[k])
        if "max_steps" in opts:
            opts["max_steps"] = int(opts["max_steps"])
    except ValueError:
        return None
    return opts


def replay(argv: list[str]) -> int | None:
    """Run `bgc simulate ARGV` from its record; None when the full way must run it."""
    opts = _parse(argv)
    if opts is None:
        return None
    t0 = time.perf_counter()
    scene = opts["scene"]
    try:
        scene_bytes = read_bytes(scene, SCENE_BYTES)  # regular files only, never blocking
        store = Cache()
        options = options_text(opts.get("method"), opts.get("rtol"), opts.get("atol"),
                               opts.get("max_wall"), opts.get("backend"),
                               opts.get("strict_causality", False), opts.get("t_end"),
                               opts.get("max_steps"))
        rec = load(store, record_key(scene, scene_bytes, options))
        if rec is None or rec["scene_digest"] != digest(scene_bytes) or not unchanged(rec):
            return None
        backend = rec["backend"]
        if backend == "c":
            if cbuild._stamp(tuple(cbuild.compiler())) != rec["compiler"]:
                return None
        entry = store.get(backend, rec["key"])
        if entry is None:
            return None
        t_np = time.perf_counter()
        if backend == "c":
            # The run calls no BLAS (scipy is not imported): numpy's OpenBLAS need not start
            # its threads, which spin for a while after numpy's import and take a core from
            # a busy machine. A value the user set is kept.
            os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
        import numpy  # noqa: F401 (not counted as the module's load time)

        return _run(rec, opts, store, entry, scene, t0 + time.perf_counter() - t_np)
    except (OSError, ValueError, KeyError, TypeError, ImportError):
        return None
    except Exception as exc:  # noqa: BLE001 - the cache's refusals and the like: full way
        from bgc.base.errors import ModelError

        if isinstance(exc, ModelError):
            return None
        raise


def unchanged(rec: dict) -> bool:
    """Whether every file the record names is still what the run read: reached by the same
    path, resolving to the same file (a re-pointed link or a moved folder is a change), with
    the same bytes (read with the bounded reader)."""
    for path, resolved, dg in rec["files"]:
        if os.path.realpath(path) != resolved or digest(read_bytes(path, MAX_BYTES)) != dg:
            return False
    return True


def _run(rec: dict, opts: dict, store, entry, scene: str, t0: float) -> int | None:
    import numpy as np

    say = Progress(bool(opts.get("quiet")), t0)
    out = opts.get("out")
    ins = Inputs([scene, *rec["inputs"]])
    if out:
        check_output(out, ins, "--out")  # a refusal: the full way says so
    backend, run = rec["backend"], rec["run"]
    say(f"cache hit ({backend} {rec['key'][:12]}, run record)")
    with np.errstate(all="ignore"):  # X0 is computed on import: no numpy warnings
        mod = load_entry(entry, backend, rec["name"], trusted=True)
    t1 = time.perf_counter()
    method, rtol, atol = run["method"], run["rtol"], run["atol"]
    why = rec.get("why") if isinstance(rec.get("why"), str) else ""
    say(simulating_line(rec["scene_name"], method, backend, rtol, atol, why))
    x0 = run["x0"]
    p = run["p"]
    try:
        res = mod.simulate(tuple(run["t_span"]), dt=run["dt"], method=method, rtol=rtol,
                           atol=atol, p=p, breakpoints=tuple(run["breakpoints"]),
                           x0=None if x0 is None else np.array(x0, dtype=float),
                           max_step=run["max_step"], max_steps=run["max_steps"],
                           max_wall=run["max_wall"])
    except mod.SimulationError as exc:
        return _failed(scene, mod, exc, p, opts)
    t2 = time.perf_counter()
    t, x, y = res
    if getattr(mod, "CONSTRAINT_DROPPED", ()):
        # lazy: numpy's watch of dropped constraint components, only for modules that drop one
        from bgc.run.watch import dropped_drift

        drift = dropped_drift(mod, t, x, p, rtol, atol)
        if drift:
            say(f"warning: {drift}")
    if out:
        import io


        buf = io.BytesIO()
        np.savez_compressed(buf, t=t, **y, **event_arrays(getattr(res, "events", ()), x.shape[0]))
        write_output(out, buf.getvalue(), ins, "--out")
        say(f"wrote {out}")
    print(summary_line(rec["scene_name"], t, method, rtol, atol, backend, res.stats, t1 - t0,
                       t2 - t1, why), flush=True)
    return 0


def _failed(scene: str, mod, exc, p, opts) -> int | None:
    """A run that failed: the full way's located diagnosis (it parses and compiles the scene,
    as a failed run of the full way does), exit status 1."""
    # lazy: the compile path, which a warm run never loads
    from bgc.format.scene import parse_scene
    from bgc.run.runner import _compiled, simulation_failed

    sc = parse_scene(scene)
    c, _ = _compiled(sc, None, bool(opts.get("strict_causality")))
    err = simulation_failed(c, mod, sc, exc, p)
    print(f"error: {err}" if err.coord is None else str(err), file=sys.stderr)
    return 1
