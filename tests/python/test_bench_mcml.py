"""bench/side_by_side.py's MCML comparison (--mcml-binary) and its place in docs/performance.md §9.
MCML itself is not here: a stand-in executable that reads the .mci and writes an .mco's RAT block
checks the run-and-parse path; the .mci is held against the bench scenes it stands for. No timing."""
import os
import stat
import sys
import textwrap

import pytest

HERE = os.path.dirname(os.path.abspath(__file__))
BENCH = os.path.join(HERE, "..", "..", "bench")
sys.path.insert(0, BENCH)
import perf_doc as pd  # noqa: E402  (bench/ modules, not a package)
import side_by_side as sbs  # noqa: E402


def data_lines(mci):
    """The data of an .mci: each line's text before '#', blank lines dropped (MCML's own reading)."""
    return [line.split("#")[0].split() for line in mci.splitlines() if line.split("#")[0].strip()]


def test_mci_holds_the_bench_scenes_optics():
    """Each MCML_PLAN entry is the bench scene it names: same media, thickness and ambient n."""
    import colon_scene as cs

    for key, layers, _ in sbs.MCML_PLAN:
        scene, _src = {"seed_tissue": cs.seed_tissue_box, "mcml_slab": cs.mcml_slab}[key]()
        assert scene.unit == "cm" and scene.ambient_n == sbs.MCML_AMBIENT_N[0] == sbs.MCML_AMBIENT_N[1]
        assert len(scene.regions) == len(layers) == 1
        m, z = scene.regions[0].medium, scene.regions[0].vertices[:, 2]
        n, mua, mus, g, d = layers[0]
        assert (m.n, m.mua, m.mus, m.g) == (n, mua, mus, g), key
        assert float(z.max() - z.min()) == pytest.approx(d, rel=1e-6), key


def test_mci_text_is_mcml_input_order():
    layers = [(1.37, 1.0, 100.0, 0.9, 0.1), (1.4, 2.5, 10.0, 0.0, 0.2)]
    rows = data_lines(sbs.mci_text(layers, 12345, grid=(0.01, 0.02, 40, 50, 3), ambient_n=(1.0, 1.5)))
    assert rows == [
        ["1.0"],
        ["1"],
        [sbs.MCML_OUT, "A"],
        ["12345"],
        ["0.01", "0.02"],
        ["40", "50", "3"],
        ["2"],
        ["1"],
        ["1.37", "1", "100", "0.9", "0.1"],
        ["1.4", "2.5", "10", "0", "0.2"],
        ["1.5"],
    ]


MCO = textwrap.dedent(
    """\
    A1 \t# Version number of the file format.

    InParm \t\t\t# Input parameters. cm is used.
    ep-bench.mco \tA\t\t# output file name, ASCII.

    RAT #Reflectance, absorption, transmission. 
    0.00226757     \t#Specular reflectance [-]
    0.0615011      \t#Diffuse reflectance [-]
    0.936231       \t#Absorbed fraction [-]
    0              \t#Transmittance [-]

    A_l #Absorption as a function of layer. [-]
    """
)


def test_parse_mco_reads_the_rat_block():
    assert sbs.parse_mco(MCO) == dict(rsp=0.00226757, rd=0.0615011, a=0.936231, tt=0.0)
    with pytest.raises(ValueError, match="no RAT block"):
        sbs.parse_mco(MCO.split("RAT")[0])


def test_run_mcml_runs_a_binary_on_the_mci_and_reads_its_output(tmp_path):
    """A stand-in 'MCML' checks the input it is given (its photon count and layer line) and answers."""
    fake = tmp_path / "fake-mcml"
    fake.write_text(
        f"#!{sys.executable}\n"
        "import sys\n"
        "rows = [l.split('#')[0].split() for l in open(sys.argv[1]) if l.split('#')[0].strip()]\n"
        "assert rows[3] == ['777'] and rows[8] == ['1.1', '20', '200', '0.9', '10'], rows\n"
        "print('   Version 9.9, test   ')\n"
        f"open(rows[2][0], 'w').write({MCO!r})\n"
    )
    fake.chmod(fake.stat().st_mode | stat.S_IXUSR)
    r = sbs.run_mcml(str(fake), sbs.MCML_PLAN[0][1], 777)
    assert (r["rd"], r["tt"], r["version"]) == (0.0615011, 0.0, "Version 9.9, test")
    assert r["cpu_s"] == pytest.approx(r["user_s"] + r["sys_s"]) and r["cpu_s"] >= 0
    fake.write_text("#!/bin/sh\nexit 3\n")
    with pytest.raises(RuntimeError, match="exit 3"):
        sbs.run_mcml(str(fake), sbs.MCML_PLAN[0][1], 777)


def test_mcml_row_takes_the_best_of_each_and_their_ratio():
    mc = [dict(cpu_s=c, user_s=c, rd=rd, tt=0.0) for c, rd in ((5.0, 0.0614), (4.0, 0.0616), (4.5, 0.0615))]
    en = [dict(pp_cpu_s=p, pps=p * 0.9, rd=0.0615, rd_se=0.0002) for p in (190_000.0, 210_000.0)]
    r = sbs.mcml_row("seed_tissue", 1_000_000, mc, en)
    assert r["mcml_cpu_s"] == 4.0 and r["mcml_pp_cpu_s"] == 250_000.0 and r["engine_pp_cpu_s"] == 210_000.0
    assert r["ratio"] == pytest.approx(210_000 / 250_000)
    assert r["mcml_rd"] == pytest.approx(0.0615) and r["mcml_rd_se"] == pytest.approx(0.0001 / 3**0.5)


def test_section_9_uses_the_measured_mcml_or_says_it_quotes_the_issue():
    import json

    with open(os.path.join(HERE, "data", "perf_results_quick.json"), encoding="utf-8") as fh:
        R = json.load(fh)
    with open(os.path.join(BENCH, "baseline.json"), encoding="utf-8") as fh:
        B = json.load(fh)
    R.pop("mcml_side_by_side", None)
    text = "\n".join(pd.sec_issue11(R, {}, B))
    assert "quoted, not measured by this run" in text and "--mcml-binary PATH" in text
    assert "MCML's figures there (quoted from issue 11)" in "\n".join(pd.sec_machine(R, {}))
    mc = [dict(cpu_s=4.0, user_s=4.0, rd=0.0615, tt=0.0), dict(cpu_s=5.0, user_s=5.0, rd=0.0617, tt=0.0)]
    en = [dict(pp_cpu_s=300_000.0, pps=290_000.0, rd=0.0616, rd_se=0.0002)]
    row = sbs.mcml_row("seed_tissue", 1_000_000, mc, en)
    R["mcml_side_by_side"] = dict(binary="/x/mcml", version="Version 1.2, 1993", grid=[0.1, 0.1, 10, 10, 1])
    R["mcml_side_by_side"].update(repeats=2, rows=[row], build="gcc -O3")
    text = "\n".join(pd.sec_issue11(R, {}, B))
    assert "quoted, not measured" not in text and "`/x/mcml` (Version 1.2, 1993; built gcc -O3)" in text
    assert "| seed_tissue | 1 000 000 | 250 000 | 300 000 | 1.20× | 0.06160 ± 0.00010 | 0.06160 ± 0.00020 |" in text
    assert "this engine is 1.20× MCML per core" in text
    head = "\n".join(pd.sec_machine(R, {}))
    assert "quoted from issue 11" not in head and "MCML itself was run beside this engine" in head
