# SPDX-License-Identifier: MIT
"""ID property names that tie a run's datablocks together (shared by the result modules).

Everything a run creates is tagged with the run id (``RUN_KEY``) so deleting the run removes
exactly that; its collection carries ``RESULT_KEY``, ``SUMMARY_KEY`` and ``PARAMS_KEY``.
"""

RESULT_KEY = "endophoton_result"  # on the run's collection


RUN_KEY = "endophoton_run"  # on every datablock the run created


SUMMARY_KEY = "endophoton_summary"  # on the run's collection


PARAMS_KEY = "endophoton_params"  # on the run's collection: what the run was asked to do


SWEEP_KEY = "endophoton_sweep"  # on a sweep's parent collection (its sweep id): holds its β collections
SWEEP_PLOT_KEY = "endophoton_sweep_plot"  # on every image a sweep loaded (its plots)
