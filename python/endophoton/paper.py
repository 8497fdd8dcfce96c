"""The seed paper's constants (Zacher 2009, §3 and §5): the one place they are written.

The tissue optics, the fluorophores and the sweep's geometry defaults are used
by the sweep's default scene (:func:`endophoton.sweep.driver.default_flat_scene`),
the default fluorophores of a region (:data:`endophoton.FLUOROPHORE_DEFAULTS`),
the Blender add-on's presets and the tests.  Plain values only: this module
imports nothing, so anything may import it.
"""

#: Colon tissue and polyp optics: mua, mus in cm^-1, g and n dimensionless (§3).
TISSUE = {"mua": 20.0, "mus": 200.0, "g": 0.9, "n": 1.1}

#: Fluorophores as (d, c): d = probability of interacting with the fluorophore,
#: c = concentration of fluorescent molecules; both dimensionless in [0, 1] (§3).
COLLAGEN = {"d": 0.2, "c": 0.4}
PHOTOFRIN = {"d": 0.1, "c": 0.33}

#: Fluorophores of each region kind, as (name, d, c): collagen everywhere,
#: photofrin accumulates in polyps only.
FLUOROPHORES = {
    "tissue": (("collagen", COLLAGEN["d"], COLLAGEN["c"]),),
    "polyp": (("collagen", COLLAGEN["d"], COLLAGEN["c"]), ("photofrin", PHOTOFRIN["d"], PHOTOFRIN["c"])),
}

#: Angle criterion of an "important" record: within this angle of the direction to the camera (§5, Fig. 6), degrees.
IMPORTANT_ANGLE_DEG = 15.0

#: Head distance from the surface point used by the sweep when none is given, cm (§5).
DISTANCE_CM = 1.0

#: The seed paper's reported trends (Zacher 2009, §5, Figs. 4-9; oracles.md §5).
#: These are the paper's numbers, not ours and not laws of physics.
PAPER_TRENDS: dict = {
    "store": 500_000,  # photons stored per beta
    "betas_deg": list(range(0, 60, 5)),
    "packets_traced_min": 1_000_000,  # "more than one million" traced to store 500,000
    "packets_flat_until_deg": 5,  # flat near 0 deg, linear decrease beyond 5 deg
    "packets_relative_drop": 0.11,  # ~11 % fewer at the largest angle than at 0 deg
    "energy_min_beta_deg": 0,  # lowest total energy at beta = 0
    "energy_fit_degree": 6,
    "energy_peak_beta_deg": 34,  # 6th-degree fit peaks near 34 deg
    "camera_fraction_max": 0.10,  # under 10 % of stored photons point to the camera
    "camera_fraction_last": 0.03,  # ~3 % at the last angle ...
    "camera_fraction_last_beta_deg": 55,  # ... beta = 55 deg
    "camera_max_angle_deg": IMPORTANT_ANGLE_DEG,
    "max_depth_cm": 0.12,  # ~0.12 cm, independent of beta
    "histogram_uniform_at_deg": 0,  # azimuthally uniform at beta = 0
    "histogram_low_shift_to_deg": 180,  # low-elevation rings shift toward 180 deg as beta grows
    "histogram_high_above_deg": 45,  # rings above 45 deg nearly unchanged
}
