"""FMU export: ``export`` packages the C printer's sources as an FMI 2.0 FMU (Model Exchange
and Co-Simulation; templates/c/fmu)."""
