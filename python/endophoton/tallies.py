"""What a run reports and what a target-accuracy run can aim at.

Leaf of the import graph: :mod:`endophoton.run` and :mod:`endophoton.quality`
both import from here, so neither imports the other's module at call time.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from . import _core
from .io import check_real

__all__ = ["FRACTIONS", "TARGET_TALLIES", "Target"]

#: The fractions every run reports, each with ``<name>_stderr``: the fates of all launched
#: weight, summing to 1. The engine owns the list (``native/tally.cpp``).
FRACTIONS = tuple(_core.BALANCE_TALLIES)
#: Tallies a target-accuracy run can aim at (engine-side, per launched packet).
TARGET_TALLIES = FRACTIONS[:4] + ("fluorescent_escaped", "escaped_energy")


@dataclass
class Target:
    """Target accuracy: run until stderr/|mean| of ``tally`` <= ``rel_error``."""

    tally: str = "diffuse_reflectance"
    rel_error: float = 0.01

    def __post_init__(self):
        if self.tally not in TARGET_TALLIES:
            raise ValueError(f"target.tally = {self.tally!r} must be one of {', '.join(TARGET_TALLIES)}")
        check_real("target.rel_error", self.rel_error, 0.0, math.inf, lo_open=True)
