"""Deprecated: ``endophoton.sweep_cli`` moved to ``endophoton.sweep.cli`` (kept for one release)."""
from ._moved import alias

alias(__name__, "endophoton.sweep.cli")
