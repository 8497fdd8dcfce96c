"""Deprecated: ``endophoton.render_cli`` moved to ``endophoton.view.render_cli`` (kept for one release)."""
from ._moved import alias

alias(__name__, "endophoton.view.render_cli")
