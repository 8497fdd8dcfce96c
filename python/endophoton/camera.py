"""Deprecated: ``endophoton.camera`` moved to ``endophoton.view.camera`` (kept for one release)."""
from ._moved import alias

alias(__name__, "endophoton.view.camera")
