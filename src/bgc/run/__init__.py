"""The run layer: compiling scenes for a backend through the cache and running them.

``driver`` (the compile driver: stages, timings), ``cache`` (what a key is made of),
``runner`` (running scenes, diagnosing failed runs), ``record`` (run records that replay a warm
run), ``fmu`` (FMU export), ``plots``, ``progress`` (the progress printer, summary lines).
"""
