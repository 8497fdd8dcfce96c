"""Deprecated: ``endophoton.beta_sweep`` moved to ``endophoton.sweep.driver`` (kept for one release)."""
from ._moved import alias

alias(__name__, "endophoton.sweep.driver")
