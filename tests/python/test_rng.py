"""The engine's random numbers (native/rng.h) against an independent pure-Python
implementation of their definition: the keyed SplitMix64 hash of (seed, packet
index) seeds a xoshiro256++ state (Blackman & Vigna 2021), whose top 53 bits
give a uniform in [0, 1). The engine's draws are read through
_core._testing.sample_hg_cos with g = 0, which returns 2u - 1 (exact in double
for a 53-bit u). Statistical tests of the generator are in tests/cpp/test_rng.cpp.
"""
import numpy as np
import pytest

from endophoton import _core

M = (1 << 64) - 1


def _mix64(z):
    """SplitMix64 finaliser (Steele, Lea & Flood 2014)."""
    z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & M
    z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & M
    return z ^ (z >> 31)


def _rotl(x, k):
    return ((x << k) | (x >> (64 - k))) & M


def _uniforms(seed, stream, n):
    """n uniforms of the packet stream (seed, stream), from the published definitions."""
    k0 = _mix64(seed ^ 0x243F6A8885A308D3) ^ _mix64((stream + 0x9E3779B97F4A7C15) & M)
    k1 = _mix64((k0 + 0x13198A2E03707344) & M) ^ _mix64((seed * 0xD1B54A32D192ED03 + stream) & M)
    s = [_mix64(_mix64((c * 0x9E3779B97F4A7C15 + k0) & M) ^ k1) for c in range(4)]
    out = []
    for _ in range(n):
        r = (_rotl((s[0] + s[3]) & M, 23) + s[0]) & M
        t = (s[1] << 17) & M
        s[2] ^= s[0]
        s[3] ^= s[1]
        s[1] ^= s[2]
        s[0] ^= s[3]
        s[2] ^= t
        s[3] = _rotl(s[3], 45)
        out.append((r >> 11) * 2.0**-53)
    return np.array(out)


@pytest.mark.parametrize("seed", [0, 1, 12345, 2**63 + 7])
def test_engine_draws_equal_the_published_xoshiro256pp_seeded_by_splitmix(seed):
    n = 300
    engine = (np.asarray(_core._testing.sample_hg_cos(0.0, n, seed)) + 1.0) / 2.0
    want = _uniforms(seed, 0, n)
    assert np.array_equal(engine, want), np.flatnonzero(engine != want)[:5]
