"""Deprecated: ``endophoton.sweep_schema`` moved to ``endophoton.sweep.schema`` (kept for one release)."""
from ._moved import alias

alias(__name__, "endophoton.sweep.schema")
