// What scripts/lane_step_bench.cpp (4 double lanes, §18 of docs/performance.md),
// scripts/lane_step_f32_bench.cpp (8 float32 lanes, §28) and scripts/lane_step_vext_bench.cpp (any width) share: the
// medium, the engine's scalar interior step they are measured against, xoshiro in lanes, and the rules and bookkeeping
// of their whole seed-tissue runs. Throwaway measurement, not part of the build.
#pragma once

#include <immintrin.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>

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

// ---- the seed tissue run of the lane benches (their `seed` mode) ----
// MCML's rules: specular loss at entry, Fresnel's all-or-none choice at the surface, roulette at 1e-4 with
// survival 1/10. The clearance budget stands in for the engine's (ClearSteps): a lane's zone is the ball of
// radius one cube side about its cube's centre, as the engine's triangle caches have it (the seed tissue's
// box of 12 triangles: a grid of 7^3 cells of 10/7 cm, split 3 ways: cubes of 0.476 cm).
constexpr double kRoulette = 1e-4, kSurvive = 0.1;
constexpr float kSide = float(10.0 / 7 / 3), kInner = kSide * (1 - 1e-6f), kLo = 1e-6f;

// The centre of the cube holding coordinate v, the grid starting at lo (the box's corner (-5, -5, 0), depth
// z >= 0).
inline float cube_centre(float v, float lo) { return lo + (std::floor((v - lo) / kSide) + 0.5f) * kSide; }

// Unpolarised Fresnel reflectance from the medium (n = kN) into air at incidence cosine ci (MCML's RFresnel).
inline double fresnel_out(double ci) {
    const double si = std::sqrt(std::max(0.0, 1 - ci * ci)), st = kN * si;
    if (st >= 1) return 1;
    const double ct = std::sqrt(1 - st * st);
    const double rs = (kN * ci - ct) / (kN * ci + ct), rp = (ci - kN * ct) / (ci + kN * ct);
    return 0.5 * (rs * rs + rp * rp);
}
inline double specular() { return (kN - 1) * (kN - 1) / ((kN + 1) * (kN + 1)); }

// The xoshiro128++ state of packet `packet`'s stream: 128 bits of the engine's keyed generator for (seed,
// packet), the last word made odd (never the all-zero state).
inline void stream_state(uint64_t seed, uint64_t packet, uint32_t s[4]) {
    Rng seeder(seed, packet);
    const uint64_t a = seeder.next_u64(), b = seeder.next_u64();
    s[0] = uint32_t(a), s[1] = uint32_t(a >> 32), s[2] = uint32_t(b), s[3] = uint32_t(b >> 32) | 1;
}
// One xoshiro128++ draw of a single lane's state (the same sequence as the lanes' own).
inline uint32_t xoshiro128_next(uint32_t& s0, uint32_t& s1, uint32_t& s2, uint32_t& s3) {
    const uint32_t r = ((s0 + s3) << 7 | (s0 + s3) >> 25) + s0, t = s1 << 9;
    s2 ^= s0, s3 ^= s1, s1 ^= s2, s0 ^= s3, s2 ^= t, s3 = s3 << 11 | s3 >> 21;
    return r;
}

struct SeedRun {
    double rd = 0, rd2 = 0, absorbed = 0;  // sums over packets (rd2: of squares, for the standard error)
    uint64_t seed = 1;
    long launched = 0, packets = 0, iterations = 0, renewals = 0, lanes_renewed = 0, hops = 0, tests = 0;
};

// Lane k of `P` moves its zone to the cube it is in. P: any lanes whose fields (px ... cz) index by lane.
template <class Lanes>
inline void hop_lane(Lanes& P, int k) {
    P.cx[k] = cube_centre(P.px[k], -5.f), P.cy[k] = cube_centre(P.py[k], -5.f), P.cz[k] = cube_centre(P.pz[k], 0.f);
}

// Lane k of `P` takes the next packet of `run` (or idles, weight 0, when all are launched): at the origin
// heading into the tissue, weight 1 - Rsp, a fresh stream; its first free path is drawn by the lanes' next.
// The lane's packet's sums (`absorbed`, `rd`: indexed by lane) go to the run first.
template <class Lanes, class Sums>
void refill_lane(Lanes& P, int k, SeedRun& run, Sums& absorbed, Sums& rd) {
    run.absorbed += absorbed[k];
    run.rd += rd[k], run.rd2 += double(rd[k]) * rd[k];
    absorbed[k] = rd[k] = 0;
    const bool idle = run.launched == run.packets;
    uint32_t st[4];
    stream_state(run.seed, uint64_t(run.launched), st);
    P.s0[k] = st[0], P.s1[k] = st[1], P.s2[k] = st[2], P.s3[k] = st[3], P.count[k] = 0;
    P.px[k] = P.py[k] = P.pz[k] = 0;
    P.tx[k] = 1, P.ty[k] = 0, P.tz[k] = 0, P.bx[k] = 0, P.by[k] = 1, P.bz[k] = 0, P.nx[k] = 0, P.ny[k] = 0;
    P.nz[k] = 1;  // z > 0 is the tissue
    P.w[k] = idle ? 0.f : float(1 - specular());
    hop_lane(P, k);
    P.budget[k] = 0;  // at the surface: the first step renews
    if (!idle) run.launched += 1;
}

// Prints a seed run: packets per CPU-s, Rd with its standard error, A, the energy balance, and how often the
// lanes left their straight path.
inline void print_seed_run(const SeedRun& r, double cpu_s, int lanes) {
    const double n = double(r.packets), rd = r.rd / n, se = std::sqrt((r.rd2 / n - rd * rd) / n);
    std::printf(
        "seed      %ld packets  %.3f CPU-s  %.0f packets per CPU-s  Rd %.6f +- %.6f  A %.6f  Rsp + Rd + A %.6f\n",
        r.packets, cpu_s, n / cpu_s, rd, se, r.absorbed / n, specular() + rd + r.absorbed / n);
    const double it = double(r.iterations);
    std::printf(
        "          %.2f iterations a packet; renewals in %.1f %% of iterations, %.1f %% of lane-steps; "
        "hops %.3f, surface tests %.3f a packet\n",
        it / n, 100 * r.renewals / it, 100 * r.lanes_renewed / (lanes * it), r.hops / n, r.tests / n);
}

}  // namespace lane_bench
