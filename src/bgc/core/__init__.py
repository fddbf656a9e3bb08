"""The core layer: what a model means, independent of any backend.

``graph`` (the flat bond graph, networkx), ``causality`` (SCAP), ``equations`` (the state
equations in sympy, their Jacobians and linear parts), ``fastsym`` (symengine for
differentiation and CSE), ``specialize`` (a scene's effects, folded parameters and outputs),
``draw`` (the bond graph with its causal strokes).
"""
