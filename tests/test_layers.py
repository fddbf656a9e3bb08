"""The package's shape (docs/architecture.md): layers with one-way imports, measured from the
source itself, imports inside functions included.

The order is bgc.LAYERS; a module may import from its own layer and from those below it, and
no group of modules may import each other round in a cycle. Sizes: no module over 600 lines
and no function over 100 lines in src/.
"""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

import bgc

SRC = Path(__file__).resolve().parent.parent / "src"
TOP_API = {"bgc.api", "bgc.linear", "bgc.fused", "bgc.builder"}  # the api layer: top-level


def modules() -> dict[str, Path]:
    out = {}
    for p in sorted((SRC / "bgc").rglob("*.py")):
        name = ".".join(p.relative_to(SRC).with_suffix("").parts)
        out[name.removesuffix(".__init__")] = p
    return out


def layer(mod: str) -> int:
    """The module's floor: its index in bgc.LAYERS; the package root stands above all."""
    if mod in ("bgc", "bgc.__main__"):
        return len(bgc.LAYERS)
    if mod in TOP_API:
        return bgc.LAYERS.index("api")
    return bgc.LAYERS.index(mod.split(".")[1])


def imports(mod: str, path: Path, mods: dict) -> set[str]:
    """Every bgc module ``mod`` imports, at any depth of its code."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    pkg = mod if path.name == "__init__.py" else mod.rsplit(".", 1)[0]
    out = set()
    for node in ast.walk(tree):
        names = []
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = pkg.split(".")[: len(pkg.split(".")) - node.level + 1]
                b = ".".join(base + ([node.module] if node.module else []))
            else:
                b = node.module or ""
            names = [f"{b}.{a.name}" for a in node.names] + [b]
        for n in names:
            while n and n not in mods:
                n = n.rpartition(".")[0]
            if n and n != mod and not (n == "bgc" and names[-1] != "bgc"):
                out.add(n)
    # a submodule's own package: importing `bgc.x.y` runs bgc.x's __init__, which is below
    return {n for n in out if not mod.startswith(n + ".")}


def graph() -> dict[str, set[str]]:
    mods = modules()
    return {m: imports(m, p, mods) for m, p in mods.items()}


def test_every_module_has_a_layer():
    for m in modules():
        if m not in ("bgc", "bgc.__main__") and m not in TOP_API:
            assert m.split(".")[1] in bgc.LAYERS, f"{m} is in no layer of bgc.LAYERS"


def test_no_import_climbs_a_layer():
    bad = [f"{m} ({bgc.LAYERS[layer(m)] if layer(m) < len(bgc.LAYERS) else 'root'}) imports "
           f"{t} ({bgc.LAYERS[layer(t)] if layer(t) < len(bgc.LAYERS) else 'root'})"
           for m, ts in graph().items() for t in sorted(ts) if layer(t) > layer(m)]
    assert not bad, "imports that climb a layer:\n" + "\n".join(bad)


def strongly_connected(g: dict[str, set[str]]) -> list[list[str]]:
    """Tarjan's algorithm, iterative."""
    index, low, on, stack, out, n = {}, {}, set(), [], [], 0
    for root in g:
        if root in index:
            continue
        work = [(root, iter(sorted(g[root])))]
        index[root] = low[root] = n; n += 1; stack.append(root); on.add(root)
        while work:
            v, it = work[-1]
            w = next(it, None)
            if w is not None:
                if w not in index:
                    index[w] = low[w] = n; n += 1; stack.append(w); on.add(w)
                    work.append((w, iter(sorted(g[w]))))
                elif w in on:
                    low[v] = min(low[v], index[w])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[v])
            if low[v] == index[v]:
                comp = []
                while True:
                    w = stack.pop(); on.discard(w); comp.append(w)
                    if w == v:
                        break
                out.append(sorted(comp))
    return out


def test_no_import_cycle():
    cycles = [c for c in strongly_connected(graph()) if len(c) > 1]
    assert not cycles, "import cycles: " + "; ".join(", ".join(c) for c in cycles)


def test_the_cycle_finder_finds_cycles():
    assert strongly_connected({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == \
        [["a", "b", "c"], ["d"]]


@pytest.mark.parametrize("path", sorted((SRC / "bgc").rglob("*.py")), ids=lambda p: p.name)
def test_sizes(path):
    text = path.read_text(encoding="utf-8")
    assert text.count("\n") <= 600, f"{path}: {text.count(chr(10))} lines (at most 600)"
    for node in ast.walk(ast.parse(text)):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            n = node.end_lineno - node.lineno + 1
            assert n <= 100, f"{path}:{node.lineno}: {node.name} is {n} lines (at most 100)"


def test_every_deferred_import_of_bgc_says_why():
    """An import of a bgc module inside a function stays there only where it keeps a warm run
    or `import bgc` light, and says so: a comment on its line, or on the line above it (one
    for a group of imports)."""
    bare = []
    for path in sorted((SRC / "bgc").rglob("*.py")):
        lines = path.read_text(encoding="utf-8").splitlines()
        tree = ast.parse("\n".join(lines))
        for fn in ast.walk(tree):
            if not isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)):
                continue
            for node in ast.walk(fn):
                if not isinstance(node, (ast.Import, ast.ImportFrom)):
                    continue
                names = [a.name for a in node.names] if isinstance(node, ast.Import) \
                    else [node.module or ""]
                if not any(n == "bgc" or n.startswith("bgc.") for n in names):
                    continue
                i = node.lineno - 1
                while i > 0 and lines[i - 1].strip().startswith(("from ", "import ")):
                    i -= 1  # the top of a group of imports
                said = "#" in lines[node.lineno - 1] or (i > 0 and "#" in lines[i - 1])
                if not said:
                    bare.append(f"{path.relative_to(SRC)}:{node.lineno}")
    assert not bare, "deferred bgc imports without a reason: " + ", ".join(bare)
