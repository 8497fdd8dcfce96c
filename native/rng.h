// Counter-based random numbers: every packet owns a stream keyed by
// (seed, packet index), so a packet's random numbers do not depend on which
// thread traces it or in which order (MCX/MMC practice). The output for draw k
// is a keyed hash of the counter k; there is no state to share between packets.
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
    // the streams of two packets collide only if both keys collide (2^-128),
    // unlike a single Weyl sequence whose windows can overlap.
    Rng(uint64_t seed, uint64_t stream) {
        k0_ = mix64(seed ^ 0x243F6A8885A308D3ULL) ^ mix64(stream + 0x9E3779B97F4A7C15ULL);
        k1_ = mix64(k0_ + 0x13198A2E03707344ULL) ^ mix64(seed * 0xD1B54A32D192ED03ULL + stream);
    }
    uint64_t next_u64() {
        const uint64_t c = counter_++;
        return mix64(mix64(c * 0x9E3779B97F4A7C15ULL + k0_) ^ k1_);
    }
    // Uniform in [0, 1) with 53 random bits.
    double uniform() { return double(next_u64() >> 11) * 0x1.0p-53; }
    // Uniform in (0, 1]: safe for -log(u) (eq. 2 of the seed) without a branch.
    double uniform_open_low() { return double((next_u64() >> 11) + 1) * 0x1.0p-53; }
    uint64_t draws() const { return counter_; }

  private:
    uint64_t k0_ = 0, k1_ = 0, counter_ = 0;
};

}  // namespace ep
