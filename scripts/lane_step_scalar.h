// What scripts/lane_step_bench.cpp (4 double lanes, §18 of docs/performance.md) and
// scripts/lane_step_f32_bench.cpp (8 float32 lanes, §28) share: the medium, the engine's scalar interior
// step they are measured against, and xoshiro in lanes. Throwaway measurement, not part of the build.
#pragma once

#include <immintrin.h>

#include <algorithm>
#include <cstdint>

#include "fast_log.h"
#include "phase.h"
#include "rng.h"
#include "vecmath.h"

namespace lane_bench {

using namespace ep;

// The medium: the seed tissue (examples/seed_tissue.json: mua 20, mus 200 per cm, g 0.9, n 1.1) unless a
// bench's command line names another (set_medium).
inline double kMua = 20, kMus = 200, kG = 0.9, kN = 1.1;
inline double kLoss = kMua / (kMua + kMus), kMutCm = kMua + kMus;
inline void set_medium(double mua, double mus, double g, double n) {
    kMua = mua, kMus = mus, kG = g, kN = n;
    kLoss = kMua / (kMua + kMus), kMutCm = kMua + kMus;
}
constexpr double kSlack = 1e-13, kRefill = 1e-4;  // W below kRefill starts again at 1 (every path alike)

// One packet of the scalar step.
struct Scalar {
    Rng rng{0, 0};
    Lanes4 p{};
    DirectionFrame frame;
    double W = 1, tau = 0, absorbed = 0, depth = 0, budget = 1e300;
    uint32_t scatterings = 0;
};

// The engine's interior step (transport.cpp's zone_steps for a plain run), with its own inline functions.
inline void scalar_step(Scalar& q, const HenyeyGreenstein& hg, const Vec3& entry_p, const Vec3& entry_in) {
    const double s = q.tau / kMutCm;
    const Lanes4 b = q.p + q.frame.n * s;
    const double left = q.budget - (s + kSlack);
    q.budget = left > 0 ? left : 1e300;  // renew() stands in: a fresh budget
    q.p = b;
    q.depth = std::max(q.depth, dot(to_vec3(q.p) - entry_p, entry_in));
    const double dW = q.W * kLoss;
    q.W -= dW;
    q.absorbed += dW;
    if (q.W < kRefill) q.W = 1;
    hg.scatter(q.rng.next_u64(), ++q.scatterings, &q.frame);
    q.tau = neg_log_lattice(q.rng.lattice_open_low());
}

// Packet `packet` at its start: the engine's stream (seed 1), a fixed direction, its first free path.
inline Scalar start(uint64_t packet) {
    Scalar q;
    q.rng = Rng(1, packet);
    q.frame = DirectionFrame(normalize(Vec3(0.3, -0.2, -1)));
    q.tau = neg_log_lattice(q.rng.lattice_open_low());
    return q;
}

// xoshiro256++ (64-bit lanes: kBits 64, rotations 23 and 45, shift 17) and xoshiro128++ (32-bit lanes: 32,
// 7, 11, 9) in the lanes of an AVX2 register (Blackman & Vigna 2021, ACM TOMS 47:36): one output a lane.
template <int kBits, int kOutRot, int kShift, int kRot>
inline __m256i xoshiro_next(__m256i& s0, __m256i& s1, __m256i& s2, __m256i& s3) {
    static_assert(kBits == 32 || kBits == 64, "32- or 64-bit lanes");
    auto add = [](__m256i a, __m256i b) { return kBits == 64 ? _mm256_add_epi64(a, b) : _mm256_add_epi32(a, b); };
    auto shl = [](__m256i a, int k) { return kBits == 64 ? _mm256_slli_epi64(a, k) : _mm256_slli_epi32(a, k); };
    auto shr = [](__m256i a, int k) { return kBits == 64 ? _mm256_srli_epi64(a, k) : _mm256_srli_epi32(a, k); };
    auto rotl = [&](__m256i x, int k) { return _mm256_or_si256(shl(x, k), shr(x, kBits - k)); };
    const __m256i out = add(rotl(add(s0, s3), kOutRot), s0);
    const __m256i t = shl(s1, kShift);
    s2 = _mm256_xor_si256(s2, s0);
    s3 = _mm256_xor_si256(s3, s1);
    s1 = _mm256_xor_si256(s1, s2);
    s0 = _mm256_xor_si256(s0, s3);
    s2 = _mm256_xor_si256(s2, t);
    s3 = rotl(s3, kRot);
    return out;
}

}  // namespace lane_bench
