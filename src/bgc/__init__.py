"""bgc: a bond-graph-to-code compiler.

From Python (docs/api.md)::
    import bgc
    model = bgc.compile("models/msd.yaml")      # the loaded module, from memory
    t, x, y = model.simulate((0.0, 2.0))

``bgc.compile``, ``bgc.check``, ``bgc.equations`` and ``bgc.linearize`` are imported on first
use, so ``import bgc`` stays light; every user error is a ``bgc.BgcError`` with ``.coord``.

The package is a house with floors (docs/architecture.md). Each layer is a subpackage that
imports only from the layers below it, never from one above, and no two modules import each
other; ``tests/test_layers.py`` reads every import (inside functions too) and holds that rule
against :data:`LAYERS`, the one place the order is written:

``base``
    errors and locations, limits, paths, the bounded reader, the checked writer, the store.
    Below everything because every stage reports errors and reads or writes files.
``format``
    what a user writes: the expression parser, the model and scene readers, tables. It knows
    YAML and text, nothing of bond graphs' meaning.
``core``
    the analysis of the model: the flat bond graph, causality (SCAP), the state equations and
    their derivatives, specialisation to a scene, the graph's drawing. Backend-neutral sympy.
``lower``
    lowering to one IR (bgc.lower.ir): pruned, CSE'd, scheduled functions that every printer
    reads, and the sparse LU plans.
``backends``
    one sibling folder per target (numpy, c, fmu), each a printer of the IR plus what that
    target needs to build and load; the loader of built modules.
``run``
    the compile driver (one function compiles a scene for a backend through the cache), the
    cache keys, running scenes, run records, plots.
``studies``
    what runs many simulations: work-precision studies, parameter sweeps.
``api``
    the public Python face: ``bgc.api``, ``bgc.linear``, ``bgc.fused``, ``bgc.builder``
    (models from Python calls).
``cli``
    the ``bgc`` command.
"""
from bgc.base import __version__  # noqa: F401
from bgc.base.errors import Coord, ModelError  # (light: no third-party imports)

#: The layers, bottom first: a module may import from its own layer (without a cycle) and from
#: the layers before it. Top-level modules (bgc.api, linear, fused, builder) form the "api"
#: layer; this package's own __init__ and __main__ stand above all.
LAYERS = ("base", "format", "core", "lower", "backends", "run", "studies", "api", "cli")

BgcError = ModelError
_API = ("compile", "check", "equations", "linearize", "CompiledModel", "CheckResult",
        "StateEquations", "Linearization", "Builder", "Component")
__all__ = ["BgcError", "Coord", "ModelError", "__version__", *_API]


def __getattr__(name):
    if name in _API:
        # lazy: `import bgc` stays light (the API loads on first use)
        from bgc import api

        return getattr(api, name)
    raise AttributeError(f"module 'bgc' has no attribute {name!r}")
