"""A sparse LU plan for the C runtime, made once at code-generation time.

The C integrators factorise iteration matrices ``c*I - J`` (``c`` real for Rodas4 and for
Radau's first system, complex for Radau's second) whose sparsity pattern is the model's
Jacobian pattern plus the diagonal, fixed when the model is compiled. As KPP does for the
chemistry solvers it generates, this module orders the matrix once with a fill-reducing
ordering (minimum degree on the symmetrised pattern), computes the fill-in and the whole
elimination schedule, and prints them as C array initialisers (:func:`plan_c`). The runtime
then factorises without pivoting along the plan; a pivot that is too small relative to its
row sends that one factorisation to the dense LU with partial pivoting (for small ``h``,
``c*I - J`` is diagonally dominant and the plan's pivots are safe).

Cost: the ordering and the symbolic factorisation take time proportional to the number of
entries of L+U and of elimination operations, which for the models bgc compiles (chains,
mechanisms with a few dense blocks) is near-linear in the pattern size.
"""

from __future__ import annotations

import heapq
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class LuPlan:
    """The plan's arrays (see ``struct bgc_lu_plan`` in templates/c/runtime/bgc_runtime.h)."""

    n: int
    perm: np.ndarray       # permuted index -> original index
    row_ptr: np.ndarray    # CSR of L+U in permuted order, fill included
    col_idx: np.ndarray
    diag_pos: np.ndarray
    jac_pos: np.ndarray    # position of each Jacobian nonzero (given order) in L+U
    elim_tgt: np.ndarray   # elimination schedule (targets of the row updates)

    @property
    def nnz_lu(self) -> int:
        return int(self.col_idx.size)

    @property
    def n_elim(self) -> int:
        return int(self.elim_tgt.size)


def minimum_degree(n: int, adj: list[set[int]]) -> tuple[list[int], list[set[int]]]:
    """Order the nodes of a symmetric graph (adjacency sets, no self loops; consumed) by
    minimum degree on the elimination graph, ties to the lowest index. Returns the order and,
    for each node, its neighbours at its elimination (the later nodes it couples to: the
    nonzeros of its U row and L column, fill included)."""
    heap = [(len(adj[v]), v) for v in range(n)]
    heapq.heapify(heap)
    done = [False] * n
    order: list[int] = []
    reach: list[set[int]] = [set() for _ in range(n)]
    while heap:
        d, v = heapq.heappop(heap)
        if done[v] or d != len(adj[v]):
            continue  # stale entry: the degree changed since it was pushed
        done[v] = True
        order.append(v)
        nbrs = adj[v]
        reach[v] = nbrs
        for u in nbrs:
            au = adj[u]
            au.discard(v)
            au.update(nbrs)
            au.discard(u)
            heapq.heappush(heap, (len(au), u))
        adj[v] = set()
    return order, reach


def make_plan(n: int, rows, cols) -> LuPlan:
    """The plan for c*I - J with J's nonzeros at (rows[e], cols[e]) (the model's order)."""
    rows = np.asarray(rows, dtype=np.int64).ravel()
    cols = np.asarray(cols, dtype=np.int64).ravel()
    if rows.shape != cols.shape:
        raise ValueError("rows and cols differ in length")
    if rows.size and (rows.min() < 0 or cols.min() < 0 or rows.max() >= n or cols.max() >= n):
        raise ValueError(f"pattern index outside 0..{n - 1}")
    adj: list[set[int]] = [set() for _ in range(n)]
    for r, c in zip(rows.tolist(), cols.tolist()):
        if r != c:
            adj[r].add(c)
            adj[c].add(r)
    order, reach = minimum_degree(n, adj)
    pos = [0] * n
    for k, v in enumerate(order):
        pos[v] = k
    upper = [sorted(pos[u] for u in reach[v]) for v in order]  # U row k: columns > k
    lower: list[list[int]] = [[] for _ in range(n)]             # L row i: columns < i
    for k in range(n):
        for j in upper[k]:
            lower[j].append(k)  # k ascends, so each L row comes out sorted
    row_ptr = [0] * (n + 1)
    col_idx: list[int] = []
    diag_pos = [0] * n
    where: list[dict[int, int]] = []
    for i in range(n):
        start = len(col_idx)
        diag_pos[i] = start + len(lower[i])
        cols_i = lower[i] + [i] + upper[i]
        col_idx.extend(cols_i)
        where.append({j: start + q for q, j in enumerate(cols_i)})
        row_ptr[i + 1] = len(col_idx)
    elim: list[int] = []
    for i in range(n):
        wi = where[i]
        for k in lower[i]:
            elim.extend(wi[j] for j in upper[k])
    jac_pos = [where[pos[r]][pos[c]] for r, c in zip(rows.tolist(), cols.tolist())]
    i32 = np.int32
    return LuPlan(n=n, perm=np.array(order, dtype=i32), row_ptr=np.array(row_ptr, dtype=i32),
                  col_idx=np.array(col_idx, dtype=i32), diag_pos=np.array(diag_pos, dtype=i32),
                  jac_pos=np.array(jac_pos, dtype=i32), elim_tgt=np.array(elim, dtype=i32))


def _c_array(name: str, values: np.ndarray, per_line: int = 16) -> str:
    vals = [str(int(v)) for v in values] or ["0"]  # C99 has no empty initialiser
    lines = [", ".join(vals[k:k + per_line]) for k in range(0, len(vals), per_line)]
    return (f"static const int {name}[{len(vals)}] = {{\n    " + ",\n    ".join(lines)
            + "\n};\n")


def plan_c(plan: LuPlan, name: str = "bgc_lu_plan_model") -> str:
    """The plan as C: the arrays and ``static const struct bgc_lu_plan NAME``. NAME must be a
    C identifier (the caller's, never a model's string)."""
    if not name.isidentifier() or not name.isascii():
        raise ValueError(f"not a C identifier: {name!r}")
    parts = [f"/* sparse LU plan: n = {plan.n}, {plan.nnz_lu} entries of L+U (fill included), "
             f"{plan.n_elim} elimination updates; made by bgc.lower.sparse_lu */\n"]
    fields = ("perm", "row_ptr", "col_idx", "diag_pos", "jac_pos", "elim_tgt")
    for f in fields:
        parts.append(_c_array(f"{name}_{f}", getattr(plan, f)))
    parts.append(
        f"static const struct bgc_lu_plan {name} = {{\n"
        f"    {plan.n}, {plan.nnz_lu}, {plan.jac_pos.size},\n"
        f"    {name}_perm, {name}_row_ptr, {name}_col_idx, {name}_diag_pos, {name}_jac_pos,\n"
        f"    {plan.n_elim}, {name}_elim_tgt\n}};\n")
    return "".join(parts)


def flops(plan: LuPlan) -> int:
    """Multiply-adds of one factorisation along the plan (for choosing sparse or dense)."""
    return plan.n_elim + int(plan.diag_pos.size and (plan.diag_pos - plan.row_ptr[:-1]).sum())


def prefer_sparse(plan: LuPlan) -> bool:
    """Whether the integrators should factorise along the plan rather than densely.

    Measured by bench/bench_c_runtime.py (gcc -O2): along the plan an update costs about
    three times a dense one (indirect addressing), and below about 30 states the dense LU's
    simple loops win anyway; the 3R2S (n = 101, 1914 nonzeros: 34k updates against 343k
    dense) factorises 3.5 times faster along its plan, a chain of 200 states 13 times."""
    n = plan.n
    return n >= 32 and 3 * flops(plan) < n ** 3 / 3
