"""bgc: a bond-graph-to-code compiler.

parse (YAML -> Model) -> graph (flat bond graph) -> causality (SCAP) -> equations (sympy)
-> emit (a standalone numpy module). :func:`bgc.compiler.compile_file` runs them in order.
"""
__version__ = "0.1.0"
