"""Fork-server harness for the hostile corpus (issue 10).

One parent process imports bgc (and sympy, numpy, scipy, matplotlib) once; every case runs in
a child made with ``os.fork``: the child puts itself in its own process group, limits its
address space (``RLIMIT_AS``: the parent's size plus ``MEM_LIMIT``), moves into a fresh
temporary directory that holds the case's files and a canary, points ``TMPDIR`` at an empty
folder of its own, and runs the real command line (``bgc.cli.commands.main``) with its stdout and stderr
sent to files. A run that outlasts ``TIMEOUT`` seconds is killed with its whole process group.
When a compile succeeded, the child also loads the module it wrote (compiled from its text, in
memory) and evaluates ``rhs(0, X0)``: a payload hidden in the module would run there, in the
child, and show as a changed canary or a new file.

The parent then judges the case against the property of the issue:

* ``ok``: exit status 0, no traceback or warning on stderr, exactly the requested outputs new
  (regular files, mode 0644 under umask 022), every other file unchanged (the canary too),
  ``TMPDIR`` empty; a written module parses, its top-level statements are the template's own
  (the skeleton of modules bgc generates from the clean models in models/, built at test
  time), it loads, and ``rhs`` at ``X0`` is finite;
* ``error``: exit status 2 (or the listed ones), exactly one line on stderr, of the form
  ``file:line:col: message`` (``error: message`` where the case allows it), containing the
  expected pattern (a case-insensitive regular expression) and at the expected line, no
  traceback, nothing written, ``TMPDIR`` empty;
* ``any``: one of the two (the property alone, for inputs where either answer is right).

Command line::

    python -m tests.fuzz.harness --summary [CORPUS_DIR] [-k SUBSTRING] [-v]

prints pass/fail per category (and each failing case with its reasons); CORPUS_DIR defaults to
tests/fuzz/corpus and must hold an ``expected.yaml`` manifest (see make_corpus.py).
"""
from __future__ import annotations

import ast
import hashlib
import json
import os
import re
import resource
import shutil
import signal
import stat
import sys
import tempfile
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("MPLBACKEND", "Agg")

import yaml  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
FUZZ = Path(__file__).resolve().parent
CORPUS = FUZZ / "corpus"

#: Address space a case may add to the parent's (bytes).
MEM_LIMIT = 2 << 30
#: Wall-clock seconds per case (all of its runs together).
TIMEOUT = float(os.environ.get("BGC_FUZZ_TIMEOUT", "20"))
#: Longest message (after the location) an error may print.
MAX_MESSAGE = 1000
CANARY = "canary.txt"
#: argv[0] that makes a child run argv[1] as Python instead of bgc (tests of the harness).
SELFTEST = "--harness-selftest-exec"
CANARY_TEXT = "the canary: bgc must never touch this file\n"
#: Modules a generated module may import besides numpy (the printer's own imports).
ALLOWED_IMPORTS = re.compile(r"^(numpy|scipy|math)(\.|$)")
_LOC = re.compile(r"^(.*?):(\d+):(\d+): (.*)$", re.S)


# ---------------------------------------------------------------------------------------------
# the manifest


@dataclass
class Case:
    id: str
    category: str
    argv: list
    expect: str  # ok | error | any
    files: dict = field(default_factory=dict)  # name in the work folder -> corpus-relative path
    setup: list = field(default_factory=list)
    outputs: list = field(default_factory=list)
    message: str | None = None
    line: object = None  # int, list of ints, or None (not checked)
    located: bool = True  # an error must be file:line:col (False: error: ... allowed too)
    exit: list = field(default_factory=lambda: [2])
    check: list | None = None  # a second command (bgc check) run after argv
    usage: bool = False  # click's own usage error (several lines) is acceptable
    twin: str | None = None  # a model (same physics, clean names): equal rhs and X0 if ok
    note: str = ""
    env: dict = field(default_factory=dict)  # environment variables of the child (CC=...)


def load_manifest(corpus: Path = CORPUS) -> list[Case]:
    data = yaml.safe_load((Path(corpus) / "expected.yaml").read_text(encoding="utf-8"))
    return [Case(**c) for c in data["cases"]]


# ---------------------------------------------------------------------------------------------
# the template's skeleton


def _target_sig(t):
    if isinstance(t, ast.Name):
        return t.id
    if isinstance(t, ast.Subscript):
        return ("subscript", _target_sig(t.value))
    if isinstance(t, (ast.Tuple, ast.List)):
        return tuple(_target_sig(e) for e in t.elts)
    return ast.dump(t)


def skeleton(tree: ast.Module) -> list:
    """The top-level statements as (kind, name...) tuples: what a template fixes."""
    sig = []
    for i, st in enumerate(tree.body):
        if isinstance(st, ast.Import):
            names = [(a.name, a.asname) for a in st.names]
            if all(ALLOWED_IMPORTS.match(n) for n, _ in names) and names != [("numpy", "np")]:
                continue  # the printer's extra imports vary with the model
            sig.append(("import", tuple(names)))
        elif isinstance(st, ast.Expr):
            doc = (i == 0 and isinstance(st.value, ast.Constant)
                   and isinstance(st.value.value, str))
            sig.append(("docstring",) if doc else ("expr", ast.dump(st)))
        elif isinstance(st, (ast.FunctionDef, ast.AsyncFunctionDef)):
            sig.append((type(st).__name__, st.name,
                        tuple(a.arg for a in st.args.posonlyargs + st.args.args
                              + st.args.kwonlyargs)))
        elif isinstance(st, ast.ClassDef):
            sig.append(("class", st.name, tuple(ast.dump(b) for b in st.bases)))
        elif isinstance(st, ast.Assign):
            sig.append(("assign", tuple(_target_sig(t) for t in st.targets)))
        elif isinstance(st, (ast.AnnAssign, ast.AugAssign)):
            sig.append((type(st).__name__, _target_sig(st.target)))
        else:
            sig.append((type(st).__name__, ast.dump(st)))
    return sig


_REFERENCE: list | None = None


def warm() -> None:
    """Import what the commands import, once, in the parent, and compile the numpy module's
    template there: every child starts warm (a child that imports the printer, the equation
    builders, symengine and jinja and compiles the template itself spends more on them than
    on the case; nothing a case computes is made here: no model, no result)."""
    import importlib

    for name in ("bgc.cli.commands", "bgc.run.driver", "bgc.run.runner", "bgc.format.scene",
                 "bgc.core.draw", "bgc.run.plots", "bgc.studies.accuracy",
                 # what a compile imports lazily (driver -> equations -> printer)
                 "bgc.core.equations", "bgc.core.fastsym", "bgc.core.modes", "bgc.lower",
                 "bgc.backends.numpy.printer", "bgc.backends.skeleton", "symengine", "jinja2",
                 # and a simulate on the C backend
                 "bgc.backends.c.printer", "bgc.core.specialize", "bgc.run.record",
                 "sympy.printing.c", "sympy.codegen.cfunctions", "sympy.combinatorics",
                 "sympy.tensor.tensor", "sympy.sets.setexpr", "concurrent.futures.thread",
                 "scipy.integrate", "scipy.sparse", "scipy.sparse.linalg", "scipy.linalg",
                 "matplotlib.pyplot"):
        try:
            importlib.import_module(name)
        except Exception:  # noqa: BLE001 - a child will report it
            pass
    try:  # the templates, compiled once (jinja's environment keeps them; a child finds them)
        from bgc.backends.c import printer as c_printer
        from bgc.backends.numpy import printer as np_printer

        np_printer._environment().get_template(f"{np_printer._TEMPLATES}/module.py.j2")
        env = c_printer.template_env()
        for name in ("c/model.c.j2", "c/part.c.j2", "c/tables.c.j2", "c/newton.c.j2",
                     "c/wrapper.py.j2"):
            env.get_template(name)
    except Exception:  # noqa: BLE001 - a child will report it
        pass


def reference_models() -> list[Path]:
    """The clean models whose modules give the reference skeletons (msd first; not the
    3R2S: its scenes are covered by the corpus' cli cases)."""
    return [ROOT / "models" / "msd.yaml"] + sorted(
        p for p in (ROOT / "models").glob("*.yaml") if p.name not in ("msd.yaml", "3r2s.yaml"))


def golden_of(model: Path) -> Path:
    """The committed module bgc generates for a clean model: generated/<its name>.py, which
    tests/test_golden.py holds byte for byte equal to what compiling the model gives now."""
    return ROOT / "generated" / f"{yaml.safe_load(model.read_text(encoding='utf-8'))['name']}.py"


def reference_skeletons() -> list:
    """Skeletons of the modules bgc generates from the clean models (msd first): a template's
    conditional blocks (no inputs, ...) give a few variants, all of them the template's.

    Read from the models' golden modules (generated/), not compiled again in every process
    that runs cases: the rigid 3R2S alone takes half a minute to compile, and test_golden
    checks that the goldens are what the compiler writes."""
    global _REFERENCE
    if _REFERENCE is None:
        warm()
        refs = []
        for p in reference_models():
            sk = skeleton(ast.parse(golden_of(p).read_text(encoding="utf-8")))
            for variant in (sk, scene_variant(sk)):
                if variant not in refs:
                    refs.append(variant)
        _REFERENCE = refs
    return _REFERENCE


def scene_variant(sk: list) -> list:
    """The skeleton of the same model's module compiled for a scene: the template's other
    branch of the linearisation block, which leaves B, C, D out and names the way to them in
    ``_NO_LINEAR`` just before its raising ``input_jacobian`` (tests/fuzz/test_corpus.py's
    test_scene_variant_is_what_a_scene_compile_gives holds this to a real compile)."""
    at = [i for i, e in enumerate(sk) if e[:2] == ("FunctionDef", "input_jacobian")]
    return sk if not at else sk[:at[0]] + [("assign", ("_NO_LINEAR",))] + sk[at[0]:]


# ---------------------------------------------------------------------------------------------
# setting up a case's folder


def _setup(work: Path, corpus: Path, case: Case) -> None:
    (work / CANARY).write_text(CANARY_TEXT)
    for dst, src in case.files.items():
        target = work / dst
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(corpus / src, target)
    for act in case.setup:
        kind = act["kind"]
        path = work / act["name"] if "name" in act else None
        if path is not None:
            path.parent.mkdir(parents=True, exist_ok=True)
        if kind == "fifo":
            os.mkfifo(path)
        elif kind == "symlink":
            os.symlink(act["target"], path)
        elif kind == "mkdir":
            path.mkdir(parents=True, exist_ok=True)
        elif kind == "sparse":  # a huge file that takes no room
            with open(path, "wb") as fh:
                fh.truncate(int(act["size"]))
        elif kind == "repeat":  # head + item * count + tail, written at test time
            with open(path, "w", encoding="utf-8") as fh:
                fh.write(act.get("head", ""))
                item, n = act["item"], int(act["count"])
                chunk = item * max(1, 65536 // max(1, len(item)))
                per = max(1, 65536 // max(1, len(item)))
                while n >= per:
                    fh.write(chunk)
                    n -= per
                fh.write(item * n)
                fh.write(act.get("tail", ""))
        elif kind == "nulldev":  # a character device (like /dev/null) inside the folder
            try:
                os.mknod(path, stat.S_IFCHR | 0o666, os.makedev(1, 3))
            except (PermissionError, OSError):
                os.symlink("/dev/null", path)
        elif kind == "chmod":
            os.chmod(path, int(act["mode"], 8))
        else:
            raise ValueError(f"unknown setup action {kind!r}")


def snapshot(folder: Path) -> dict:
    """Every entry under folder (not following links): type, size, content hash, link target."""
    out = {}
    for dirpath, dirnames, filenames in os.walk(folder, followlinks=False):
        for name in dirnames + filenames:
            p = os.path.join(dirpath, name)
            rel = os.path.relpath(p, folder)
            st = os.lstat(p)
            if stat.S_ISREG(st.st_mode):
                if st.st_size <= 16 << 20:
                    with open(p, "rb") as fh:
                        h = hashlib.sha256(fh.read()).hexdigest()
                else:
                    h = f"size {st.st_size} mtime {st.st_mtime_ns}"
                out[rel] = ("file", st.st_size, h)
            elif stat.S_ISLNK(st.st_mode):
                out[rel] = ("link", os.readlink(p))
            elif stat.S_ISDIR(st.st_mode):
                out[rel] = ("dir",)
            else:
                out[rel] = (stat.S_IFMT(st.st_mode),)
    return out


# ---------------------------------------------------------------------------------------------
# the child


def _restore_warnings() -> None:
    """Python's own warning behaviour (a test runner may have replaced it in the parent)."""
    import warnings

    warnings.resetwarnings()
    warnings.simplefilter("default")
    for cat in (DeprecationWarning, PendingDeprecationWarning, ImportWarning, ResourceWarning):
        warnings.simplefilter("ignore", cat)

    def show(message, category, filename, lineno, file=None, line=None):
        sys.stderr.write(warnings.formatwarning(message, category, filename, lineno, line))

    warnings.showwarning = show
    if hasattr(warnings, "_showwarnmsg_impl"):
        warnings._showwarnmsg_impl = lambda msg: show(msg.message, msg.category, msg.filename,
                                                      msg.lineno, msg.file, msg.line)


def _run_cli(argv: list, res: Path, k: int) -> int:
    out_fd = os.open(res / f"{k}.out", os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    err_fd = os.open(res / f"{k}.err", os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    os.dup2(out_fd, 1)
    os.dup2(err_fd, 2)
    os.close(out_fd)
    os.close(err_fd)
    # as a real interpreter opens them: stdout strict, stderr backslashreplace
    sys.stdout = open(1, "w", encoding="utf-8", errors="strict", closefd=False)
    sys.stderr = open(2, "w", encoding="utf-8", errors="backslashreplace", closefd=False)
    from bgc.cli.commands import main

    code = 0
    try:
        if argv and argv[0] == SELFTEST:  # the harness's own tests: run this code instead
            exec(argv[1], {"__name__": "__selftest__"})  # noqa: S102
        else:
            main(args=list(argv), prog_name="bgc", standalone_mode=True)
    except SystemExit as exc:
        c = exc.code
        code = 0 if c is None else (c if isinstance(c, int) else 1)
        if not isinstance(c, (int, type(None))):
            sys.stderr.write(f"{c}\n")
    except BaseException:  # noqa: BLE001 - what the interpreter would print
        traceback.print_exc()
        code = 1
    for s in (sys.stdout, sys.stderr):
        try:
            s.flush()
        except Exception:  # noqa: BLE001
            pass
    return code


def _load_eval(path: str) -> dict:
    """Load a generated module from its text (in memory) and evaluate rhs at X0."""
    import types

    import numpy as np

    src = Path(path).read_text(encoding="utf-8")
    mod = types.ModuleType("bgc_fuzz_module")
    mod.__file__ = "<fuzz module>"
    exec(compile(src, path, "exec"), mod.__dict__)  # noqa: S102 - the point of the test
    x0 = np.asarray(mod.X0, dtype=float)
    with np.errstate(all="ignore"):
        r = np.asarray(mod.rhs(0.0, x0), dtype=complex)
    return {"x0": [float(v) for v in np.ravel(x0)],
            "rhs": [[float(v.real), float(v.imag)] for v in np.ravel(r)],
            "finite": bool(np.all(np.isfinite(r)) and np.all(np.isfinite(x0))
                           and np.all(np.imag(r) == 0)),
            "shape_ok": r.shape == x0.shape}


def _child(work: Path, tmp: Path, res: Path, case: Case, limit: int) -> None:
    try:
        os.setpgid(0, 0)
        resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
        resource.setrlimit(resource.RLIMIT_CORE, (0, 0))
        os.chdir(work)
        os.umask(0o022)
        os.environ["TMPDIR"] = str(tmp)
        os.environ.update({k: str(v) for k, v in case.env.items()})
        tempfile.tempdir = str(tmp)
        null = os.open(os.devnull, os.O_RDONLY)
        os.dup2(null, 0)
        sys.stdin = open(0, "r", closefd=False)
        signal.signal(signal.SIGINT, signal.SIG_DFL)
        signal.signal(signal.SIGTERM, signal.SIG_DFL)
        _restore_warnings()
        codes = [_run_cli(case.argv, res, 0)]
        if case.check is not None:
            codes.append(_run_cli(case.check, res, 1))
        evals = {}
        if codes[0] == 0:
            for o in case.outputs:
                if o.endswith(".py") and os.path.isfile(o):
                    try:
                        evals[o] = _load_eval(o)
                    except BaseException as exc:  # noqa: BLE001
                        evals[o] = {"error": "".join(traceback.format_exception_only(
                            type(exc), exc)).strip()[:2000]}
            if case.twin:  # the same model under clean names, compiled outside the folder
                twin = str(res / "twin.py")
                if _run_cli(["compile", case.twin, "-o", twin, "-q"], res, 2) == 0:
                    evals["__twin__"] = _load_eval(twin)
        with open(res / "result.json", "w") as fh:
            json.dump({"codes": codes, "evals": evals}, fh)
    except BaseException:  # noqa: BLE001
        try:
            with open(res / "child_error.txt", "w") as fh:
                fh.write(traceback.format_exc())
        except BaseException:  # noqa: BLE001
            pass
        os._exit(99)
    os._exit(0)


# ---------------------------------------------------------------------------------------------
# the parent


@dataclass
class Outcome:
    case: Case
    ok: bool
    problems: list
    wall: float
    codes: list
    stderr: list

    def describe(self) -> str:
        err = " | ".join(s.strip().replace("\n", "\\n")[:300] for s in self.stderr)
        return (f"{self.case.id} [{self.case.category}] expect {self.case.expect}: "
                + "; ".join(self.problems) + f" (exit {self.codes}; stderr: {err})")


def _vm_size() -> int:
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith("VmSize:"):
                return int(line.split()[1]) * 1024
    return 0


def _wait(pid: int, timeout: float) -> tuple[int | None, bool]:
    """(wait status, timed out)."""
    deadline = time.monotonic() + timeout
    try:
        pfd = os.pidfd_open(pid)
    except (AttributeError, OSError):
        pfd = None
    try:
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                break
            if pfd is not None:
                import select

                select.select([pfd], [], [], min(left, 1.0))
            else:
                time.sleep(min(left, 0.005))
            wpid, status = os.waitpid(pid, os.WNOHANG)
            if wpid:
                return status, False
        for target in (-pid, pid):
            try:
                os.kill(target, signal.SIGKILL)
            except ProcessLookupError:
                pass
        _, status = os.waitpid(pid, 0)
        return status, True
    finally:
        if pfd is not None:
            os.close(pfd)


def run_case(case: Case, corpus: Path = CORPUS, timeout: float | None = None,
             keep: bool = False) -> Outcome:
    timeout = TIMEOUT if timeout is None else timeout
    refs = reference_skeletons() if case.outputs else None
    base = Path(tempfile.mkdtemp(prefix="bgcfuzz_"))
    work, tmp, res = base / "work", base / "tmp", base / "res"
    for d in (work, tmp, res):
        d.mkdir()
    try:
        try:
            _setup(work, Path(corpus), case)
        except Exception as exc:  # noqa: BLE001 - the corpus is broken, not bgc
            return Outcome(case, False, [f"setup failed: {exc!r}"], 0.0, [], ["", ""])
        before = snapshot(work)
        limit = _vm_size() + MEM_LIMIT
        sys.stdout.flush()
        sys.stderr.flush()
        t0 = time.perf_counter()
        pid = os.fork()
        if pid == 0:  # pragma: no cover - the child
            _child(work, tmp, res, case, limit)
        status, timed_out = _wait(pid, timeout)
        wall = time.perf_counter() - t0
        after = snapshot(work)
        left = snapshot(tmp)
        return _judge(case, work, res, before, after, left, status, timed_out, wall, refs)
    finally:
        if not keep:
            _rmtree(base)


def _rmtree(base: Path) -> None:
    for dirpath, dirnames, _ in os.walk(base):
        for d in dirnames:  # a case may have made a folder unreadable
            try:
                os.chmod(os.path.join(dirpath, d), 0o755)
            except OSError:
                pass
    shutil.rmtree(base, ignore_errors=True)


def _read(p: Path) -> str:
    try:
        return p.read_bytes().decode("utf-8", "backslashreplace")
    except OSError:
        return ""


def _judge(case, work, res, before, after, left, status, timed_out, wall, refs) -> Outcome:
    problems: list[str] = []
    stderr = [_read(res / f"{k}.err") for k in range(2)]
    stdout = [_read(res / f"{k}.out") for k in range(2)]
    codes: list = []
    result = None
    if timed_out:
        problems.append(f"timed out after {TIMEOUT:g} s")
    elif os.WIFSIGNALED(status):
        problems.append(f"killed by signal {os.WTERMSIG(status)}")
    elif (res / "result.json").is_file():
        result = json.loads((res / "result.json").read_text())
        codes = result["codes"]
    else:
        problems.append("the child died: " + _read(res / "child_error.txt")[-500:])
    if left:
        problems.append(f"left in TMPDIR: {sorted(left)[:5]}")
    if result is None:
        if (res / "0.err").exists():
            problems.append("stderr so far: " + stderr[0][-300:])
        return Outcome(case, False, problems, wall, codes, stderr)

    ok_p = _judge_ok(case, work, before, after, codes, stderr, stdout, result, refs)
    err_p = _judge_error(case, before, after, codes, stderr)
    if case.expect == "ok":
        problems += ok_p
    elif case.expect == "error":
        problems += err_p
    else:  # any
        if ok_p and err_p:
            branch = ok_p if codes and codes[0] == 0 else err_p
            problems += branch
    return Outcome(case, not problems, problems, wall, codes, stderr)


def _traceback(s: str) -> bool:
    return "Traceback (most recent call last)" in s


def _judge_ok(case, work, before, after, codes, stderr, stdout, result, refs) -> list[str]:
    p = []
    if codes[0] != 0:
        p.append(f"exit {codes[0]}, expected 0")
    for k, s in enumerate(stderr[:len(codes)]):
        if _traceback(s):
            p.append(f"traceback on stderr of run {k}")
        if re.search(r"\w+Warning\b", s):
            p.append(f"a warning on stderr of run {k}")
    if len(codes) > 1 and codes[1] not in (0,):
        p.append(f"the check run exits {codes[1]}")
    new = set(after) - set(before)
    dirs = [o.rstrip("/") for o in case.outputs if o.endswith("/")]
    want = {k for k in set(after) | set(before)
            if k in case.outputs or any(k == d or k.startswith(d + "/") for d in dirs)}
    changed = {k for k in before if k in after and before[k] != after[k]} | (set(before)
                                                                             - set(after))
    if CANARY not in after or after[CANARY] != before[CANARY]:
        p.append("the canary was touched")
    extra = new - want
    if extra:
        p.append(f"new files besides the outputs: {sorted(extra)[:5]}")
    if changed - want:
        p.append(f"changed or removed: {sorted(changed - want)[:5]}")
    if codes[0] != 0:
        return p
    for o in case.outputs:
        path = work / o
        if o.endswith("/"):
            if not path.is_dir() or not any(path.iterdir()):
                p.append(f"output folder {o} missing or empty")
            continue
        st = os.lstat(path) if os.path.lexists(path) else None
        if st is None or not stat.S_ISREG(st.st_mode):
            p.append(f"output {o} is not a regular file")
            continue
        if stat.S_IMODE(st.st_mode) != 0o644:
            p.append(f"output {o} has mode {oct(stat.S_IMODE(st.st_mode))}, not 0o644 "
                     "(umask 022)")
        if o.endswith(".py"):
            p += _check_module(path, result["evals"].get(o), refs)
        elif o.endswith(".npz"):
            p += _check_npz(path)
    if case.twin and not p:
        a, b = result["evals"].get(case.outputs[0]), result["evals"].get("__twin__")
        if not (a and b and "rhs" in a and "rhs" in b):
            p.append("the clean twin did not compile and evaluate")
        else:
            if a["x0"] != b["x0"] or not _close(a["rhs"], b["rhs"]):
                p.append(f"rhs/X0 differ from the clean twin {case.twin}: {a['rhs']} vs "
                         f"{b['rhs']}")
    return p


def _close(a, b) -> bool:
    if len(a) != len(b):
        return False
    for (ar, ai), (br, bi) in zip(a, b):
        if abs(ar - br) > 1e-12 * max(1.0, abs(ar), abs(br)) or ai != bi:
            return False
    return True


def _check_module(path: Path, ev, refs) -> list[str]:
    p = []
    try:
        tree = ast.parse(path.read_bytes(), filename=str(path))
    except (SyntaxError, ValueError) as exc:
        return [f"module does not parse: {exc}"]
    sk = skeleton(tree)
    if sk not in refs:
        diff = [s for s in sk if not any(s in r for r in refs)]
        p.append(f"module's top-level statements are not the template's: {diff[:3] or sk[:3]}")
    if ev is None:
        p.append("module was not evaluated")
    elif "error" in ev:
        p.append(f"module fails to load/evaluate: {ev['error'][:300]}")
    else:
        if not ev["finite"]:
            p.append(f"rhs at X0 not finite and real: {ev['rhs'][:4]}")
        if not ev["shape_ok"]:
            p.append("rhs at X0 has the wrong shape")
    return p


def _check_npz(path: Path) -> list[str]:
    import numpy as np

    try:
        with np.load(path, allow_pickle=False) as z:
            if "t" not in z.files:
                return ["results have no t"]
            for k in z.files:
                if not np.all(np.isfinite(z[k])):
                    return [f"results {k} not finite"]
    except Exception as exc:  # noqa: BLE001
        return [f"results do not load: {exc}"]
    return []


def _judge_error(case, before, after, codes, stderr) -> list[str]:
    p = []
    if codes[0] not in case.exit:
        p.append(f"exit {codes[0]}, expected {case.exit}")
    err = stderr[0]
    if _traceback(err):
        p.append("traceback on stderr")
    if after != before:
        diff = sorted(set(after) ^ set(before)) + sorted(
            k for k in before if k in after and before[k] != after[k])
        p.append(f"something was written or changed: {diff[:5]}")
    lines = err.rstrip("\n").split("\n") if err.strip() else []
    if case.usage and lines and lines[0].startswith("Usage:"):
        if not re.search(case.message or "", err, re.I):
            p.append(f"usage error lacks {case.message!r}")
        return p
    if len(lines) != 1:
        p.append(f"{len(lines)} lines on stderr, expected 1")
        return p
    line = lines[0]
    m = _LOC.match(line)
    if m:
        msg, where = m.group(4), int(m.group(2))
        if case.line is not None:
            want = case.line if isinstance(case.line, list) else [case.line]
            if where not in want:
                p.append(f"located at line {where}, expected {want}")
    elif line.startswith("error: ") and not case.located:
        msg = line[len("error: "):]
    else:
        p.append("not a located message" if case.located else "neither located nor error:")
        return p
    if len(msg) > MAX_MESSAGE:
        p.append(f"message of {len(msg)} characters (cap {MAX_MESSAGE})")
    if case.message and not re.search(case.message, msg, re.I):
        p.append(f"message lacks /{case.message}/")
    for k in range(1, len(codes)):  # the check run: exit 0, or the same kind of error
        c, e = codes[k], stderr[k]
        if _traceback(e) or c not in (0, 2):
            p.append(f"the check run exits {c}{' with a traceback' if _traceback(e) else ''}")
    return p


# ---------------------------------------------------------------------------------------------


def run_all(cases, corpus: Path = CORPUS, verbose: bool = False, out=sys.stdout):
    outcomes = []
    for c in cases:
        o = run_case(c, corpus)
        outcomes.append(o)
        if verbose:
            print(("PASS " if o.ok else "FAIL ") + f"{o.wall:6.2f}s {c.id}", file=out,
                  flush=True)
    return outcomes


def problem_kind(p: str) -> str:
    """A problem without its details (for counting)."""
    p = re.sub(r"\d+(\.\d+)?", "N", p)
    return re.split(r"[:(\[{/]", p, maxsplit=1)[0].strip()[:60]


def summary(outcomes, out=sys.stdout) -> None:
    cats: dict[str, list] = {}
    for o in outcomes:
        cats.setdefault(o.case.category, []).append(o)
    total = sum(o.wall for o in outcomes)
    print(f"{'category':<16} {'cases':>5} {'pass':>5} {'fail':>5} {'wall s':>7}", file=out)
    for cat in sorted(cats):
        os_ = cats[cat]
        n_ok = sum(o.ok for o in os_)
        print(f"{cat:<16} {len(os_):>5} {n_ok:>5} {len(os_) - n_ok:>5} "
              f"{sum(o.wall for o in os_):>7.1f}", file=out)
    n_ok = sum(o.ok for o in outcomes)
    print(f"{'total':<16} {len(outcomes):>5} {n_ok:>5} {len(outcomes) - n_ok:>5} {total:>7.1f}",
          file=out)
    walls = sorted(o.wall for o in outcomes)
    if walls:
        print(f"per case: median {walls[len(walls) // 2]:.3f} s, max {walls[-1]:.2f} s",
              file=out)
    fails = [o for o in outcomes if not o.ok]
    kinds: dict[str, int] = {}
    for o in fails:
        for k in {problem_kind(p) for p in o.problems}:
            kinds[k] = kinds.get(k, 0) + 1
    if kinds:
        print("\nproblems (cases showing each):", file=out)
        for k, n in sorted(kinds.items(), key=lambda kv: -kv[1]):
            print(f"  {n:>4}  {k}", file=out)
    if fails:
        print("\nfailing cases:", file=out)
        for o in fails:
            print("  " + o.describe(), file=out)


def main(argv=None) -> int:
    import argparse

    ap = argparse.ArgumentParser(prog="python -m tests.fuzz.harness")
    ap.add_argument("corpus", nargs="?", default=str(CORPUS))
    ap.add_argument("--summary", action="store_true", help="pass/fail per category")
    ap.add_argument("-k", default=None, help="only cases whose id contains this")
    ap.add_argument("-v", "--verbose", action="store_true")
    ap.add_argument("--json", default=None, help="write the outcomes here")
    a = ap.parse_args(argv)
    corpus = Path(a.corpus)
    cases = load_manifest(corpus)
    if a.k:
        cases = [c for c in cases if a.k in c.id]
    reference_skeletons()
    outcomes = run_all(cases, corpus, verbose=a.verbose)
    summary(outcomes)
    if a.json:
        Path(a.json).write_text(json.dumps(
            [{"id": o.case.id, "category": o.case.category, "ok": o.ok,
              "problems": o.problems, "wall": o.wall, "codes": o.codes,
              "stderr": [s[-500:] for s in o.stderr]} for o in outcomes], indent=1))
    return 0 if all(o.ok for o in outcomes) else 1


if __name__ == "__main__":
    sys.exit(main())
