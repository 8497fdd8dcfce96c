"""ENDOPHOTON_EMBREE_ISA (native/embree_device.h): Embree's kernels capped to an older processor's,
with the same answer; a value that names no instruction set is an error naming the variable and the
value, before any tracing. (test_isa_bits.py compares the bits across caps, builds and libm.)"""
import json
import os

from cli_helpers import EXAMPLES, ROOT, cli_env, run_cli

SEED = os.path.join(EXAMPLES, "seed_tissue.json")
COLON = os.path.join(ROOT, "bench", "scenes", "colon.json")  # the rig in the lumen: Embree's queries


def test_a_capped_embree_gives_the_same_result():
    results = []
    for extra in ({}, {"ENDOPHOTON_EMBREE_ISA": "sse2"}):
        out = run_cli("run", COLON, "--photons", "1000", "--threads", "2", env=cli_env(**extra))
        assert out.returncode == 0, out.stderr
        result = json.loads(out.stdout)
        del result["seconds"]  # the clock's, not the arithmetic's
        results.append(result)
    assert results[0] == results[1]


def test_an_unknown_instruction_set_is_a_named_error():
    out = run_cli("run", SEED, "--photons", "100", env=cli_env(ENDOPHOTON_EMBREE_ISA="avx9"))
    assert out.returncode != 0
    assert "ENDOPHOTON_EMBREE_ISA = 'avx9'" in out.stderr and "sse2" in out.stderr, out.stderr
    assert "Traceback" not in out.stderr, out.stderr
