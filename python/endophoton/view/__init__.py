"""The endoscope's view: the pinhole ``camera``, spectral ``colour`` (CIE 1931 → sRGB), the ``render`` of
escape records into images, the ``visibility`` contrasts with their errors, and the ``render`` CLI
(``render_cli``).  Public names: ``endophoton.Camera``, ``endophoton.View``, ``endophoton.render_view``."""
