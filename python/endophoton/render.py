"""Deprecated: ``endophoton.render`` moved to ``endophoton.view.render`` (kept for one release)."""
from ._moved import alias

alias(__name__, "endophoton.view.render")
