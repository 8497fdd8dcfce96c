"""Deprecated: ``endophoton.visibility`` moved to ``endophoton.view.visibility`` (kept for one release)."""
from ._moved import alias

alias(__name__, "endophoton.view.visibility")
