// Random numbers keyed by (seed, packet index): every packet owns a stream, so
// its random numbers do not depend on which thread traces it or in which order
// (MCX/MMC practice). The key is hashed once per packet (a keyed SplitMix64
// counter) into the 256-bit state of a xoshiro256++ generator, which then
// draws at a few instructions per number.
#pragma once
#include <cmath>
#include <cstdint>

namespace ep {

// SplitMix64 finaliser (Steele, Lea & Flood 2014): a bijective 64-bit mixer
// with full avalanche.
inline uint64_t mix64(uint64_t z) {
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ULL;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBULL;
    return z ^ (z >> 31);
}

class Rng {
  public:
    // Two 64-bit keys from (seed, stream). Two rounds with independent keys make
    // the streams of two packets collide only if both keys collide (2^-128).
    // The xoshiro state is the keyed hash of the counters 0..3: four distinct
    // outputs of a bijection of distinct inputs, so never the all-zero state
    // xoshiro must avoid, and uncorrelated between neighbouring packet indices
    // (Vigna's advice: seed xoshiro through SplitMix64, never with raw keys).
    Rng(uint64_t seed, uint64_t stream) {
        const uint64_t k0 = mix64(seed ^ 0x243F6A8885A308D3ULL) ^ mix64(stream + 0x9E3779B97F4A7C15ULL);
        const uint64_t k1 = mix64(k0 + 0x13198A2E03707344ULL) ^ mix64(seed * 0xD1B54A32D192ED03ULL + stream);
        for (uint64_t c = 0; c < 4; ++c) s_[c] = mix64(mix64(c * 0x9E3779B97F4A7C15ULL + k0) ^ k1);
    }
    // xoshiro256++ 1.0 (Blackman & Vigna 2021, "Scrambled linear pseudorandom
    // number generators", ACM TOMS 47:36): period 2^256 - 1, passes BigCrush
    // and PractRand in all bits. A packet draws a few hundred numbers from a
    // random start in that period, so two streams overlap with probability
    // about (packets * draws)^2 / 2^256, i.e. never.
    uint64_t next_u64() {
        const uint64_t out = rotl(s_[0] + s_[3], 23) + s_[0];
        const uint64_t t = s_[1] << 17;
        s_[2] ^= s_[0];
        s_[3] ^= s_[1];
        s_[1] ^= s_[2];
        s_[0] ^= s_[3];
        s_[2] ^= t;
        s_[3] = rotl(s_[3], 45);
        return out;
    }
    // Uniform in [0, 1) with 53 random bits (the top ones: the best in any
    // linear generator).
    double uniform() { return double(next_u64() >> 11) * 0x1.0p-53; }
    // Uniform in (0, 1]: safe for -log(u) (eq. 2 of the seed) without a branch.
    double uniform_open_low() { return double(lattice_open_low()) * 0x1.0p-53; }
    // The same draw as the integer m in [1, 2^53] of u = m 2^-53
    // (neg_log_lattice takes it).
    uint64_t lattice_open_low() { return (next_u64() >> 11) + 1; }

  private:
    static uint64_t rotl(uint64_t x, int k) { return (x << k) | (x >> (64 - k)); }
    uint64_t s_[4];
};

}  // namespace ep
