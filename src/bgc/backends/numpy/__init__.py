"""The numpy backend: ``printer`` renders the IR into a standalone numpy module
(templates/numpy)."""
