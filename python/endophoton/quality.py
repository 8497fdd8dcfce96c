"""Quality presets: a requested accuracy instead of a packet count.

Each preset is a target relative standard error of a tally (the diffuse
reflectance by default, which every scene with a tissue surface has) and an
upper bound on the packets, so that a preset never runs away on a scene whose
tally is tiny. The run reports the error it reached and why it stopped
(``stop_reason`` "target" or "max_photons").

| preset | target rel. error | packet cap |
|---|---|---|
| preview | 5 % | 1e6 |
| standard | 1 % | 2e7 |
| reference | 0.2 % | 2e8 |

The cost of a preset follows the 1/sqrt(N) law measured in docs/performance.md:
each 5x smaller error costs 25x more packets.
"""
from __future__ import annotations

from dataclasses import dataclass

from .tallies import Target


@dataclass(frozen=True)
class Quality:
    name: str
    target: Target
    max_photons: int


QUALITY_PRESETS = {
    "preview": Quality("Preview", Target("diffuse_reflectance", 0.05), 1_000_000),
    "standard": Quality("Standard", Target("diffuse_reflectance", 0.01), 20_000_000),
    "reference": Quality("Reference", Target("diffuse_reflectance", 0.002), 200_000_000),
}


def quality_preset(name: str, tally: str | None = None) -> Quality:
    """The preset ``name`` ("preview", "standard", "reference"), optionally aimed at another tally."""
    key = str(name).lower()
    if key not in QUALITY_PRESETS:
        raise ValueError(f"quality = {name!r} must be one of {', '.join(QUALITY_PRESETS)}")
    q = QUALITY_PRESETS[key]
    if tally is not None:
        q = Quality(q.name, Target(tally, q.target.rel_error), q.max_photons)
    return q
