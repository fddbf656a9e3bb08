"""bgc: a bond-graph-to-code compiler.

parse (YAML -> Model) -> graph (flat bond graph) -> causality (SCAP) -> equations (sympy)
-> emit (a standalone numpy module). From Python (docs/api.md)::

    import bgc
    model = bgc.compile("models/msd.yaml")      # the loaded module, from memory
    t, x, y = model.simulate((0.0, 2.0))

``bgc.compile``, ``bgc.check``, ``bgc.equations`` and ``bgc.linearize`` are imported on first
use, so ``import bgc`` stays light; every user error is a ``bgc.BgcError`` with ``.coord``.
"""
__version__ = "0.1.0"

from .errors import Coord, ModelError  # noqa: E402  (light: no third-party imports)

BgcError = ModelError
_API = ("compile", "check", "equations", "linearize", "CompiledModel", "CheckResult",
        "StateEquations", "Linearization")
__all__ = ["BgcError", "Coord", "ModelError", "__version__", *_API]


def __getattr__(name):
    if name == "equations":  # the submodule, callable as the API function (see its end)
        import importlib

        return importlib.import_module(__name__ + ".equations")
    if name in _API:
        from . import api

        return getattr(api, name)
    raise AttributeError(f"module 'bgc' has no attribute {name!r}")
