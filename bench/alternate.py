"""Before/after in alternating fresh processes: the harness of the compile benchmarks that
compare this checkout's bgc with another's (bench_compile_split, bench_compile_stages,
bench_compile_front).

A script parses its options with :func:`parser`, names the checkouts with :func:`checkouts`,
and for each round and checkout runs itself again as a child (``--child``) under that
checkout's sources, with an empty compile cache of its own; the child prints one JSON
object on its last line. Alternating the checkouts round by round keeps a shared machine's
load from favouring one of them.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def parser(doc: str, repeats: int) -> argparse.ArgumentParser:
    """--model (the 3R2S by default), --repeats, --before SRC, and the hidden --child."""
    ap = argparse.ArgumentParser(description=doc.splitlines()[0])
    ap.add_argument("--model", default=str(ROOT / "models" / "3r2s.yaml"))
    ap.add_argument("--repeats", type=int, default=repeats)
    ap.add_argument("--before", default=None, help="src folder of the bgc to compare with")
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    return ap


def checkouts(before: str | None) -> dict[str, str]:
    """label -> src folder: this checkout's ("after"), and --before's where given."""
    srcs = {"after": str(ROOT / "src")}
    if before:
        srcs["before"] = before
    return srcs


def child(script: str, src: str, args: list[str]) -> dict:
    """Run ``script --child ARGS`` with bgc from ``src`` and an empty compile cache (its
    folder made with the cache's own permissions); the JSON object it printed last."""
    with tempfile.TemporaryDirectory() as d:
        cache = Path(d) / "cache"
        cache.mkdir(mode=0o700)
        env = {**os.environ, "PYTHONPATH": src, "BGC_CACHE_DIR": str(cache)}
        got = subprocess.run([sys.executable, script, "--child", *args], env=env, check=True,
                             capture_output=True, text=True, cwd=ROOT)
    return json.loads(got.stdout.strip().splitlines()[-1])


def rounds(srcs: dict[str, str], repeats: int, one) -> dict[str, list[dict]]:
    """``one(src)`` for every checkout, round after round, each round's figures printed."""
    rows: dict[str, list[dict]] = {k: [] for k in srcs}
    for r in range(repeats):
        for label, src in srcs.items():
            rows[label].append(one(src))
            print(f"round {r + 1} {label}: " + ", ".join(
                f"{k.strip()} {v:.3f}" for k, v in rows[label][-1].items()), flush=True)
    return rows
