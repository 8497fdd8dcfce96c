"""The text of docs/performance.md: one renderer per section, from the measurements of bench/run_all.py.

Everything that is not a measurement (what a section measured, how, and what the columns mean) lives
here as templates, so the page is regenerated whole and nothing in it is edited by hand. Each
renderer takes the results dict ``R`` (the content of docs/perf/results.json) and the figure paths
``figs`` and returns lines of Markdown; a section whose measurements are missing says how to
measure it. No measuring happens in this module (tests/python/test_bench_doc.py renders a stored
results file).
"""
from __future__ import annotations

import math
import re

# Oracle references (/work/shared/reference/oracles.md).
VDH_RD, VDH_TT, VDH_UNC = 0.09739, 0.66096, 0.5e-5  # §1, van de Hulst, 5 decimals
SEMI_R, SEMI_UNC = 0.2600, 0.001  # §2, Giovanelli Rsp+Rd; spread of the published values

#: Other processes using more than this many cores (on average over a section) mark its figures as
#: measured under load.
LOAD_CORES = 0.25

SCENE_LABEL = {
    "seed_tissue": "seed tissue, semi-infinite box (n 1.1, mua 20, mus 200, g 0.9), pencil",
    "mcml_slab": "MCML slab (oracles §1), pencil",
    "semi_infinite_n15": "semi-infinite n = 1.5, g = 0 (oracles §2), pencil",
    "colon": "colon tube + polyp, rig at beta 20°, fluorescence (collagen, photofrin)",
    "colon+grids": "colon, + absorbed/fluorescence grids, voxel 0.2 mm",
    "colon+records": "colon, + all escape records kept",
    "colon_lumen_off": "colon, lumen rule off (`lumen=False`: every packet ends at its first exit, as before issue 9)",
}

#: After-configurations measured against a baseline configuration of another name because they run
#: its physics: the issue-11 baseline (37f845d) predates the lumen rule (issue 9), so its colon is
#: today's colon with lumen=False.
LIKE_FOR_LIKE = {"colon_lumen_off": "colon"}

#: Measurement groups (``--sections``) and the keys of ``R`` each one fills.
GROUPS = {
    "throughput": ("throughput",),
    "accuracy": ("accuracy_runs", "accuracy", "accuracy_pooled"),
    "knobs": ("roulette", "safe_distance", "voxel_profile", "voxel_colon", "max_steps", "presets", "target_overhead"),
    "profile": ("profile",),
    "lumen": ("lumen",),
    "render": ("render",),
    "dask": ("dask",),
    "issue11": ("mcml_rd",),
    "meshes": ("mesh_size",),
}


def fmt_int(n):
    return f"{int(round(n)):,}".replace(",", " ")


def md_table(head, rows):
    """A Markdown table: one header row, then ``rows`` (cells formatted with str)."""
    out = ["| " + " | ".join(head) + " |", "|" + "|".join("---" for _ in head) + "|"]
    for r in rows:
        out.append("| " + " | ".join(str(c) for c in r) + " |")
    return "\n".join(out)


def load_note(R, group):
    """'' on a quiet machine, else a sentence marking the group's figures as measured under load."""
    ld = (R.get("load") or {}).get(group)
    if not ld or ld["other_cores"] <= LOAD_CORES:
        return ""
    return (
        f"**Measured under load**: other processes used {ld['other_cores']:.1f} of the "
        f"{R['machine']['cpu_count']} cores on average while this section ran (load average "
        f"{ld['load_start']:.1f} at its start, {ld['load_end']:.1f} at its end), so its wall-clock figures are "
        "indicative only; instruction counts and accuracy figures are not affected.\n"
    )


def missing(R, group):
    """The sentence of a section whose measurements this results file does not hold."""
    why = (R.get("errors") or {}).get(group)
    return [
        (f"Not measured: {why}.\n" if why else "Not measured in this run.\n")
        + f"Measure it with `/usr/bin/python3 bench/run_all.py --sections {group}`.\n"
    ]


def has(R, group):
    return all(k in R for k in GROUPS[group])


def subsection(title):
    """Decorates a part of a section's renderer with its ### heading."""

    def wrap(fn):
        def render(R, figs):
            return [f"### {title}\n"] + fn(R, figs)

        render.__name__, render.__doc__ = fn.__name__, fn.__doc__
        return render

    return wrap


def figure(figs, key, alt):
    """The Markdown line of figure ``key`` (a path relative to the page)."""
    return f"\n![{alt}]({figs[key]})\n"


def section(title, group):
    """Decorates a section's renderer with its heading and, before its lines, either how to measure
    ``group`` (when the results lack it) or, when the machine was busy, the under-load mark."""

    def wrap(fn):
        def render(R, figs, *extra):
            if not has(R, group):
                return [f"## {title}\n"] + missing(R, group)
            return [f"## {title}\n", load_note(R, group)] + fn(R, figs, *extra)

        render.__name__, render.__doc__ = fn.__name__, fn.__doc__
        return render

    return wrap


def sec_machine(R, figs):
    """Title, provenance and the machine table."""
    L = []
    a = L.append
    M = R["machine"]
    a("# EndoPhoton performance and accuracy\n")
    a(
        "Generated by `/usr/bin/python3 bench/run_all.py` (do not edit by hand; rerun it: the whole page, "
        "explanations included, comes from `bench/perf_doc.py`'s templates). Every number below comes from that "
        "run, except the issue-11 baseline of §9"
        + ("" if R.get("mcml_side_by_side") else " and MCML's figures there (quoted from issue 11)")
        + ", which `bench/baseline.json` records with its provenance; the raw numbers are in `docs/perf/results.json`."
        + (" MCML itself was run beside this engine (`--mcml-binary`, §9).\n" if R.get("mcml_side_by_side") else "\n")
    )
    a("## Machine\n")
    a(
        md_table(
            ["", ""],
            [
                ["date", M["date"]],
                ["CPU", M["cpu"]],
                ["nproc", M["nproc"]],
                ["memory", M["mem"]],
                ["kernel", M["kernel"]],
                ["Python / numpy", f"{M['python']} / {M['numpy']}"],
                ["engine", f"endophoton {M['engine']}, commit {M['commit']}"],
                [
                    "load average at start / end",
                    " / ".join(f"{x:.1f}" for x in M["load_start"])
                    + " ; "
                    + " / ".join(f"{x:.1f}" for x in M["load_end"]),
                ],
                [
                    "bench wall time",
                    f"{R['bench_seconds']:.0f} s (budget {R.get('budget_s', 900):.0f} s)"
                    + (" (--quick)" if R["quick"] else "")
                    + (f" (partial rerun of {', '.join(R['partial_rerun'])})" if R.get("partial_rerun") else ""),
                ],
            ],
        )
    )
    under = [g for g in GROUPS if load_note(R, g)]
    if under:
        a(
            f"\nThe machine was shared while these sections ran: {', '.join(under)}. Their wall-clock figures are "
            "marked **measured under load** (other processes' CPU time, from /proc/stat less this run's own); "
            "instruction counts (callgrind) and accuracy figures do not depend on load.\n"
        )
    else:
        a("\nNo other process used more than a quarter of a core during any section (from /proc/stat).\n")

    return L


@section("1. Throughput and peak memory", "throughput")
def sec_throughput(R, figs):
    """§1: packets/s, packets per CPU-second and peak memory per configuration, 1 and 2 threads."""
    L = []
    a = L.append
    rows = R["throughput"]
    a(
        "One fresh process per configuration; a 2000-packet warm-up, then the timed run; packets/s = packets / "
        "engine seconds (wall clock); packets per CPU-second = packets / (user + system CPU time of the run), which "
        "shows the parallel efficiency even when the shared machine does not give the run two whole cores; best of "
        f"{len(_pairs_of(rows)) or 3} repeats, interleaved over time. The scaling is the median over the repeats of the ratio of a 2-thread run to the 1-thread run next to it in time (alternating which runs first), so the machine's drift in speed between repeats does not enter it; the paired ratios and the ratio of the two best runs are shown beside it, and the median of the paired ratios recomputed from each run's engine seconds less the hypervisor's steal met during it (/proc/stat; divided by the run's threads, since the units are shared out on demand). In this run the steal met by one run reached "
        f"{max((r.get('steal_s', 0) / (r['seconds'] * r['threads']) for r in rows), default=0):.0%} of the CPU time it "
        "asked for. Memory is the process's peak resident set (VmHWM, Python + numpy + engine): `base` before the "
        "timed run (after imports, scene build and warm-up), `peak` after it. (`resource.getrusage().ru_maxrss` is "
        "not used: Linux carries the parent's peak over fork + execve into the child's ru_maxrss, so a child started "
        f"from this bench reported the bench's own peak — here up to {max(r['ru_maxrss_mb'] for r in rows):.0f} MB.)\n"
    )
    scen = SCENE_LABEL
    tr = []
    for key in dict.fromkeys(r["key"] for r in rows):
        r1 = next(r for r in rows if r["key"] == key and r["threads"] == 1)
        r2 = next(r for r in rows if r["key"] == key and r["threads"] == 2)
        tr.append(
            [
                key,
                scen[key],
                fmt_int(r1["packets"]),
                fmt_int(r1["pps"]),
                fmt_int(r2["pps"]),
                _scaling_cell(r1, r2),
                f"{fmt_int(r1['pp_cpu_s'])} / {fmt_int(r2['pp_cpu_s'])}",
                f"{r1['base_rss_mb']:.0f} / {r1['peak_rss_mb']:.0f}",
                f"{r2['base_rss_mb']:.0f} / {r2['peak_rss_mb']:.0f}",
            ]
        )
    a(
        md_table(
            [
                "config",
                "scene",
                "packets",
                "packets/s, 1 thread",
                "packets/s, 2 threads",
                "wall-clock scaling",
                "packets per CPU-s (1 / 2 thr)",
                "RSS MB base / peak (1 thr)",
                "RSS MB base / peak (2 thr)",
            ],
            tr,
        )
    )
    eff = [
        next(r for r in rows if r["key"] == k and r["threads"] == 2)["pp_cpu_s"]
        / next(r for r in rows if r["key"] == k and r["threads"] == 1)["pp_cpu_s"]
        for k in dict.fromkeys(r["key"] for r in rows)
    ]
    wall = [
        scaling_of(
            next(r for r in rows if r["key"] == k and r["threads"] == 1),
            next(r for r in rows if r["key"] == k and r["threads"] == 2),
        )
        for k in dict.fromkeys(r["key"] for r in rows)
    ]
    a(
        f"\nPer CPU-second the 2-thread runs do {min(eff):.2f}–{max(eff):.2f} of the 1-thread work, so on two idle "
        f"cores the expected scaling is about {2 * min(eff):.1f}–{2 * max(eff):.1f}×. The wall-clock scaling measured "
        f"here ranges from {min(wall):.2f}× to {max(wall):.2f}× (load "
        f"average {R['machine']['load_start'][0]:.1f} at the start, {R['machine']['load_end'][0]:.1f} at the end)."
    )
    rec = next(r for r in rows if r["key"] == "colon+records" and r["threads"] == 2)
    grd = next(r for r in rows if r["key"] == "colon+grids" and r["threads"] == 2)
    a(
        f"\nEscape records: {fmt_int(rec['records_n'])} records took {rec['record_bytes'] / 1e6:.1f} MB in the engine "
        f"({rec['record_bytes'] / max(1, rec['records_n']):.0f} bytes per record). Grids at 0.2 mm: the .vdb file was "
        f"{grd['grid_bytes'] / 1e6:.2f} MB.\n"
    )
    a(f"![throughput]({figs['throughput']})\n")

    return L


@section("2. Accuracy versus packets and wall time (MCML slab, oracles §1)", "accuracy")
def sec_accuracy(R, figs):
    """§2: error against van de Hulst versus packets and wall time."""
    L = []
    a = L.append
    summ, pooled = R["accuracy"], R["accuracy_pooled"]
    a(
        "Independent runs (different seeds, 2 threads) of the slab n = 1, mua = 10, mus = 90, g = 0.75, "
        "d = 0.02 cm; error against van de Hulst (Rd = 0.09739, Tt = 0.66096, rounding ±5e-6). "
        "`in 3σ` counts the runs with |error| < 3 × reported stderr + 5e-6.\n"
    )
    tr = []
    for s in summ:
        tr.append(
            [
                fmt_int(s["N"]),
                s["runs"],
                f"{s['seconds']:.3f}",
                f"{s['rd_rms']:.2e}",
                f"{s['rd_se']:.2e}",
                f"{s['rd_rms'] / s['rd_se']:.2f}",
                f"{s['rd_within3']}/{s['runs']}",
                f"{s['tt_rms']:.2e}",
                f"{s['tt_se']:.2e}",
                f"{s['tt_within3']}/{s['runs']}",
            ]
        )
    a(
        md_table(
            [
                "N",
                "runs",
                "s / run",
                "Rd RMS error",
                "Rd stderr",
                "RMS/stderr",
                "Rd in 3σ",
                "Tt RMS error",
                "Tt stderr",
                "Tt in 3σ",
            ],
            tr,
        )
    )
    a("")
    for k, lab, ref in (("rd", "Rd", VDH_RD), ("tt", "Tt", VDH_TT)):
        p = pooled[k]
        a(
            f"- Pooled over all {fmt_int(p['packets'])} packets: {lab} = {p['mean']:.6f} ± {p['se']:.1e} vs {ref}; "
            f"error {p['err']:+.1e} = {p['z']:+.2f} σ. Per-packet standard deviation σ₁ = {p['sigma1']:.3f}, so the "
            f"stderr is σ₁/√N."
        )
    floor = any(abs(pooled[k]["z"]) > 3 for k in ("rd", "tt"))
    a("")
    if floor:
        a(
            "**A floor appears**: the pooled error is more than 3 σ from the reference (see the table above); "
            "the error stops following 1/√N at about that level.\n"
        )
    else:
        a(
            f"**No floor** is visible: down to the pooled stderr ({pooled['rd']['se']:.1e} on Rd, "
            f"{pooled['tt']['se']:.1e} on Tt) the pooled error is within 3 σ of the reference. Over the "
            f"{pooled['rd']['runs']} runs the RMS of (error / reported stderr) is {pooled['rd']['rms_z']:.2f} for Rd and "
            f"{pooled['tt']['rms_z']:.2f} for Tt (1 if the stderr describes the scatter). The next floor is the "
            f"reference itself: van de Hulst's 5 decimals (±5e-6), reached at N ≈ (σ₁/5e-6)² = "
            f"{fmt_int((pooled['rd']['sigma1'] / 5e-6) ** 2)} packets for Rd.\n"
        )
    a(f"![accuracy vs N]({figs['accuracy_N']})\n")
    a(f"![accuracy vs time]({figs['accuracy_time']})\n")

    return L


@subsection("Russian roulette threshold")
def _knob_roulette(R, figs):
    """Russian roulette threshold against efficiency and bias."""
    L = []
    a = L.append
    a(
        "MCML roulette: below the threshold a packet survives with chance 0.1 and weight × 10. Efficiency = "
        "1/(σ² t) (higher is better), relative to the default 1e-4. Reference: van de Hulst Rd for the slab, "
        "Giovanelli Rsp + Rd = 0.2600 (±0.001, the spread of the published values) for the semi-infinite medium.\n"
    )
    tr = []
    for r in R["roulette"]:
        base = next(x for x in R["roulette"] if x["scene"] == r["scene"] and x["threshold"] == 1e-4)
        tr.append(
            [
                r["scene"],
                f"{r['threshold']:.0e}",
                fmt_int(r["N"]),
                f"{r['seconds']:.2f}",
                f"{r['value']:.5f} ± {r['se']:.5f}",
                f"{(r['value'] - r['ref']) / r['se']:+.2f}",
                "yes" if r["ok"] else "**no**",
                f"{r['fom'] / base['fom']:.2f}",
                f"{r['roulette']:+.1e} ± {r['roulette_se']:.1e}",
            ]
        )
    a(
        md_table(
            [
                "scene",
                "threshold",
                "packets",
                "seconds",
                "estimate ± σ",
                "(x − ref)/σ",
                "within 3σ + ref unc.",
                "efficiency vs 1e-4",
                "net roulette weight",
            ],
            tr,
        )
    )
    a(figure(figs, "roulette", "roulette"))
    return L


@subsection("Safe distance (closest-surface query) on / off")
def _knob_safe_distance(R, figs):
    """safe_distance on / off: wall clock and instructions."""
    L = []
    a = L.append
    a(
        "`safe_distance=True` (the default) lets the engine answer steps near surfaces from its local geometry "
        "(issue 11's triangle cache, on scenes it serves) instead of a full Embree query; `False` queries Embree "
        "at every step. Wall clock, 1 thread, best of three interleaved repeats; the tallies are identical "
        "(same random numbers, same decisions) but where a crossing lies within float rounding of a shared "
        "triangle edge, which the two may resolve to different triangles (`docs/numerics.md`, \"Vertices and "
        "edges\").\n"
    )
    tr = []
    for r in R["safe_distance"]:
        tr.append(
            [
                r["scene"],
                fmt_int(r["N"]),
                fmt_int(r["pps_on"]),
                fmt_int(r["pps_off"]),
                f"{r['pps_on'] / r['pps_off']:.2f}×",
                "yes" if r["identical"] else "**no**",
            ]
        )
    a(md_table(["scene", "packets", "packets/s on", "packets/s off", "speed-up on/off", "identical Rd"], tr))
    pf = R.get("profile") or {}
    if pf.get("safe_distance"):
        a("\nSame comparison in instructions (callgrind, 1 thread, load-independent), per packet:\n")
        tr = [
            [
                r["scene"],
                fmt_int(r["packets"]),
                fmt_int(r["ir_on"]),
                fmt_int(r["ir_off"]),
                f"{r['ir_off'] / r['ir_on']:.2f}×",
                f"{r['rq_on']:.1f}",
                f"{r['rq_off']:.1f}",
            ]
            for r in pf["safe_distance"]
        ]
        head = ["scene", "packets", "Ir/packet on", "Ir/packet off", "off/on", "all-hits queries/packet on", "off"]
        a(md_table(head, tr))
        verdict = "; ".join(
            f"{r['scene']}: {'saves' if r['ir_on'] < r['ir_off'] else 'costs'} "
            f"{abs(1 - r['ir_on'] / r['ir_off']) * 100:.0f} %"
            for r in pf["safe_distance"]
        )
        a(f"\nBy instruction count, `safe_distance=True` {verdict}.")
    a("")
    return L


@subsection("Voxel size of the grids")
def _knob_voxel(R, figs):
    """Voxel size of the grids: accuracy against Beer–Lambert, cost on the colon."""
    L = []
    a = L.append
    vb = R["voxel_profile"]
    a(
        "Accuracy: the absorbed grid of a pencil beam (matched n, mua = 10 cm⁻¹) summed over x, y, for voxels fully "
        "below the surface down to 0.3 cm, against Beer–Lambert. Two deposit paths of the engine: **interaction "
        "sites** — mus = 90, g = 1 (scattering never deflects, so the expected absorption density is mua·e^(−mua z) "
        f"exactly; {vb[0]['seeds']} independent seeds give the noise) — and **clear region** — mus = 0, where the "
        "engine applies Beer–Lambert along the path and spreads the deposit over pieces of the segment "
        "(deterministic). Columns: the largest relative error against the exact voxel integrals "
        "e^(−mua(z−h/2)) − e^(−mua(z+h/2)); the RMS of (error/stderr) against them (expected "
        "√((s−1)/(s−3)) for s seeds if only noise); and the RMS relative error against the point density "
        "mua·h·e^(−mua z) at the voxel centre, the usual reading of a grid, whose bias is the midpoint error "
        "≈ (mua h)²/24.\n"
    )
    tr = []
    for r in vb:
        z = f"{r['rms_z_vs_exact']:.2f} (exp. {r['rms_z_expected']:.2f})" if "rms_z_vs_exact" in r else "– (no noise)"
        tr.append(
            [
                r["case"],
                f"{r['h']:g}",
                r["voxels"],
                fmt_int(r["N"]),
                f"{r['max_rel_vs_exact']:.2e}",
                z,
                f"{r['rms_rel_vs_point']:.4f}",
                f"{r['bias_point']:+.4f}",
                f"{r['seconds']:.2f}",
                f"{r['file_bytes'] / 1e3:.0f}",
                f"{r['sum_rel']:.1e}",
            ]
        )
    a(
        md_table(
            [
                "deposits",
                "h (cm)",
                "voxels",
                "packets",
                "max rel. error vs exact integral",
                "RMS (error/stderr)",
                "RMS rel. error vs point density",
                "midpoint bias",
                "seconds",
                "file kB",
                "grid sum vs absorbed (rel. diff.)",
            ],
            tr,
        )
    )
    clear = [r for r in vb if "clear" in r["case"]]
    worst = max(clear, key=lambda r: r["max_rel_vs_exact"])
    if worst["max_rel_vs_exact"] > 0.05:
        a(
            f"\n**Engine issue (reported):** in a clear absorbing region the grid deposit of each piece of the "
            f"straight segment goes to the voxel that holds the piece's midpoint, and the pieces are not aligned "
            f"with the voxels, so single voxels are off by up to {100 * worst['max_rel_vs_exact']:.0f} % "
            f"(h = {worst['h']:g} cm) although the totals are exact. Splitting the segment at voxel faces (a 3-D DDA) "
            "would make each voxel exact.\n"
        )
    vc = R["voxel_colon"]
    base = vc[0]
    a(f"\nCost on the colon scene ({fmt_int(base['packets'])} packets, 2 threads, one process each):\n")
    tr = [["none", fmt_int(base["pps"]), f"{base['peak_rss_mb']:.0f}", "–", "–"]]
    for r in vc[1:]:
        tr.append(
            [
                f"{r['h_mm']:g}",
                fmt_int(r["pps"]),
                f"{r['peak_rss_mb']:.0f}",
                f"{r['grid_bytes'] / 1e6:.2f}",
                f"{abs(r['grid_absorbed_sum'] - r['absorbed_energy']) / r['absorbed_energy']:.1e}",
            ]
        )
    a(md_table(["voxel (mm)", "packets/s", "peak RSS MB", "VDB MB", "grid sum vs absorbed energy (rel. diff.)"], tr))
    a(figure(figs, "voxel", "voxel"))
    return L


@subsection("max_steps cap")
def _knob_max_steps(R, figs):
    """The max_steps cap: cut weight and bias."""
    L = []
    a = L.append
    a(
        "Events (interactions + boundary crossings) per packet above the cap end the packet; its weight is tallied "
        "as `cut`, so the estimate is biased low by up to the cut weight.\n"
    )
    tr = []
    for r in R["max_steps"]:
        tr.append(
            [
                r["scene"],
                r["cap"] if r["cap"] else "0 (none)",
                fmt_int(r["N"]),
                f"{r['seconds']:.2f}",
                f"{r['cut']:.2e}",
                f"{r['value']:.5f} ± {r['se']:.5f}",
                f"{(r['value'] - r['ref']) / r['se']:+.1f}",
                "yes" if r["ok"] else "**no**",
            ]
        )
    a(
        md_table(
            ["scene", "max_steps", "packets", "seconds", "cut", "estimate ± σ", "(x − ref)/σ", "within 3σ + ref unc."],
            tr,
        )
    )
    a(figure(figs, "max_steps", "max steps"))
    return L


@subsection("Packet count and target accuracy")
def _knob_target(R, figs):
    """Target accuracy: packets and time per target, and the cost of the stop rule."""
    L = []
    a = L.append
    a(
        "The packet count sets the error as σ₁/√N (section 2). Target-accuracy mode "
        "(`ep.run(..., target=ep.Target(tally, rel_error))`) runs until stderr/|mean| ≤ rel_error; packets used, "
        "time (2 threads) and, where an oracle exists, the error against it. Each run is capped at "
        f"{fmt_int(R['presets'][0].get('cap', 0))} packets to keep the bench within its budget; `stop` = "
        "`max_photons` marks a target the cap did not reach.\n"
    )
    tr = []
    for r in R["presets"]:
        ref = f"{r['err']:+.1e} ({r['err'] / math.hypot(r['se'], r['unc']):+.1f} σ)" if "ref" in r else "–"
        tr.append(
            [
                r["scene"],
                r["tally"],
                f"{100 * r['target']:g} %",
                fmt_int(r["packets"]),
                f"{r['seconds']:.2f}",
                f"{100 * r['rel']:.3f} %",
                f"{r['value']:.5f}",
                ref,
                r["stop"],
            ]
        )
    a(md_table(["scene", "tally", "target", "packets", "seconds", "reached", "value", "error vs oracle", "stop"], tr))
    a(figure(figs, "presets", "presets"))
    to = R["target_overhead"]
    a(
        "**Cost of the stop rule.** The target mode checks its rule after every merged work unit. Measured on the "
        f"slab ({fmt_int(to[0]['N'])} packets, impossible target, `max_photons` = packets, best of three), target mode "
        "against a fixed-count run of the same packets, for several unit sizes (K units per run):\n"
    )
    tr = [
        [r["unit"], fmt_int(r["units"]), f"{r['fixed_s']:.2f}", f"{r['target_s']:.2f}", f"{r['overhead_s']:+.2f}"]
        for r in to
    ]
    a(md_table(["unit size", "units K", "fixed-count s", "target mode s", "overhead s"], tr))
    a(stop_rule_verdict(to))
    return L


@subsection("float or double positions")
def _knob_float(R, figs):
    """float or double positions (no float build: text only)."""
    L = []
    a = L.append
    a(
        "Not available as a runtime option: the engine is double-only. `native/vecmath.h` defines one alias "
        "`using Float = double;` for positions, directions, weights and step lengths (Embree itself receives float32 "
        "rays and vertices). A float build would mean changing that alias and rebuilding, then re-validating: "
        "`ray_offset` / `group_tolerance` in `transport.cpp` are tuned for double positions with float Embree hits, "
        "the counter-based RNG returns doubles with 53 random bits, and the batch accumulators must stay double. "
        "No float numbers are reported here because no float build exists.\n"
    )
    return L


@section("3. Speed / accuracy knobs", "knobs")
def sec_knobs(R, figs):
    """§3: roulette, safe distance, voxel size, max_steps, target accuracy, float vs double."""
    return [line for part in KNOBS for line in part(R, figs)]


KNOBS = (_knob_roulette, _knob_safe_distance, _knob_voxel, _knob_max_steps, _knob_target, _knob_float)


@section("5. Quality presets", "knobs")
def sec_presets(R, figs):
    """§5: the quality presets."""
    L = []
    a = L.append
    a(
        "Presets defined by a target relative standard error on the diffuse reflectance (`ep.run(quality=...)`; "
        "this bench also aims the colon runs at the fluorescent escaped weight, with `target=`), measured above "
        "with 2 threads:\n"
    )
    tr = []
    for name, t in (("Preview", 0.05), ("Standard", 0.01), ("Reference", 0.002)):
        cells = [name, f"{100 * t:g} %"]
        for scene in dict.fromkeys(r["scene"] for r in R["presets"]):
            r = next((x for x in R["presets"] if x["scene"] == scene and x["target"] == t), None)
            cells.append(f"{fmt_int(r['packets'])} / {r['seconds']:.2f} s" if r else "–")
        tr.append(cells)
    a(
        md_table(
            ["preset", "target rel. stderr"]
            + [f"{s}: packets / time" for s in dict.fromkeys(r["scene"] for r in R["presets"])],
            tr,
        )
    )
    tu = R["presets"][0].get("unit", 0)
    a(
        f"\nThe smallest target run used {fmt_int(min(r['packets'] for r in R['presets']))} packets: the target mode "
        f"works in units of {tu} packets and checks the rule from 20 units on (`native/engine.cpp`), so a loose "
        "target costs at least that.\n"
    )
    try:
        import endophoton as ep

        qp = ep.QUALITY_PRESETS
        a(
            "The package defines them in `python/endophoton/quality.py` (`ep.run(..., quality=...)`): "
            + "; ".join(
                f"{q.name} = {100 * q.target.rel_error:g} % on {q.target.tally}, cap {fmt_int(q.max_photons)} packets"
                for q in qp.values()
            )
            + ".\n"
        )
    except Exception:
        pass
    return L


#: Differences of best-of-three run times below this are timing noise on this VM (seconds).
STOP_RULE_NOISE_S = 0.05


def stop_rule_verdict(to):
    """What the stop-rule runs say about how the check's cost grows with the K units of a run. The growth
    is read where it can be told from noise: from the runs whose overhead exceeds the timing noise, as the
    slope p of log(overhead) against log(K) (overhead ∝ K^p: p = 1 for a cost per unit, as reading prefix
    sums gives; p = 2 if every check re-read the merged units). p ≥ 1.5 is reported as K² growth. With
    fewer than two such runs (or K spanning less than ×2) no growth can be read. Without K² growth the
    cost per unit is bounded by the largest overhead per unit of the runs above the noise (with none, by
    the noise over the largest K). (A least-squares fit of a·K + c·K² to one run above the noise and
    three within it read a +0.08 s overhead at K = 100 000 as K² growth, which runs at K = 50 000 and
    200 000 then contradicted: 0.15 s at both.)"""
    import numpy as np

    K = np.array([r["units"] for r in to], dtype=float)
    o = np.array([r["overhead_s"] for r in to], dtype=float)
    unit = to[0].get("default_target_unit", 1024)
    cap = to[0].get("largest_preset_cap", 200_000_000)
    Kc = cap / unit
    at_cap = f"a run at the largest preset cap ({fmt_int(cap)} packets, {fmt_int(Kc)} units of {unit})"
    big = o > STOP_RULE_NOISE_S
    if big.sum() >= 2 and K[big].max() >= 2 * K[big].min():
        p = float(np.polyfit(np.log(K[big]), np.log(o[big]), 1)[0])
        span = f"between K = {fmt_int(K[big].min())} and {fmt_int(K[big].max())}"
        if p >= 1.5:
            c = float(np.sum(K[big] ** 2 * o[big]) / np.sum(K[big] ** 4))  # least squares of o = c K²
            return (
                f"\nThe overhead grows as K²: above the timing noise ({STOP_RULE_NOISE_S} s) it grows as K^{p:.2f} "
                f"{span}; with overhead = c·K², c = {c:.1e} s, so {at_cap} would spend ≈ {c * Kc**2:.0f} s on stop "
                "checks (extrapolated, not measured). **Engine issue**: the check should cost O(1) per unit.\n"
            )
        growth = (
            f"above the timing noise ({STOP_RULE_NOISE_S} s) the overhead grows as K^{p:.2f} {span} (K² would give 2)"
        )
    else:
        growth = (
            f"{int(big.sum())} of the {len(to)} runs have an overhead above the timing noise ({STOP_RULE_NOISE_S} s), "
            "too few to read a growth from"
        )
    # The cost per unit, bounded by the runs above the noise (the largest overhead per unit among them),
    # or, with none, by the noise at the largest K.
    if big.any():
        per_unit = float(np.max(o[big] / K[big]))
        bound = f"at most {per_unit * 1e6:.2f} µs per unit (the largest overhead per unit of the runs above the noise)"
    else:
        per_unit = STOP_RULE_NOISE_S / K.max()
        bound = f"below {per_unit * 1e6:.2f} µs per unit (the noise at the largest K, {fmt_int(K.max())})"
    return (
        f"\nNo K² growth: {growth}. The check reads prefix sums of the merged units (`StopRule::after_merge`), "
        f"O(1) per unit; it costs {bound}, so {at_cap} spends ≲ {per_unit * Kc:.1f} s on stop checks "
        "(extrapolated).\n"
    )


def sec_profile(R, figs):
    """§4: instructions per packet and per interaction, split by part of the loop (callgrind)."""
    L = []
    a = L.append
    a("## 4. Instructions per step (callgrind)\n")
    pf = R.get("profile") or {}
    if "steps" not in pf:
        why = pf.get("error") or (R.get("errors") or {}).get("profile")
        return L + missing(dict(R, errors={"profile": why}), "profile")
    rows = pf["steps"]
    a(
        "`bench/callgrind_steps.py`: `valgrind --tool=callgrind --toggle-collect='ep::Tracer::trace(*'`, one thread, "
        f"with an unstripped build of the same sources ({pf.get('build', 'a profile build')}; the in-tree module is "
        "stripped, so its functions would be addresses). Only instructions (Ir) executed inside `Tracer::trace` "
        "count; a step is an interaction (the `interactions` tally). Instruction counts do not depend on the "
        "machine's load.\n"
    )
    a(
        md_table(
            ["scene", "packets", "Ir / packet", "interactions / packet", "Ir / interaction", "Rd ± σ"],
            [
                [
                    r["scene"],
                    fmt_int(r["packets"]),
                    fmt_int(r["ir_packet"]),
                    f"{r['steps_packet']:.1f}",
                    fmt_int(r["ir_step"]),
                    f"{r['rd']:.5f} ± {r['rd_se']:.5f}",
                ]
                for r in rows
            ],
        )
    )
    a(
        "\nEach part of the loop, Ir per interaction (calls per packet in brackets; `loop (rest)` is everything "
        "inlined into the transport loop: RNG, phase function, vector maths, tallies, interface logic):\n"
    )
    parts = list(dict.fromkeys(k for r in rows for k in r["parts"]))
    tr = []
    for k in parts:
        cells = [k]
        for r in rows:
            v, c = r["parts"].get(k), r["calls"].get(k)
            cells.append("–" if v is None else f"{v:.0f}" + (f" ({c:.2f})" if c is not None else ""))
        tr.append(cells)
    a(md_table(["part"] + [r["scene"] for r in rows], tr))
    if "profile" in figs:
        a(figure(figs, "profile", "profile"))
    return L


@section("6. Light crosses the lumen on colon_polyp (issue 9)", "lumen")
def sec_lumen(R, figs):
    """§6: what the lumen rule (issue 9) changes on colon_polyp, and what it costs."""
    L = []
    a = L.append
    m = R["lumen"]
    off, on = m["without_rule"], m["with_rule"]
    a(
        "`bench/lumen_colon.py` traces `bench/colon_scene.py`'s tube (seed's tissue, collagen, photofrin polyp, rig "
        "at β = 20°, 1 cm from the polyp, head body on) with the rule on and off (`ep.run(..., lumen=False)`, the "
        f"engine's behaviour before issue 9), same seed {m['seed']}, {fmt_int(m['photons'])} packets, "
        f"{m['threads']} threads. Errors are 1σ batch means over 50 blocks.\n"
    )

    def pm(d, k):
        v, se = d[k]
        return f"{v:.6f} ± {se:.6f}"

    tr = [
        [k, pm(off, k), pm(on, k)]
        for k in ("specular_reflectance", "diffuse_reflectance", "transmittance", "absorbed", "occluded")
        + ("camera_collected",)
    ]
    tr += [
        ["balance − 1", f"{off['balance'] - 1:+.1e}", f"{on['balance'] - 1:+.1e}"],
        ["records (exits)", fmt_int(off["records"]), fmt_int(on["records"])],
        ["interactions per packet", f"{off['interactions_per_packet']:.1f}", f"{on['interactions_per_packet']:.1f}"],
        ["packets/s", fmt_int(off["packets_per_s"]), fmt_int(on["packets_per_s"])],
        [
            "seconds per million interactions",
            f"{off['seconds_per_million_interactions']:.2f}",
            f"{on['seconds_per_million_interactions']:.2f}",
        ],
    ]
    a(md_table(["quantity (per launched packet)", "rule off", "rule on"], tr))
    hits = m["next_hit_counts"]
    land, far = m["lumen_landing_weight"], m["far_wall_landing_weight"]
    a(
        f"\n- **Second and later exits:** {100 * m['share_second_or_later_exits']:.1f} % of the records have "
        f"`exit_order` ≥ 2. Where the exits' rays went: "
        + ", ".join(f"{k} {fmt_int(v)}" for k, v in hits.items())
        + "."
    )
    a(
        f"- **Light that crosses the lumen and lands on tissue:** {land[0]:.4f} ± {land[1]:.4f} of the launched "
        "weight (arriving weight, before the landing's Fresnel choice). **The far wall** (z > 0: the half of the "
        "tube opposite the polyp and the rig's view; the landing point found with the scene's ray query on each "
        f"record's ray) receives {far[0]:.4f} ± {far[1]:.4f} of it. With the rule off this light was counted in Rd "
        "and lost."
    )
    a(
        f"- **Cost:** rule on / off = {on['packets_per_s'] / off['packets_per_s']:.2f} in packets/s, "
        f"{on['interactions_per_packet'] / off['interactions_per_packet']:.2f} in interactions per packet (landed "
        "light walks in the tissue again) and "
        f"{on['seconds_per_million_interactions'] / off['seconds_per_million_interactions']:.2f} in time per "
        "interaction (the ray query per exit to infinity and the mirror-ray query at the first boundary); one "
        "run each, wall clock.\n"
    )
    return L


@section("7. Endoscope view: seconds per image", "render")
def sec_render(R, figs):
    """§7: seconds per endoscope image against kernel size and resolution (bench/render_speed.py)."""
    import render_speed  # the table's own template lives with its measurement

    return [render_speed.table(R["render"]["rows"], R["render"]["meta"])]


@section("8. Distributed runs (Dask)", "dask")
def sec_dask(R, figs):
    """§8: distributed runs, the table bench/dask_cluster.py prints."""
    L = []
    a = L.append
    d = R["dask"]
    a(
        f"`/usr/bin/python3 bench/{' '.join(d['args'])}` (what it measures: its docstring; the set-up: "
        "`docs/distributed.md`). Its output, as printed"
        + (":" if d["returncode"] == 0 else f" (**it failed**, exit status {d['returncode']}):")
        + "\n"
    )
    out = d["stdout"].rstrip("\n")
    if d["returncode"] == 0 and "\n|---" in out:  # the script prints Markdown: its headings go below §8's
        a(re.sub(r"^#{1,3} ", "### ", out, flags=re.M) + "\n")
    else:
        a("```text\n" + out + ("\n" + d["stderr_tail"].rstrip("\n") if d["returncode"] else "") + "\n```\n")
    return L


def _pairs_of(rows):
    """The paired scaling ratios of the first 2-thread row that has them (none in older results)."""
    return next((r["paired_scaling"] for r in rows if r.get("paired_scaling")), [])


def _median(xs):
    s = sorted(xs)
    m = len(s) // 2
    return s[m] if len(s) % 2 else 0.5 * (s[m - 1] + s[m])


def scaling_of(r1, r2, field="paired_scaling"):
    """Scaling from 1 to 2 threads: the median of the ratios of adjacent 1- and 2-thread runs
    (bench_throughput's `paired_scaling`, measured at nearly the same machine speed; with
    field="paired_scaling_steal_free", of the same ratios less the hypervisor's steal); the ratio of
    the two best runs where a result predates the pairing."""
    pairs = r2.get(field)
    return _median(pairs) if pairs else r2["pps"] / r1["pps"]


def _scaling_cell(r1, r2):
    """The scaling for a table cell: the paired median, then the paired ratios and the best/best ratio."""
    pairs = r2.get("paired_scaling")
    if not pairs:
        return f"{r2['pps'] / r1['pps']:.2f}×"
    cell = (
        f"{scaling_of(r1, r2):.2f}× (pairs {', '.join(f'{p:.2f}' for p in pairs)}; best/best "
        f"{r2['pps'] / r1['pps']:.2f})"
    )
    if r2.get("paired_scaling_steal_free"):
        cell += f"; less steal {scaling_of(r1, r2, 'paired_scaling_steal_free'):.2f}×"
    return cell


def _goal(ok):
    return "**reached**" if ok else "**not reached**"


def sec_issue11(R, figs, B):
    """§9: issue 11 before / after: packets/s per core, scaling, memory, instructions, MCML side by side."""
    L = []
    a = L.append
    a("## 9. Issue 11: before / after, and MCML side by side\n")
    if not (has(R, "throughput") and B):
        return L + missing(R, "throughput") + _issue11_mcml(R)
    bt, pv = B["throughput"], B["provenance"]
    a(load_note(R, "throughput"))
    a(
        f"**Before** = commit {B['commit']} ({B['commit_subject']}): its figures are recorded in "
        f"`bench/baseline.json` ({pv['source']}; {pv['command']}, {pv['date']}, {pv['machine']}, load average "
        f"{pv['load_average_start_end'][0]:.1f} at the start), not measured by this run. Note: {pv['scenes']}. "
        f"**After** = this run (§1, the same configurations and one process each; best of "
        f"{len(_pairs_of(R['throughput'])) or 3} repeats, and the packet counts in §1's table). "
        "Speed-ups are after / before. The baseline's colon had no lumen rule (every packet ended at its "
        "first exit), so the like-for-like after of its `colon` row is `colon_lumen_off` (today's engine with "
        "`lumen=False`); the `colon` rows compare today's heavier physics (§6) with the baseline's.\n"
    )
    after = {(r["key"], r["threads"]): r for r in R["throughput"]}
    tr = []
    pairs = [(key, key) for key in bt]
    for akey, bkey in LIKE_FOR_LIKE.items():  # right after the row of the baseline config it matches
        pairs.insert(next((i + 1 for i, (k, _) in enumerate(pairs) if k == bkey), len(pairs)), (akey, bkey))
    for key, bkey in pairs:
        for th in (1, 2):
            b, r = bt.get(bkey, {}).get(str(th)), after.get((key, th))
            if not (b and r):
                continue
            tr.append(
                [
                    key if key == bkey else f"{key} (before: {bkey})",
                    th,
                    fmt_int(b["pps"]),
                    fmt_int(r["pps"]),
                    f"{r['pps'] / b['pps']:.2f}×",
                    f"{fmt_int(b['pp_cpu_s'])} → {fmt_int(r['pp_cpu_s'])}",
                    f"{b['peak_rss_mb']:.0f} → {r['peak_rss_mb']:.0f}",
                ]
            )
    a(
        md_table(
            ["config", "threads", "packets/s before", "packets/s after", "speed-up", "packets per CPU-s", "peak MB"],
            tr,
        )
    )
    a(
        "\nScaling from 1 to 2 threads (wall clock, the median of paired ratios as in §1; then packets per CPU-second, 2 threads / 1 thread):\n"
    )
    sc, scaling = [], []
    for key in dict.fromkeys(k for k, _ in after):
        if (key, 1) in after and (key, 2) in after:
            r1, r2 = after[(key, 1)], after[(key, 2)]
            b = bt.get(key, {})
            before = f"{b['2']['pps'] / b['1']['pps']:.2f}×" if b.get("1") and b.get("2") else "–"
            scaling.append(scaling_of(r1, r2))
            sc.append([key, before, f"{_scaling_cell(r1, r2)}, per CPU-s {r2['pp_cpu_s'] / r1['pp_cpu_s']:.2f}"])
    a(md_table(["config", "before", "after"], sc))
    a("")
    sbs = R.get("side_by_side")
    if sbs:
        a(
            f"Side by side, measured by this run: the baseline package in `{sbs['before_py']}` and this engine, "
            "one process each, interleaved, best of 2 (`bench/side_by_side.py`):\n"
        )
        rows = [
            [
                r["config"],
                r["threads"],
                fmt_int(r["packets"]),
                f"{fmt_int(r['before'])} ({fmt_int(r['before_cpu'])})",
                f"{fmt_int(r['after'])} ({fmt_int(r['after_cpu'])})",
                f"{r['after'] / r['before']:.2f}×",
            ]
            for r in sbs["rows"]
        ]
        a(md_table(["config", "threads", "packets", "before /s (per CPU-s)", "after /s (per CPU-s)", "speed-up"], rows))
        a(
            "\nThe baseline traces every config without the lumen rule; the after engine traces `colon` and "
            "`colon+grids` with it (today's default) and `colon_lumen_off` without it, the like-for-like pair.\n"
        )
        L += _same_physics(sbs["rows"])
    L += _issue11_mcml(R)
    L += _issue11_instructions(R, B)
    L += _issue11_goals(R, B, after, scaling)
    return L


def _same_physics(rows):
    """Side by side: the like-for-like configs' answers, before against after, in standard errors.
    The engines' random streams differ (issue 11 changed the generator), so the runs are independent."""
    out = []
    for r in rows:
        b, f = r.get("before_physics"), r.get("after_physics")
        if not (b and f) or r["config"] not in LIKE_FOR_LIKE or r["threads"] != 1:
            continue
        cells = []
        for name, key in (("Rd", "rd"), ("absorbed", "absorbed"), ("fluorescent escaped", "fluorescent")):
            values = [d.get(k) for d in (b, f) for k in (key, key + "_se")]
            if not all(isinstance(v, (int, float)) and math.isfinite(v) for v in values):
                continue  # an engine that does not report it
            se = math.hypot(b[key + "_se"], f[key + "_se"])
            if not se > 0:
                continue
            z = (f[key] - b[key]) / se
            cells.append(
                [name, f"{b[key]:.5f} ± {b[key + '_se']:.5f}", f"{f[key]:.5f} ± {f[key + '_se']:.5f}", f"{z:+.2f}"]
            )
        out += [
            f"Same answer: `{r['config']}`, {fmt_int(r['packets'])} packets, seed 1, one run of each engine (their "
            "random streams differ, so the runs are independent; z = difference / combined standard error):\n",
            md_table(["fraction of the launched weight", "before", "after", "z"], cells),
            "",
        ]
    return out


def _issue11_mcml(R):
    """MCML run beside this engine by this run (bench/run_all.py --mcml-binary), if it was."""
    m = R.get("mcml_side_by_side")
    if not m:
        return []
    dz, dr, nz, nr, na = m["grid"]
    k = m["repeats"]
    rows = [
        [
            r["config"],
            fmt_int(r["packets"]),
            fmt_int(r["mcml_pp_cpu_s"]),
            fmt_int(r["engine_pp_cpu_s"]),
            f"{r['ratio']:.2f}×",
            f"{r['mcml_rd']:.5f} ± {r['mcml_rd_se']:.5f}",
            f"{r['engine_rd']:.5f} ± {r['engine_rd_se']:.5f}",
        ]
        for r in m["rows"]
    ]
    return [
        load_note(R, "issue11"),
        f"MCML side by side, measured by this run: `{m['binary']}` ({m['version'] or 'no version line'}; built "
        f"{m.get('build') or 'as not stated'}), outside the repository, on the input `bench/side_by_side.py` writes "
        f"(one layer, ambient n = 1 above and below, scoring grid dz = {dz:g} cm, dr = {dr:g} cm, {nz} × {nr} × {na} "
        "bins). MCML's CPU time is its whole process's (user + system: start-up and writing its output included); "
        "this engine's is the run's own (1 thread, fresh process, 2000-packet warm-up, scene build excluded); best "
        f"of {k} each, interleaved. MCML's Rd is the mean of its {k} runs (seeded by the clock) ± the standard error "
        "from their spread; the engine's is one run ± its standard error.\n",
        md_table(
            [
                "config",
                "packets",
                "MCML packets per CPU-s",
                "engine packets per CPU-s",
                "engine / MCML",
                "MCML Rd",
                "engine Rd",
            ],
            rows,
        ),
        "",
    ]


def _issue11_instructions(R, B):
    steps = {r["scene"]: r for r in (R.get("profile") or {}).get("steps", [])}
    if not steps:
        return ["Instructions: not measured in this run (`--sections profile`).\n"]
    tr = []
    for scene, b in B["instructions"].items():
        r = steps.get(scene)
        if r is None:
            continue
        tr.append(
            [
                scene,
                fmt_int(b["ir_packet"]),
                fmt_int(r["ir_packet"]),
                f"{r['ir_packet'] / b['ir_packet'] - 1:+.0%}",
                f"{fmt_int(b['ir_step'])} → {fmt_int(r['ir_step'])}"
                if "ir_step" in b
                else f"– → {fmt_int(r['ir_step'])}",
            ]
        )
    out = [
        f"Instructions (callgrind, §4; before: {B['provenance']['instructions']}):\n",
        md_table(["scene", "Ir/packet before", "Ir/packet after", "change", "Ir per interaction before → after"], tr),
        "",
    ]
    b, r = B["instructions"].get("seed_tissue"), steps.get("seed_tissue")
    if b and r and "parts" in b:
        parts = list(dict.fromkeys(list(b["parts"]) + list(r["parts"])))
        cell = lambda d, k: f"{d['parts'][k]:.0f}" if k in d["parts"] else "–"  # noqa: E731
        rows = [[k, cell(b, k), cell(r, k)] for k in parts]
        out += [
            "Seed tissue, Ir per interaction by part of the loop:\n",
            md_table(["part", "before", "after"], rows),
            "",
        ]
    return out


def _issue11_goals(R, B, after, scaling):
    g, mc = B["goals"], B["mcml"]
    out = ["**Goals of issue 11, as measured by this run:**\n"]
    seed1 = after.get(("seed_tissue", 1))
    if seed1:
        per_core = seed1["pp_cpu_s"]
        side = _mcml_seed_row(R)
        estimate = (
            f"{fmt_int(seed1['pps'])} packets/s ({fmt_int(per_core)} per CPU-second of the run) against the "
            f"issue's estimate of that goal, {fmt_int(g['seed_tissue_pps_1thread'])} packets/s (which assumed "
            f"MCML at 2.0–2.5e5 per core): {_goal(min(seed1['pps'], per_core) >= g['seed_tissue_pps_1thread'])}"
        )
        if side:
            # The goal itself is "2x MCML's per-core speed on this machine kind": measured here, it is judged here.
            out.append(
                f"1. Seed tissue, one core, at least 2× MCML's per-core speed: {side['ratio']:.2f}× MCML measured "
                f"side by side: {_goal(side['ratio'] >= 2)}. " + _mcml_per_core(R, mc, per_core) + f" §1: {estimate}."
            )
        else:
            out.append(f"1. Seed tissue, one core: {estimate}. " + _mcml_per_core(R, mc, per_core))
    out += _issue11_goal2(R, B, after)
    if scaling:
        worst = min(scaling)
        free = [
            scaling_of(after[(k, 1)], after[(k, 2)], "paired_scaling_steal_free")
            for k, t in after
            if t == 2 and (k, 1) in after and after[(k, 2)].get("paired_scaling_steal_free")
        ]
        out.append(
            f"3. Scaling 1 → 2 threads: lowest {worst:.2f}× over the bench scenes; goal ≥ {g['scaling_1_to_2']}×: "
            f"{_goal(worst >= g['scaling_1_to_2'])}"
            + (
                " (wall clock under load: see the packets per CPU-second ratios)."
                if load_note(R, "throughput")
                else "."
            )
            + (
                f" Recomputed less the hypervisor's steal met by each run (§1), the lowest is {min(free):.2f}×; the "
                "verdict stays with the wall clock."
                if free
                else ""
            )
        )
    rd = R.get("mcml_rd")
    if rd:
        z = (rd["rd"] - mc["rd"]) / rd["rd_se"]
        out.append(
            f"4. Accuracy: seed tissue, {fmt_int(rd['photons'])} packets, seed {rd['seed']}: Rd = {rd['rd']:.5f} ± "
            f"{rd['rd_se']:.5f} against MCML's {mc['rd']}: {z:+.2f} σ; goal within 3 σ: {_goal(abs(z) <= 3)}."
        )
    else:
        out.append("4. Accuracy: not measured in this run (`--sections issue11`).")
    return out + [""]


def _issue11_goal2(R, B, after):
    """Goal 2 (colon_polyp with fluorescence, 3x the baseline per core), judged like for like: the
    baseline had no lumen rule, so its physics is today's colon with lumen=False (LIKE_FOR_LIKE)."""
    g = B["goals"]["colon_speedup"]
    if "colon" not in B["throughput"]:
        return []
    before = B["throughput"]["colon"]["1"]["pps"]
    same, col1 = after.get(("colon_lumen_off", 1)), after.get(("colon", 1))
    out = []
    if same:
        text = (
            "2. `colon_polyp` with fluorescence, one thread, the baseline's physics (lumen rule off): "
            f"{fmt_int(same['pps'])} packets/s against {fmt_int(before)} before = {same['pps'] / before:.2f}×; goal "
            f"{g:g}×: {_goal(same['pps'] / before >= g)}."
        )
        rows = (R.get("side_by_side") or {}).get("rows", [])
        side = next((r for r in rows if r["config"] == "colon_lumen_off" and r["threads"] == 1), None)
        if side:
            text += (
                " Side by side with the baseline engine built and run by this run (table above): "
                f"{side['after'] / side['before']:.2f}× in packets/s, {side['after_cpu'] / side['before_cpu']:.2f}× "
                "in packets per CPU-second."
            )
        out.append(text)
    if col1:
        head = "   " if same else "2. `colon_polyp` with fluorescence, one thread. "
        out.append(
            f"{head}With the lumen rule on (today's default, §6: about 1.3× the interactions a packet, a ray query "
            f"for every exit, and landings all over the tube): {fmt_int(col1['pps'])} packets/s = "
            f"{col1['pps'] / before:.2f}× the baseline's figure, whose physics had no lumen rule"
            + ("." if same else f"; goal {g:g}×: {_goal(col1['pps'] / before >= g)}.")
        )
    return out


def _mcml_seed_row(R):
    """The seed-tissue row of the MCML side-by-side run (--mcml-binary), or None when MCML was not run."""
    return next((r for r in (R.get("mcml_side_by_side") or {}).get("rows", []) if r["config"] == "seed_tissue"), None)


def _mcml_per_core(R, mc, per_core):
    """Goal 1's MCML sentence: measured by this run (--mcml-binary) if it was, else issue 11's figures."""
    seed = _mcml_seed_row(R)
    if seed:
        return (
            f"MCML side by side, measured by this run (table above, {fmt_int(seed['packets'])} packets): MCML "
            f"{fmt_int(seed['mcml_pp_cpu_s'])} packets per CPU-second, this engine {fmt_int(seed['engine_pp_cpu_s'])} "
            f"in the same run, so this engine is {seed['ratio']:.2f}× MCML per core (the engine's CPU time excludes "
            "process start-up and scene build, MCML's includes them)."
        )
    lo, hi = mc["packets_per_cpu_s"]
    return (
        f"MCML side by side, quoted, not measured by this run (MCML's figures: `bench/baseline.json`, from issue 11, "
        f"whole-process CPU time, 1e6 packets): {fmt_int(lo)}–{fmt_int(hi)} packets per CPU-second, so this engine "
        f"is {per_core / hi:.2f}–{per_core / lo:.2f}× MCML per core (the engine's CPU time excludes process start-up "
        "and scene build, MCML's includes them). `bench/run_all.py --sections issue11 --mcml-binary PATH` measures "
        "MCML here, beside this engine."
    )


SECTIONS = (sec_machine, sec_throughput, sec_accuracy, sec_knobs, sec_profile, sec_presets, sec_lumen, sec_render)


@section("10. Mesh size: scene build and packets/s", "meshes")
def sec_mesh_size(R, figs):
    """§10: the engine scene's build time and packets/s as colon_polyp's tube is tessellated finer."""
    rows = R["mesh_size"]["rows"]
    r0 = rows[0]
    L = [
        "`bench/mesh_size.py` tessellates `bench/colon_scene.py`'s tube finer (rings along it × points around "
        "it; the polyp and the rig stay) and measures the engine scene's build on a fresh engine scene "
        "(`Scene.to_native()`: the mesh checks, Embree's BVH, the triangle grid and its per-triangle data), then "
        f"packets/s of a run of {fmt_int(r0['photons'])} packets at {r0['threads']} thread after a {fmt_int(2000)}-packet "
        "warm-up, and the per-cube cache store that run built.\n",
        md_table(
            ["tessellation", "triangles", "build, s", "packets/s", "cache store, MB"],
            [
                [
                    f"{r['n_x']} × {r['n_theta']}",
                    fmt_int(r["triangles"]),
                    f"{r['build_s']:.2f}",
                    fmt_int(r["pps"]),
                    f"{r['store_mb']:.0f}",
                ]
                for r in rows
            ],
        ),
        f"\nFrom {fmt_int(r0['triangles'])} to {fmt_int(rows[-1]['triangles'])} triangles "
        f"(×{rows[-1]['triangles'] / r0['triangles']:.0f}) the build takes ×{rows[-1]['build_s'] / r0['build_s']:.1f} "
        f"as long, and packets/s fall to {rows[-1]['pps'] / r0['pps']:.2f} of the first row's. The triangle grid has "
        "at most 128 cells a side (`native/triangle_grid.h`), so a finer mesh puts more and smaller triangles in "
        "each cube's ball, and a cube whose ball meets more than 16 triangles has no cache (its steps take the "
        "full ray query).\n",
    ]
    return L


def render_document(R, figs, baseline):
    """The whole of docs/performance.md for results ``R``, figures ``figs`` and the issue-11 ``baseline``."""
    lines = []
    for fn in SECTIONS:
        lines += fn(R, figs)
    lines += sec_dask(R, figs)
    lines += sec_issue11(R, figs, baseline)
    lines += sec_mesh_size(R, figs)
    return re.sub(r"\n{3,}", "\n\n", "\n".join(lines)).rstrip("\n") + "\n"
