"""The base layer: what every other layer may use, and which uses nothing of bgc's.

Locations and user errors (``errors``), the bounds on untrusted input (``limits``), where bgc's
own files live (``paths``), the bounded reader (``safeio``), the checked writer (``outfiles``),
the safe on-disk store behind the compile cache and run records (``store``) and the
collector's pause around big allocations (``collector``). Nothing here
imports a third-party package at module level, so a warm run's replay can use it.
"""
__version__ = "0.1.0"

#: The backends a scene (``solver: {backend: ...}``), a command (``--backend``, ``--target``)
#: or ``bgc.compile(target=...)`` may name, written once (bgc.backends has one folder each).
BACKENDS = ("numpy", "c")
