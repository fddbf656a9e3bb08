"""ctypes harness for the C runtime's tests and bench: builds templates/c/runtime/*.c with the
hand-written models of tests/c_models/models.c into a shared library and mirrors the structs
of bgc_runtime.h."""

from __future__ import annotations

import ctypes as C
import os
import shutil
import subprocess
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
RUNTIME = ROOT / "templates" / "c" / "runtime"
MODELS = ROOT / "tests" / "c_models" / "models.c"
FLAGS = ["-O2", "-std=c99", "-Wall", "-Wextra", "-fPIC", "-shared"]

RHS = C.CFUNCTYPE(C.c_int, C.c_double, C.POINTER(C.c_double), C.POINTER(C.c_double),
                  C.POINTER(C.c_double))
INTP, DBLP = C.POINTER(C.c_int), C.POINTER(C.c_double)
STATUS = {0: "OK", 1: "NONFINITE", 2: "MAX_STEPS", 3: "STEP_TOO_SMALL", 4: "WALL",
          5: "SINGULAR", 6: "MODEL", 7: "ARGS"}


class Complex(C.Structure):
    """double complex by value (the x86-64 and AArch64 ABIs pass it as two doubles)."""
    _fields_ = [("re", C.c_double), ("im", C.c_double)]


class LuPlan(C.Structure):
    _fields_ = [("n", C.c_int), ("nnz_lu", C.c_int), ("nnz_jac", C.c_int),
                ("perm", INTP), ("row_ptr", INTP), ("col_idx", INTP), ("diag_pos", INTP),
                ("jac_pos", INTP), ("n_elim", C.c_int), ("elim_tgt", INTP)]


class Model(C.Structure):
    _fields_ = [("n", C.c_int), ("np", C.c_int), ("nnz", C.c_int), ("jac_row", INTP),
                ("jac_col", INTP), ("rhs", RHS), ("jac", RHS), ("has_time_inputs", C.c_int),
                ("lu", C.POINTER(LuPlan)), ("nws", C.c_int), ("rhs_ws", C.c_void_p),
                ("jac_ws", C.c_void_p), ("nev", C.c_int), ("guards", C.c_void_p),
                ("reset", C.c_void_p), ("ev_dir", INTP)]


class Options(C.Structure):
    _fields_ = [("method", C.c_int), ("rtol", C.c_double), ("atol", DBLP),
                ("atol_len", C.c_int), ("h0", C.c_double), ("max_step", C.c_double),
                ("max_steps", C.c_long), ("max_wall", C.c_double), ("t_out", DBLP),
                ("n_out", C.c_int), ("breaks", DBLP), ("n_breaks", C.c_int),
                ("ev_log", DBLP), ("ev_cap", C.c_int), ("ev_count", INTP),
                ("max_events", C.c_int), ("zeno_window", C.c_double)]


class Stats(C.Structure):
    _fields_ = [("nsteps", C.c_long), ("naccept", C.c_long), ("nreject", C.c_long),
                ("nfev", C.c_long), ("njev", C.c_long), ("nlu", C.c_long),
                ("status", C.c_int), ("t_fail", C.c_double), ("bad_index", C.c_int),
                ("bad_where", C.c_int), ("message", C.c_char * 256)]


class StatsExt(C.Structure):
    _fields_ = [("bad_entry", C.c_int), ("n_done", C.c_int), ("t_last", C.c_double),
                ("nsparse_fallback", C.c_long)]


def compiler() -> str | None:
    cc = os.environ.get("CC") or "cc"
    return shutil.which(cc.split()[0]) and cc


def build(out: Path, openmp: bool = True) -> Path:
    """Compile the runtime and the test models into out (a .so path); returns it."""
    cc = compiler()
    if cc is None:
        raise RuntimeError("no C compiler (CC or cc)")
    srcs = sorted(str(p) for p in RUNTIME.glob("*.c")) + [str(MODELS)]
    cmd = cc.split() + FLAGS + (["-fopenmp"] if openmp else []) + ["-I", str(RUNTIME), "-o",
                                                                    str(out)] + srcs + ["-lm"]
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0 or r.stderr.strip():
        raise RuntimeError(f"{' '.join(cmd)}\n{r.stderr}")
    return out


def openmp_works(cc: str, tmp: Path) -> bool:
    src = tmp / "omp_probe.c"
    src.write_text("#include <omp.h>\nint main(void){return omp_get_max_threads() < 1;}\n")
    r = subprocess.run(cc.split() + ["-fopenmp", "-o", str(tmp / "omp_probe"), str(src)],
                       capture_output=True)
    return r.returncode == 0


class Lib:
    """The loaded library with typed entry points."""

    def __init__(self, path: Path):
        self.lib = lib = C.CDLL(str(path))
        lib.bgc_integrate.argtypes = [C.POINTER(Model), DBLP, C.c_double, C.c_double, DBLP,
                                      C.POINTER(Options), DBLP, C.POINTER(Stats)]
        lib.bgc_integrate_ex.argtypes = lib.bgc_integrate.argtypes + [C.POINTER(StatsExt)]
        lib.bgc_integrate_batch.argtypes = [C.POINTER(Model), C.c_int, DBLP, DBLP, C.c_double,
                                            C.c_double, C.POINTER(Options), DBLP,
                                            C.POINTER(Stats), C.c_int]
        lib.bgc_sparse_lu.argtypes = [C.POINTER(LuPlan), DBLP]
        lib.bgc_sparse_solve.argtypes = [C.POINTER(LuPlan), DBLP, DBLP, DBLP]
        lib.bgc_sparse_lu_z.argtypes = [C.POINTER(LuPlan), C.c_void_p]
        lib.bgc_sparse_solve_z.argtypes = [C.POINTER(LuPlan), C.c_void_p, C.c_void_p, C.c_void_p]
        lib.bgc_dense_lu.argtypes = [C.c_int, DBLP, INTP]
        lib.bgc_dense_solve.argtypes = [C.c_int, DBLP, INTP, DBLP]
        lib.bgc_dense_lu_z.argtypes = [C.c_int, C.c_void_p, INTP]
        lib.bgc_dense_solve_z.argtypes = [C.c_int, C.c_void_p, INTP, C.c_void_p]
        lib.bgc_radau5_constants.argtypes = [DBLP]
        lib.bgc_linsys_solve_once.argtypes = [C.POINTER(Model), C.c_double, DBLP, DBLP,
                                              C.POINTER(C.c_long)]
        lib.bgc_linsys_solve_once_z.argtypes = [C.POINTER(Model), Complex, DBLP,
                                                C.c_void_p, C.POINTER(C.c_long)]

    def model(self, name, n, rows, cols, np_, time_inputs=False, plan=None):
        return ModelHandle(self, name, n, rows, cols, np_, time_inputs, plan)


def ptr(a, t=C.c_double):
    return a.ctypes.data_as(C.POINTER(t))


def plan_struct(plan):
    """A ctypes LuPlan over a bgc.lower.sparse_lu.LuPlan (keeps the arrays alive on the struct)."""
    arrs = [np.ascontiguousarray(getattr(plan, f), dtype=np.int32)
            for f in ("perm", "row_ptr", "col_idx", "diag_pos", "jac_pos", "elim_tgt")]
    s = LuPlan(plan.n, plan.nnz_lu, plan.jac_pos.size, *(ptr(a, C.c_int) for a in arrs[:5]),
               plan.n_elim, ptr(arrs[5], C.c_int))
    s._keep = arrs
    return s


class ModelHandle:
    def __init__(self, lib, name, n, rows, cols, np_, time_inputs, plan):
        self.lib = lib
        self.rows = np.ascontiguousarray(rows, dtype=np.int32)
        self.cols = np.ascontiguousarray(cols, dtype=np.int32)
        rhs = C.cast(getattr(lib.lib, f"{name}_rhs"), RHS)
        jac = C.cast(getattr(lib.lib, f"{name}_jac"), RHS)
        self.plan = None if plan is None else plan_struct(plan)
        self.s = Model(n, np_, len(self.rows), ptr(self.rows, C.c_int), ptr(self.cols, C.c_int),
                       rhs, jac, int(time_inputs),
                       C.pointer(self.plan) if self.plan is not None else None)
        self.n = n

    def options(self, method="Rodas4", rtol=1e-6, atol=1e-9, t_out=(), breaks=(), h0=0.0,
                max_step=0.0, max_steps=0, max_wall=0.0):
        atol = np.ascontiguousarray(np.atleast_1d(atol), dtype=float)
        t_out = np.ascontiguousarray(t_out, dtype=float)
        breaks = np.ascontiguousarray(breaks, dtype=float)
        o = Options({"Rodas4": 0, "Radau5": 1}[method], rtol, ptr(atol), atol.size, h0,
                    max_step, max_steps, max_wall, ptr(t_out), t_out.size, ptr(breaks),
                    breaks.size)
        o._keep = (atol, t_out, breaks)
        return o

    def run(self, p, t0, t1, x0, **kw):
        """(status, Y (n_out, n), stats) of one bgc_integrate call."""
        o = self.options(**kw)
        p = np.ascontiguousarray(p, dtype=float)
        x0 = np.ascontiguousarray(x0, dtype=float)
        Y = np.zeros((o.n_out, self.n))
        st, ext = Stats(), StatsExt()
        status = self.lib.lib.bgc_integrate_ex(C.byref(self.s), ptr(p), t0, t1, ptr(x0),
                                               C.byref(o), ptr(Y), C.byref(st), C.byref(ext))
        for name, _ in StatsExt._fields_:
            setattr(st, name, getattr(ext, name))
        return status, Y, st

    def run_batch(self, P, t0, t1, X0, nthreads=2, **kw):
        o = self.options(**kw)
        P = np.ascontiguousarray(P, dtype=float)
        X0 = np.ascontiguousarray(X0, dtype=float)
        nb = X0.shape[0]
        Y = np.zeros((nb, o.n_out, self.n))
        st = (Stats * nb)()
        status = self.lib.lib.bgc_integrate_batch(C.byref(self.s), nb, ptr(P), ptr(X0), t0,
                                                  t1, C.byref(o), ptr(Y), st, nthreads)
        return status, Y, list(st)


def chain_pattern(N):
    """The chain model's Jacobian pattern (rows, cols), in its jac's order; n = 2N."""
    rows, cols = [], []
    for i in range(N):
        rows.append(2 * i); cols.append(2 * i + 1)
        if i:
            rows += [2 * i + 1] * 2; cols += [2 * i - 2, 2 * i - 1]
        rows += [2 * i + 1] * 2; cols += [2 * i, 2 * i + 1]
        if i + 1 < N:
            rows += [2 * i + 1] * 2; cols += [2 * i + 2, 2 * i + 3]
    return np.array(rows), np.array(cols)


def chain_matrix(N, k_stiff, k_soft, c, m):
    """The chain's system matrix A (x' = A x), assembled independently of the C code."""
    n = 2 * N
    K = np.zeros((N, N))
    D = np.zeros((N, N))
    for i in range(N):  # spring/damper i joins mass i to mass i-1 (or the wall)
        k = k_stiff if i % 2 == 0 else k_soft
        for M, v in ((K, k), (D, c)):
            M[i, i] += v
            if i:
                M[i - 1, i - 1] += v
                M[i, i - 1] -= v
                M[i - 1, i] -= v
    A = np.zeros((n, n))
    A[0::2, 1::2] = np.eye(N)
    A[1::2, 0::2] = -K / m
    A[1::2, 1::2] = -D / m
    return A


BGC = {v: k for k, v in STATUS.items()}
