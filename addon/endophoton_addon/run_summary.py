# SPDX-License-Identifier: MIT
"""A run's summary: the engine Result's totals (each with its standard error), times and
counts as plain values (stored on the run's collection), and the rows the panel shows."""

from .keys import SUMMARY_KEY

TOTAL_NAMES = (
    "diffuse_reflectance",
    "specular_reflectance",
    "transmittance",
    "absorbed",
    "missed",
    "cut",
    "roulette",
    "fluorescent_escaped",
    "escaped_energy",
)


def summary_from_result(result, inputs, records):
    """Plain dict of what the panel shows (stored on the collection as ID properties)."""
    totals = {}
    for name in TOTAL_NAMES:
        value = getattr(result, name, None)
        if value is None:
            continue
        stderr = getattr(result, f"{name}_stderr", 0.0) or 0.0
        totals[name] = [float(value), float(stderr)]
    regions = {}
    by_region = getattr(result, "absorbed_by_region", None) or {}
    by_region_se = getattr(result, "absorbed_by_region_stderr", None) or {}
    for name, value in by_region.items():
        regions[str(name)] = [float(value), float(by_region_se.get(name, 0.0))]
    packets_traced = getattr(result, "packets_traced", None)
    if packets_traced is None:
        packets_traced = getattr(result, "photons", 0)
    return {
        "beta_deg": float(inputs.beta_deg),
        "timestamp": inputs.timestamp,
        "mode": inputs.kind,
        "requested": int(inputs.count),
        "photons": int(getattr(result, "photons", 0) or 0),
        "packets_traced": int(packets_traced or 0),
        "records": int(records),
        "seconds": float(getattr(result, "seconds", 0.0) or 0.0),
        "grid_path": str(getattr(result, "grid_path", None) or ""),
        "totals": totals,
        "absorbed_by_region": regions,
    }


# Short labels: the sidebar is narrow (Rsp + Rd + Tt + A + missed + cut + roulette = 1).
SUMMARY_LABELS = {
    "diffuse_reflectance": "Rd",
    "specular_reflectance": "Rsp",
    "transmittance": "Tt",
    "absorbed": "A",
    "missed": "Missed",
    "cut": "Cut",
    "roulette": "Roulette",
    "fluorescent_escaped": "Fluor. out",
    "escaped_energy": "Energy out",
}


def summary_rows(collection):
    """(label, value) rows of a run's summary for the panel; totals as value ± standard error."""
    summary = collection.get(SUMMARY_KEY)
    if summary is None:
        return []
    s = summary.to_dict() if hasattr(summary, "to_dict") else dict(summary)
    rows = [
        ("β", f"{s['beta_deg']:+.2f}°"),
        ("Traced", f"{s['packets_traced']:,}"),
        ("Launched", f"{s['photons']:,}"),
        ("Records", f"{s['records']:,}"),
        ("Time", f"{s['seconds']:.2f} s"),
    ]
    for name, (value, stderr) in s.get("totals", {}).items():
        rows.append((SUMMARY_LABELS.get(name, name), f"{value:.4g}±{stderr:.1g}"))
    for name, (value, stderr) in s.get("absorbed_by_region", {}).items():
        rows.append((f"A {name}", f"{value:.4g}±{stderr:.1g}"))
    return rows


def summary_lines(collection):
    """The summary as 'label: value' lines (scripts, reports)."""
    return [f"{label}: {value}" for label, value in summary_rows(collection)]
