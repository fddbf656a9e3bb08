"""Fused rhs and Jacobian: a generated module's functions compiled by ``jax.jit`` into one
XLA computation each (optional; needs JAX).

The generated ``rhs``/``jacobian`` take their array namespace from x and write their results
entry by entry (``_dx[k, ...] = ...``), which JAX's immutable arrays refuse. :func:`jax_functions`
rewrites the two functions' syntax trees (nothing else in them changes): the entries are
stacked into one array instead (the Jacobian's nonzeros scattered into place with ``.at[]``),
and the rest of each body, the equations in causal order, runs unchanged on ``jax.numpy``
through array-api-compat. Under ``jax.jit`` the whole body becomes one fused computation:
on a GPU, a handful of kernels per call instead of one launch per operation.

    from bgc.fused import jax_functions
    rhs, jac = jax_functions(mod, p={"m2": masses})   # parameters fixed per compiled pair
    dx = rhs(t, x)             # x: (n, *batch), numpy or JAX array; returns a JAX array

JAX computes in float32 unless 64-bit mode is on: this module turns it on when imported
(``jax_enable_x64``), as the solvers need float64.
"""
from __future__ import annotations

import ast
import inspect


def _jax():
    import jax

    jax.config.update("jax_enable_x64", True)
    return jax


class _Rewrite(ast.NodeTransformer):
    """rhs: `_dx = xp.empty(..)` + `_dx[k, ...] = e` -> `return xp.stack([...])`;
    jacobian: `_J = xp.zeros(..)` + `_J[i, j, ...] = e` -> a scatter of the stacked entries."""

    def __init__(self, target: str, n: int):
        self.target, self.n = target, n

    def visit_FunctionDef(self, node):
        body, entries = [], []
        for st in node.body:
            if (isinstance(st, ast.Assign) and isinstance(st.targets[0], ast.Name)
                    and st.targets[0].id == self.target):
                continue  # the allocation
            if (isinstance(st, ast.Assign) and isinstance(st.targets[0], ast.Subscript)
                    and isinstance(st.targets[0].value, ast.Name)
                    and st.targets[0].value.id == self.target):
                idx = st.targets[0].slice
                ks = tuple(e.value for e in idx.elts if isinstance(e, ast.Constant)
                           and isinstance(e.value, int))
                entries.append((ks, st.value))
                continue
            if isinstance(st, ast.Return):
                continue
            body.append(st)
        shape = ast.parse("_shape = np.broadcast_shapes(x.shape[1:], _bshape)").body[0]
        bf = ast.parse("_bf = lambda v: xp.broadcast_to(xp.asarray(v, dtype=xp.float64), "
                       "_shape)").body[0]
        stack = ast.Call(ast.Attribute(ast.Name("xp", ast.Load()), "stack", ast.Load()),
                         [ast.List([ast.Call(ast.Name("_bf", ast.Load()), [e], [])
                                    for _, e in entries], ast.Load())], [])
        body += [shape, bf]
        if self.target == "_dx":
            order = [k[0] for k, _ in entries]
            if order != list(range(self.n)):
                raise AssertionError("rhs does not assign every derivative in order")
            body.append(ast.Return(stack))
        else:
            flat = [i * self.n + j for (i, j), _ in entries]
            body.append(ast.Assign([ast.Name("_vals", ast.Store())], stack))
            body += ast.parse(
                f"_J = xp.zeros(({self.n * self.n},) + _shape, dtype=xp.float64)\n"
                f"_J = _J.at[np.array({flat!r}, dtype=np.intp)].set(_vals)\n"
                f"return xp.reshape(_J, ({self.n}, {self.n}) + _shape)").body
        node.body = body
        return node


def _source(mod) -> str:
    src = getattr(mod, "__loader__", None)
    if src is not None and hasattr(src, "get_source"):
        try:
            text = src.get_source(mod.__name__)
            if text:
                return text
        except Exception:  # noqa: BLE001 - fall back to inspect
            pass
    return inspect.getsource(mod)


def jax_functions(mod, p=None, jit=True):
    """(rhs(t, x), jacobian(t, x)) of the generated module `mod` on JAX arrays, with the
    parameters p (a dict, arrays over the batch allowed) fixed, each jax.jit-compiled."""
    jax = _jax()
    import jax.numpy as jnp

    tree = ast.parse(_source(mod))
    fns = {}
    for fn, target in (("rhs", "_dx"), ("jacobian", "_J")):
        node = next(n for n in tree.body if isinstance(n, ast.FunctionDef) and n.name == fn)
        node = _Rewrite(target, mod.N_STATES).visit(ast.parse(ast.unparse(node)).body[0])
        node.name = f"_fused_{fn}"
        code = compile(ast.fix_missing_locations(ast.Module([node], [])),
                       f"<bgc fused {fn}>", "exec")
        env = dict(vars(mod))
        exec(code, env)  # noqa: S102 - the generated module's own function, rewritten
        fns[fn] = env[f"_fused_{fn}"]
    unpacked = mod._params(p)  # parameters unpacked once, as numpy; JAX constants when traced

    def rhs(t, x):
        return fns["rhs"](t, jnp.asarray(x, dtype=jnp.float64), unpacked)

    def jacobian(t, x):
        return fns["jacobian"](t, jnp.asarray(x, dtype=jnp.float64), unpacked)

    if jit:
        return jax.jit(rhs), jax.jit(jacobian)
    return rhs, jacobian


def available() -> bool:
    """Is JAX importable here?"""
    import importlib.util

    return importlib.util.find_spec("jax") is not None


__all__ = ["jax_functions", "available"]
