"""The bond graph as Graphviz DOT, with causal strokes and multibond widths."""
from __future__ import annotations

import shutil
import subprocess

from bgc.base.errors import ModelError
from bgc.core.causality import Causality
from bgc.core.graph import BondGraph

_SHAPES = {"0": "circle", "1": "circle"}


def to_dot(bg: BondGraph, caus: Causality | None) -> str:
    """DOT text. A bond is a half arrow in the power direction; the causal stroke (a bar) sits
    at the end that receives the effort. Multibonds are drawn thick and labelled with n."""
    lines = [f'digraph "{bg.model.name}" {{', "  graph [rankdir=LR, fontname=Helvetica];",
             '  node [fontname=Helvetica, shape=plaintext];',
             '  edge [fontname=Helvetica, fontsize=9];']
    clusters: dict[tuple, list] = {}
    for el in bg.elements:
        clusters.setdefault(el.scope, []).append(el)
    for scope, els in clusters.items():
        indent = "  "
        if scope:
            lines.append(f'  subgraph "cluster_{".".join(scope)}" {{')
            lines.append(f'    label="{".".join(scope)}"; style=rounded; color=gray60;')
            indent = "    "
        for el in els:
            short = el.id.split(".")[-1]
            label = el.type if el.type in ("0", "1") else f"{el.type}:{short}"
            shape = _SHAPES.get(el.type, "plaintext")
            extra = ', width=0.3, fixedsize=true' if shape == "circle" else ""
            lines.append(f'{indent}"{el.id}" [label="{label}", shape={shape}{extra}];')
        if scope:
            lines.append("  }")
    for b in bg.bonds:
        attrs = [f'label="{b.id.split(".")[-1]}' + (f' [{b.n}]"' if b.n > 1 else '"')]
        if b.n > 1:
            attrs.append("penwidth=2.5")
        stroke_at_head = caus is not None and caus.effort_by[b.id] == b.src
        stroke_at_tail = caus is not None and not stroke_at_head
        attrs.append('arrowhead="teelnormal"' if stroke_at_head else 'arrowhead="lnormal"')
        if stroke_at_tail:
            attrs.append('dir=both, arrowtail="tee"')
        lines.append(f'  "{b.src}" -> "{b.dst}" [{", ".join(attrs)}];')
    lines.append("}")
    return "\n".join(lines) + "\n"


def render_image(dot: str, fmt: str) -> bytes:
    exe = shutil.which("dot")
    if exe is None:
        raise ModelError(None, f"writing .{fmt} needs Graphviz's 'dot' program (install the "
                               "graphviz package), or write .dot")
    try:
        proc = subprocess.run([exe, f"-T{fmt}"], input=dot.encode(), capture_output=True,
                              timeout=120)
    except subprocess.TimeoutExpired:
        raise ModelError(None, "graphviz did not finish within 120 s; write .dot") from None
    except OSError as exc:
        raise ModelError(None, f"graphviz could not be started: {exc.strerror or exc}") from None
    if proc.returncode != 0:
        err = " ".join(proc.stderr.decode(errors="replace").split())[:300]
        raise ModelError(None, f"graphviz failed: {err}")
    return proc.stdout
