"""The format layer: what a user writes, read safely and with a place for every value.

``expr`` (the whitelisting expression parser), ``reader`` (guarded YAML, typed values with
``file:line:col``, name checks), ``parse`` (model files and their imports), ``scene`` (scene
files), ``tables`` (CSV inputs). It knows text and YAML, nothing of what a bond graph means.
"""
