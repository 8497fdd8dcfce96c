"""Deprecated: ``endophoton.sweep_reduce`` moved to ``endophoton.sweep.reduce`` (kept for one release)."""
from ._moved import alias

alias(__name__, "endophoton.sweep.reduce")
