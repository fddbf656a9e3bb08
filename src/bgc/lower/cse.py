"""Common-subexpression elimination in time linear in the size of the expressions.

symengine's ``cse`` (and sympy's) first look for common sub-sums and sub-products among the
arguments of every pair of sums and products: the best factoring, but its cost grows about as
the square of the body (a 3-D link chain of 1,000 states spent 97 % of its compile there).
:func:`linear_cse` shares exactly the subtrees that occur more than once (value numbering by
structural equality, which sympy's cached hashes make one dictionary look-up per node): every
node is visited once to count its parents, and once to rebuild it. It finds every repeated
subtree, but not a sum ``a + b`` hidden inside two different sums ``a + b + c`` and
``a + b + d``; bgc.lower.ir uses it for bodies beyond :data:`LINEAR_ABOVE` nodes, where the
pairwise search stops paying (measured: bench/profile_compile.py, bench/RESULTS_compile_scale.md),
and for *binary* bodies (every sum and product of at most two operands besides a numeric
coefficient: a linear network such as an RC ladder) beyond :data:`BINARY_ABOVE` nodes. There
the pairwise search found nothing more in a 1,000-node ladder's rhs (11,000 nodes; 6,000
operations either way) and cost 1.2-1.7 s against 0.2 s for the linear pass (one process, a
load of 4-5); its Jacobian has 5,998 operations instead of 4,999 (the pairwise search shares
``d/R`` inside ``-d/R``), evaluated once per Jacobian.

``stats`` counts the nodes each call visited (tests/test_compile_scale.py holds the work
linear in the model's size through it).
"""
from __future__ import annotations

import sympy as sp

#: bodies (counted in distinct expression nodes) above which the linear pass replaces the
#: pairwise one; the goldens and the 3R2S lie below it
LINEAR_ABOVE = 15_000

#: binary bodies (:func:`survey`) above this many nodes take the linear pass too; the goldens'
#: bodies above it hold sums or products of three and more operands
BINARY_ABOVE = 2_000

#: work counters: "nodes" visited by linear_cse and size_of since the last reset
stats = {"nodes": 0}


def size_of(exprs, limit: int | None = None) -> int:
    """The number of distinct nodes of ``exprs`` (stops counting past ``limit``)."""
    seen: set = set()
    stack = list(exprs)
    while stack:
        e = stack.pop()
        if e in seen:
            continue
        seen.add(e)
        if limit is not None and len(seen) > limit:
            break
        stack.extend(e.args)
    stats["nodes"] += len(seen)
    return len(seen)


def survey(exprs, limit: int) -> tuple[int, bool]:
    """(the number of distinct nodes of ``exprs``, counting stopped past ``limit``; whether
    the body is *binary*: every sum and product in it has at most two operands besides a
    numeric coefficient)."""
    seen: set = set()
    stack = list(exprs)
    plain = True
    while stack:
        e = stack.pop()
        if e in seen:
            continue
        seen.add(e)
        if len(seen) > limit:
            break
        if plain and (e.is_Add or e.is_Mul):
            plain = sum(1 for a in e.args if not a.is_Number) <= 2
        stack.extend(e.args)
    stats["nodes"] += len(seen)
    return len(seen), plain


def linear_wanted(exprs) -> bool:
    """Whether a body takes :func:`linear_cse` rather than the pairwise search: beyond
    :data:`LINEAR_ABOVE` nodes, or binary (:func:`survey`) beyond :data:`BINARY_ABOVE`. In a
    binary body no sum or product has a sub-sum or sub-product of two operands other than
    itself: what the pairwise search would find beyond repeated subtrees is only a shared
    operand pair under a numeric coefficient."""
    n, plain = survey(exprs, LINEAR_ABOVE)
    return n > LINEAR_ABOVE or (plain and n > BINARY_ABOVE)


def _worth(e) -> bool:
    """A repeated node worth a temporary: an expression that is not an atom nor -atom."""
    if e.is_Atom or not isinstance(e, sp.Expr):
        return False
    if e.is_Mul and len(e.args) == 2 and e.args[0] is sp.S.NegativeOne and e.args[1].is_Atom:
        return False
    return True


def _parents(exprs) -> dict:
    """How many times each distinct node is an argument of a distinct node (or a result);
    atoms (never worth a temporary: :func:`_worth`) are not counted, nor hashed."""
    count: dict = {}
    stack = [e for e in exprs if not e.is_Atom]
    while stack:
        e = stack.pop()
        if e in count:
            count[e] += 1
            continue
        count[e] = 1
        stack.extend(a for a in e.args if not a.is_Atom)
    stats["nodes"] += len(count)
    return count


def _rebuilt(e, args):
    """``e`` with new arguments, without re-canonicalising sums and products (replacing a
    subtree by a symbol changes nothing of their meaning)."""
    if e.is_Add or e.is_Mul:
        return e.func._from_args(args)
    if e.is_Pow:
        return sp.Pow(*args, evaluate=False)
    return e.func(*args)


def linear_cse(exprs: list, make_symbol) -> tuple[list, list]:
    """(replacements [(symbol, expr)] in dependency order, reduced exprs), like sympy's
    ``cse``: every non-trivial subtree met more than once is computed once, as a temporary
    named by ``make_symbol()``."""
    count = _parents(exprs)
    memo: dict = {}
    repl: list = []
    for root in exprs:
        if root.is_Atom:  # (atoms stand for themselves: never looked up)
            continue
        stack = [(root, False)]
        while stack:  # post-order without recursion (trees may be deep)
            e, ready = stack.pop()
            if e in memo:
                continue
            args = e.args
            if not ready:
                stack.append((e, True))
                stack.extend((a, False) for a in reversed(args)
                             if not a.is_Atom and a not in memo)
                continue
            new_args = tuple(a if a.is_Atom else memo[a] for a in args)
            out = e if all(n is a for n, a in zip(new_args, args)) else _rebuilt(e, new_args)
            if count[e] > 1 and _worth(e):
                s = make_symbol()
                repl.append((s, out))
                out = s
            memo[e] = out
    stats["nodes"] += len(memo)
    return repl, [r if r.is_Atom else memo[r] for r in exprs]
