"""Mutations of the valid models and scenes (issue 10): whatever hypothesis does to them, bgc
either writes a module that is the template's, loads, and evaluates rhs(X0) to finite values
without touching the canary, or prints one located line, exits 2 and writes nothing, within
the harness's time and memory limits (each example in a forked child, harness.py).

Mutations work on the YAML data (replace a scalar by a hostile string or number, delete or
duplicate an entry, change an element's type, splice hostile tokens into an expression, nest a
value deeply) and on the text (duplicate, delete or swap lines: duplicate keys, broken
indentation). Derandomised, so CI sees the same examples every run.
"""
from __future__ import annotations

import copy
import os
import sys
import tempfile
from pathlib import Path

import pytest
import yaml
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st

sys.path.insert(0, str(Path(__file__).resolve().parent))
import harness  # noqa: E402

MODELS = harness.ROOT / "models"
# small models (3r2s takes seconds to compile: its scenes are covered by the corpus' cli cases)
MODEL_NAMES = ["msd", "rlc", "dc_motor", "pendulum", "two_tanks", "van_der_pol",
               "two_mass_chain", "motor_thermal", "algebraic_loop", "point_mass_3d"]
SCENES = {"msd_step": "msd", "dc_motor_load_step": "dc_motor",
          "motor_load_motion_cold": "motor_thermal", "pendulum_swing": "pendulum"}

HOSTILE_STRINGS = [
    'x"""\nimport os; open("canary.txt", "w").write("pwned")\n"""',
    "x'''\nopen('canary.txt','w')\n'''", "\\N{BULLET}", "trailing\\", "nul\0", "\ud800",
    "a\rb", "\u2028", "{{ 1 }}", "", " ", "\n", "name\n", "__import__", "os.system",
    "e(spring)", "1e999", "nan", "inf", "-inf", "x" * 300, "k ^ 2", "signum(k)",
    "eye(1000) @ eye(1000)", "where(exp(exp(exp(100))) > 1, 1, 0)", "sqrt(-1)", "0/0",
    "9**9**9", "(" * 300 + "1" + ")" * 300, "lambda: 0", "zeros(64, 64)",
]
HOSTILE_NUMBERS = [float("inf"), float("-inf"), float("nan"), 10 ** 400, -(10 ** 400), 0,
                   -1, 1e-300, 1e300, 2 ** 63, True, None, 65, 1e-9]
TOKENS = ["**", "^", "(", ")", "[", "]", ",", ".", "__", "e(", "f(", "q(", "/0", "*1e999",
          "exp(", "sqrt(-1)", "eye(64)", "@", ";", "\n", '"""', "lambda", ":", "t", "x0",
          "np", "-", "+", "0", "1e308", "where(", "abs(", " ", "\\", "#", "'"]
TYPES = ["Se", "Sf", "C", "I", "R", "TF", "GY", "MTF", "MGY", "0", "1", "sd", "bogus", 1, None]


def _paths(node, prefix=()):
    """Every path (tuple of keys/indices) into a YAML document."""
    yield prefix
    if isinstance(node, dict):
        for k, v in node.items():
            yield from _paths(v, prefix + (k,))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            yield from _paths(v, prefix + (i,))


def _get(node, path):
    for k in path:
        node = node[k]
    return node


def _set(doc, path, value):
    if not path:
        return value
    _get(doc, path[:-1])[path[-1]] = value
    return doc


def mutate(doc, data) -> object:
    paths = [p for p in _paths(doc) if p] or [()]
    leaves = [p for p in paths if not isinstance(_get(doc, p), (dict, list))] or paths
    # uniform choices (hypothesis' own draws favour the first entries: the version number)
    rnd = data.draw(st.randoms(use_true_random=False), label="rnd")
    # mostly a leaf (a value: text, number, expression), sometimes a whole entry
    path = rnd.choice(leaves) if rnd.random() < 0.75 else rnd.choice(paths)
    kind = rnd.choice(["text", "text", "text", "string", "number", "delete", "duplicate",
                       "type", "tokens", "tokens", "nest", "container", "name", "name",
                       "rename", "rename", "retype"])
    texts = [p for p in leaves if p[-1] in ("description", "unit", "title", "name")]
    if kind == "text" and texts:  # free text: compiles when escaped, so the module is checked
        path = rnd.choice(texts)
        kind = "string"
    node = _get(doc, path)
    if kind in ("name", "rename", "retype"):
        return _mutate_names(doc, path, node, kind, rnd)
    if kind == "string":
        return _set(doc, path, rnd.choice(HOSTILE_STRINGS))
    if kind == "number":
        return _set(doc, path, rnd.choice(HOSTILE_NUMBERS))
    if kind == "delete" and path:
        parent = _get(doc, path[:-1])
        del parent[path[-1]]
        return doc
    if kind == "duplicate" and path:
        parent = _get(doc, path[:-1])
        if isinstance(parent, list):
            parent.insert(path[-1], copy.deepcopy(node))
        else:  # the same value under a second, mangled key
            parent[f"{path[-1]}_2" if isinstance(path[-1], str) else path[-1]] = copy.deepcopy(
                node)
        return doc
    if kind == "type":
        els = [p for p in paths if len(p) >= 1 and p[-1] == "type"]
        if els:
            return _set(doc, rnd.choice(els), rnd.choice(TYPES))
    if kind == "tokens" and isinstance(node, str):
        pos = rnd.randint(0, len(node))
        tok = "".join(rnd.choice(TOKENS) for _ in range(rnd.randint(1, 4)))
        return _set(doc, path, node[:pos] + tok + node[pos:])
    if kind == "nest":
        depth = rnd.randint(2, 60)
        v = node
        for _ in range(depth):
            v = [v]
        return _set(doc, path, v)
    if kind == "container":
        return _set(doc, path, rnd.choice([[], {}, [[1, 2], [3]], {"a": 1}]))
    return _set(doc, path, rnd.choice(HOSTILE_STRINGS + HOSTILE_NUMBERS))


def _names(doc) -> list[str]:
    """Every mapping key of the document: the names a model or scene defines and uses."""
    return sorted({p[-1] for p in _paths(doc) if p and isinstance(p[-1], str)})


def _mutate_names(doc, path, node, kind, rnd):
    """Names used where another kind of name is expected (a state in an input's default, an
    element as a parameter), keys renamed (to another name of the document or a fresh one),
    and values whose type changes (text <-> number <-> list <-> mapping)."""
    names = _names(doc) or ["x"]
    if kind == "name":  # a value (an expression, an endpoint) becomes another name
        return _set(doc, path, rnd.choice(names))
    if kind == "rename":
        keyed = [p for p in _paths(doc) if p and isinstance(p[-1], str)]
        if keyed:
            p = rnd.choice(keyed)
            parent = _get(doc, p[:-1])
            new = rnd.choice(names + [p[-1] + "2", p[-1].upper(), "x0", "P", "t"])
            parent[new] = parent.pop(p[-1])
        return doc
    swaps = {str: lambda v: rnd.choice([1.5, [v], {v: v}]), bool: lambda v: str(v).lower(),
             int: lambda v: rnd.choice([str(v), [v], {"value": v}]),
             float: lambda v: rnd.choice([str(v), [v, v], {"value": str(v)}]),
             list: lambda v: rnd.choice([str(v), len(v), {str(i): x for i, x in enumerate(v)}]),
             dict: lambda v: rnd.choice([list(v), list(v.values()), "x"])}
    change = swaps.get(type(node))
    return _set(doc, path, change(node)) if change else doc


def text_mutate(text: str, data) -> str:
    lines = text.split("\n")
    rnd = data.draw(st.randoms(use_true_random=False), label="rnd")
    # most examples keep the YAML intact (a broken file stops at the parser)
    op = rnd.choice(["none"] * 6 + ["dup", "del", "swap", "indent"])
    if op == "none" or len(lines) < 3:
        return text
    i, j = rnd.randrange(len(lines)), rnd.randrange(len(lines))
    if op == "dup":
        lines.insert(i, lines[i])
    elif op == "del":
        del lines[i]
    elif op == "swap":
        lines[i], lines[j] = lines[j], lines[i]
    else:
        lines[i] = " " * rnd.randint(1, 5) + lines[i]
    return "\n".join(lines)


def _dump(doc) -> str:
    try:
        return yaml.safe_dump(doc, sort_keys=False, allow_unicode=False, width=10 ** 6)
    except yaml.YAMLError:
        return yaml.safe_dump({"bgc": 1}, sort_keys=False)


def _check(files: dict, argv: list, what: str):
    with tempfile.TemporaryDirectory(prefix="bgcmut_") as d:
        names = {}
        for name, text in files.items():
            (Path(d) / name).write_text(text, encoding="utf-8", errors="surrogatepass")
            names[name] = name
        case = harness.Case(id="mutation", category="mutation", argv=argv, expect="any",
                            files=names, outputs=["out.py"],
                            check=["check", "model.yaml"] if argv[0] == "compile"
                            and "--scene" not in argv else None)
        out = harness.run_case(case, Path(d))
        if os.environ.get("BGC_FUZZ_LOG"):  # the outcomes, to see what the mutations reach
            with open(os.environ["BGC_FUZZ_LOG"], "a") as fh:
                fh.write(f"{what}\t{out.ok}\t{out.codes}\t{out.wall:.2f}\t"
                         f"{out.stderr[0].strip()[:150]!r}\n")
        assert out.ok, out.describe() + "\n--- " + what + ":\n" + "\n\n".join(
            f"{k}:\n{v[:3000]}" for k, v in files.items())


#: BGC_FUZZ_EXAMPLES scales the number of examples (e.g. 1000 for a long local run).
N_EXAMPLES = int(os.environ.get("BGC_FUZZ_EXAMPLES", "150"))
SETTINGS = dict(max_examples=N_EXAMPLES, derandomize=True, database=None, deadline=None,
                phases=[Phase.explicit, Phase.generate],
                suppress_health_check=list(HealthCheck))


@pytest.mark.slow
@settings(**SETTINGS)
@given(data=st.data(), name=st.sampled_from(MODEL_NAMES), n=st.integers(1, 3))
def test_mutated_models(data, name, n):
    doc = yaml.safe_load((MODELS / f"{name}.yaml").read_text())
    for _ in range(n):
        doc = mutate(doc, data)
    text = text_mutate(_dump(doc), data)
    _check({"model.yaml": text}, ["compile", "model.yaml", "-o", "out.py", "-q"],
           f"mutated {name}")


@pytest.mark.slow
@settings(**{**SETTINGS, "max_examples": max(1, N_EXAMPLES * 2 // 5)})
@given(data=st.data(), scene=st.sampled_from(sorted(SCENES)), n=st.integers(1, 2),
       both=st.booleans())
def test_mutated_scenes(data, scene, n, both):
    sdoc = yaml.safe_load((MODELS / "scenes" / f"{scene}.yaml").read_text())
    sdoc["model"] = "model.yaml"
    for _ in range(n):
        sdoc = mutate(sdoc, data)
    mtext = (MODELS / f"{SCENES[scene]}.yaml").read_text()
    if both:
        mtext = _dump(mutate(yaml.safe_load(mtext), data))
    _check({"scene.yaml": text_mutate(_dump(sdoc), data), "model.yaml": mtext},
           ["compile", "model.yaml", "--scene", "scene.yaml", "-o", "out.py", "-q"],
           f"mutated scene {scene}")
