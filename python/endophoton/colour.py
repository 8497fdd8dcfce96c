"""Deprecated: ``endophoton.colour`` moved to ``endophoton.view.colour`` (kept for one release)."""
from ._moved import alias

alias(__name__, "endophoton.view.colour")
