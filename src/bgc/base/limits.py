"""Every bound bgc puts on untrusted input, in one place.

Model and scene files are untrusted: each limit below keeps one kind of work (reading, parsing,
flattening, symbolic evaluation, the output grid, the integrator) bounded, and every check that
enforces one raises a located :class:`~bgc.base.errors.ModelError` naming the limit. The numbers are
far above what real models need (the largest example in ``models/`` is well inside each) and
are documented in ``docs/model-format.md`` ("Limits").
"""
from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Limits:
    # -- files ----------------------------------------------------------------------------
    #: Largest model or imported file, in bytes.
    model_bytes: int = 2_000_000
    #: Largest scene file, in bytes.
    scene_bytes: int = 1_000_000
    #: Most distinct files one model may import (directly and through other imports).
    import_files: int = 256
    #: Deepest nesting of YAML collections.
    yaml_depth: int = 32
    # -- the flattened model --------------------------------------------------------------
    #: Most component instances in one body (one level of the hierarchy).
    instances_per_level: int = 1000
    #: Most flat elements after every component is expanded.
    flat_elements: int = 20_000
    #: Deepest component nesting.
    component_depth: int = 8
    #: Largest bond cardinality and vector/matrix dimension in a shape.
    cardinality: int = 64
    #: Most bonds on one junction: its balance is one sum, one line of the generated module,
    #: which Python's own parser refuses beyond about 2 500 terms.
    junction_bonds: int = 1000
    # -- expressions ----------------------------------------------------------------------
    #: Longest expression text, in characters.
    expr_chars: int = 20_000
    #: Most syntax-tree nodes in one expression.
    expr_nodes: int = 5_000
    #: Deepest nesting of an expression tree.
    expr_depth: int = 200
    #: Largest number of entries in a matrix an expression builds (eye(n), products, lists).
    matrix_entries: int = 4096
    #: Largest matrix dimension (rows or columns) an expression may build.
    matrix_dim: int = 64
    #: Largest magnitude of a number: 10**number_exponent (a double reaches 1.8e308).
    number_exponent: int = 300
    #: Largest magnitude of an exponent in ``a ** b`` when both are numbers.
    power_exponent: int = 1000
    #: Decimal digits used when a constant expression is evaluated numerically.
    eval_digits: int = 30
    #: Largest number of sympy operations in one built expression (after substitution).
    built_ops: int = 20_000
    #: Longest unit string, its deepest parentheses, its largest exponent (bgc.format.units).
    unit_chars: int = 100
    unit_depth: int = 4
    unit_exponent: int = 12
    # -- scenes and runs ------------------------------------------------------------------
    #: Largest magnitude of a time (start, end, breakpoint) in seconds.
    time_magnitude: float = 1e15
    #: Most output samples a scene's dt may ask for.
    output_samples: int = 1_000_000
    #: Most breakpoints in a scene.
    breakpoints: int = 10_000
    #: Smallest relative tolerance.
    min_rtol: float = 1e-14
    #: Smallest max_step, relative to the length of the time span.
    min_step_fraction: float = 1e-12
    # -- messages -------------------------------------------------------------------------
    #: Longest error message, in characters (user text inside is cut to fit).
    message_chars: int = 500


LIMITS = Limits()
