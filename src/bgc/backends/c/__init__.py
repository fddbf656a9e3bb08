"""The C backend: ``printer`` renders the IR as C (templates/c), ``build`` runs the system C
compiler and keeps its objects in the cache."""
