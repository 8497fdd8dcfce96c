"""The β sweep: its ``schema`` (CSV columns, file names, β parsing), the per-run ``reduce`` to a CSV row,
the ``driver`` (``endophoton.sweep``, local or on a Dask cluster), the ``sweep`` CLI (``cli``) and the
endoscope's view per β (``view_sweep``).

The attribute ``endophoton.sweep`` is the function :func:`endophoton.sweep.driver.sweep` (public API since
the first release); import this subpackage's modules by name: ``from endophoton.sweep import driver``.
"""
