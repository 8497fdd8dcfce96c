"""Deprecated: ``endophoton.view_sweep`` moved to ``endophoton.sweep.view_sweep`` (kept for one release)."""
from ._moved import alias

alias(__name__, "endophoton.sweep.view_sweep")
