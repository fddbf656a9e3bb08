"""The lowering layer: the state equations as one IR every printer reads (``ir``: pruned,
CSE'd, scheduled functions) and the sparse LU plans (``sparse_lu``)."""
