"""The backends layer: one sibling folder per target, each printing the lowered IR.

``numpy`` (the standalone module), ``c`` (C sources, their build and the ctypes binding),
``fmu`` (FMI 2.0 packaging of the C sources); ``skeleton`` checks a rendered module's shape
before it is loaded, ``load`` builds and loads modules (cached or not). Templates live in
``templates/<backend>/``.
"""
