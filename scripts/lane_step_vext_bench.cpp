// Issue 39, §28 of docs/performance.md continued: the float32 lane step of scripts/lane_step_f32_bench.cpp
// written once with GCC's vector extensions, for any lane count, instead of AVX2 intrinsics. The lane engine
// must give the same bits on every x86-64 machine (docs/distributed.md, "Any instruction set"), so it needs
// one source that compiles to 4 lanes of SSE2 on an old machine, 8 of AVX2 here and 16 of AVX-512 where that
// pays. This times one step at 4, 8 or 16 lanes (a lane count wider than the build's registers is slow), and
// prints a digest of every packet's state after the steps: the digest must be the same in every build and at
// every lane count. Since the lanes went into the engine (§29) it takes the engine's lane helpers
// (native/lane_kernel.h) and keeps its own packets, step and seed run. Throwaway measurement, not part of the
// build; with
// FLAGS="-O3 -ffp-contract=off -Wno-psabi -std=c++17 -Inative":
//   g++ $FLAGS -mavx2 scripts/lane_step_vext_bench.cpp -o /tmp/vext_avx2
//   g++ $FLAGS -march=x86-64 scripts/lane_step_vext_bench.cpp -o /tmp/vext_sse2
//   g++ $FLAGS -mavx512f -mavx512vl -mavx512dq -mprefer-vector-width=512 -o /tmp/vext_avx512
//       scripts/lane_step_vext_bench.cpp
//   /tmp/vext_avx2 [steps] [4|8|16|scalar]
//   /tmp/vext_avx2 [packets] seed [4|8|16] [seed]   (the seed tissue, whole, as lane_step_f32_bench.cpp's seed mode)
#include <immintrin.h>

#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <ctime>
#include <string>

#include "lane_kernel.h"
#include "lane_step_scalar.h"

using namespace lane_bench;

namespace {

// The engine's lane helpers (native/lane_kernel.h): the types, xoshiro128++, -ln u, the azimuth, the
// square root, the mask test and the frame's renormalisation, so that this bench times the engine's code.
template <int W>
struct V {
    using f = typename LaneTypes<W>::F;
    using u = typename LaneTypes<W>::U;
    using i = typename LaneTypes<W>::I;
};

// W packets, one a lane: xoshiro128++ state, position, frame, weight, free path, absorbed weight, depth,
// clearance budget, scatterings.
template <int W>
struct Packets {
    using F = typename V<W>::f;
    using U = typename V<W>::u;
    U s0, s1, s2, s3, count;
    F px, py, pz, tx, ty, tz, bx, by, bz, nx, ny, nz, w, tau, absorbed, depth, budget;
    F cx, cy, cz;  // the centre of the lane's zone (mode seed)
};

template <int W>
inline typename V<W>::u next_u32(Packets<W>& P) {
    return lane_next(P.s0, P.s1, P.s2, P.s3);
}
template <class F>
inline F splat(float x) {
    return lane_splat<F>(x);
}
template <class M>
inline bool any(M m) {
    return lane_bits(m) != 0;
}
template <int W>
inline typename V<W>::f neg_log_u24(typename V<W>::u x) {
    return lane_neg_log<W>(x);
}
// The scattering of every lane: the HG cosine (MCML's form, one division), the azimuth, the frame's turn
// and, every 16th scattering, its renormalisation.
template <int W>
inline void scatter(Packets<W>& P, const float hgc[4]) {
    using F = typename V<W>::f;
    using I = typename V<W>::i;
    const F u = __builtin_convertvector(I(next_u32(P) >> 8), F) * 0x1.0p-24f;
    const F sq = hgc[0] / (hgc[1] + u * hgc[2]);
    const F ct = lane_max(lane_min((hgc[3] - sq * sq) * (1.0f / hgc[2]), splat<F>(1.0f)), splat<F>(-1.0f));
    const F st = lane_sqrt((1.0f - ct) * (1.0f + ct));
    F cp, sp;
    lane_azimuth<W>(next_u32(P), &cp, &sp);
    const F e1x = P.tx * cp + P.bx * sp, e1y = P.ty * cp + P.by * sp, e1z = P.tz * cp + P.bz * sp;
    P.bx = P.bx * cp - P.tx * sp;
    P.by = P.by * cp - P.ty * sp;
    P.bz = P.bz * cp - P.tz * sp;
    P.tx = e1x * ct - P.nx * st;
    P.ty = e1y * ct - P.ny * st;
    P.tz = e1z * ct - P.nz * st;
    P.nx = P.nx * ct + e1x * st;
    P.ny = P.ny * ct + e1y * st;
    P.nz = P.nz * ct + e1z * st;
    P.count += 1;
    const I due = I((P.count & (DirectionFrame::kRenormalizeEvery - 1)) == 0);
    if (__builtin_expect(any(due), 0)) lane_renormalize<W>(P, due);
}

// One step of every lane: §28's float32 step (the HG form of MCML; one division).
template <int W>
inline void step(Packets<W>& P, const float hgc[4]) {
    using F = typename V<W>::f;
    const F s = P.tau * float(1 / kMutCm);
    P.px += P.nx * s;
    P.py += P.ny * s;
    P.pz += P.nz * s;
    const F left = P.budget - (s + float(kSlack));
    P.budget = left > 0.0f ? left : splat<F>(1e30f);
    P.depth = lane_max(-P.pz, P.depth);  // the entry (0, 0, 0) facing -z
    const F dw = P.w * float(kLoss);
    P.w -= dw;
    P.absorbed += dw;
    P.w = P.w < float(kRefill) ? splat<F>(1.0f) : P.w;
    scatter<W>(P, hgc);
    P.tau = neg_log_u24<W>(next_u32(P));
}

constexpr int kPackets = 16;  // every lane count traces the same 16 packets

// Lanes [first, first + W) of the 16 packets: each stream from (seed 1, packet index), as in §28's bench.
template <int W>
Packets<W> start(int first) {
    Packets<W> P;
    std::memset(&P, 0, sizeof P);
    const DirectionFrame f(normalize(Vec3(0.3, -0.2, -1)));
    for (int k = 0; k < W; ++k) {
        uint32_t st[4];
        stream_state(1, uint64_t(first + k), st);
        P.s0[k] = st[0], P.s1[k] = st[1], P.s2[k] = st[2], P.s3[k] = st[3];
        P.tx[k] = float(f.t[0]), P.ty[k] = float(f.t[1]), P.tz[k] = float(f.t[2]);
        P.bx[k] = float(f.b[0]), P.by[k] = float(f.b[1]), P.bz[k] = float(f.b[2]);
        P.nx[k] = float(f.n[0]), P.ny[k] = float(f.n[1]), P.nz[k] = float(f.n[2]);
        P.w[k] = 1, P.budget[k] = 1e30f;
    }
    P.tau = neg_log_u24<W>(next_u32(P));
    return P;
}

// FNV-1a over packet k's state (lane k of P), the fields in a fixed order.
template <int W>
void digest_lane(const Packets<W>& P, int k, uint64_t& h) {
    const float f[] = {P.px[k], P.py[k], P.pz[k], P.tx[k], P.ty[k],       P.tz[k],    P.bx[k],     P.by[k], P.bz[k],
                       P.nx[k], P.ny[k], P.nz[k], P.w[k],  P.absorbed[k], P.depth[k], P.budget[k], P.tau[k]};
    const uint32_t u[] = {P.s0[k], P.s1[k], P.s2[k], P.s3[k], P.count[k]};
    auto feed = [&](const void* p, size_t n) {
        for (size_t b = 0; b < n; ++b) h = (h ^ static_cast<const unsigned char*>(p)[b]) * 0x100000001B3ull;
    };
    feed(f, sizeof f);
    feed(u, sizeof u);
}

double thread_ns() {
    timespec t;
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t);
    return 1e9 * double(t.tv_sec) + double(t.tv_nsec);
}

// The 16 packets as 16 / W groups of W lanes, `steps` steps each; prints ns per packet step and the digest.
template <int W>
void run(long steps, const float hgc[4]) {
    Packets<W> P[kPackets / W];
    for (int g = 0; g < kPackets / W; ++g) P[g] = start<W>(g * W);
    const double t0 = thread_ns();
    for (long n = 0; n < steps; ++n)
        for (auto& p : P) step<W>(p, hgc);
    const double t = thread_ns() - t0;
    uint64_t h = 0xCBF29CE484222325ull;
    for (int k = 0; k < kPackets; ++k) digest_lane<W>(P[k / W], k % W, h);
    std::printf("%2d lanes  %.3f ns/packet-step  digest %016llx\n", W, t / (double(steps) * kPackets),
                (unsigned long long)h);
}

// ---- the seed tissue, whole (mode seed): scripts/lane_step_f32_bench.cpp's seed run at any lane count ----
// The lanes' budgets at their points: min(the ball's inner radius less the distance to the centre, the depth
// less the surface's allowance).
template <int W>
inline typename V<W>::f fresh_budget(const Packets<W>& P) {
    const auto dx = P.px - P.cx, dy = P.py - P.cy, dz = P.pz - P.cz;
    return lane_min(kInner - lane_sqrt(lane_dot(dx, dy, dz, dx, dy, dz)), P.pz - kLo);
}
template <int W>
__attribute__((noinline)) void surface(Packets<W>& lanes, typename V<W>::i out, typename V<W>::f& rd_lanes) {
    Packets<W> P = lanes;
    auto rd = rd_lanes;
    for (int k = 0; k < W; ++k) {
        if (!out[k]) continue;
        if (double(xoshiro128_next(P.s0[k], P.s1[k], P.s2[k], P.s3[k])) * 0x1.0p-32 < fresnel_out(-double(P.nz[k]))) {
            P.pz[k] = -P.pz[k], P.nz[k] = -P.nz[k], P.tz[k] = -P.tz[k], P.bz[k] = -P.bz[k];
            P.budget[k] = 0;
        } else {
            rd[k] += P.w[k];
            P.w[k] = 0;
        }
    }
    lanes = P, rd_lanes = rd;
}
// Lanes under the roulette's threshold: survival, or a new packet.
template <int W>
__attribute__((noinline)) void roulette(Packets<W>& lanes, typename V<W>::i low, SeedRun& run,
                                        typename V<W>::f& absorbed_lanes, typename V<W>::f& rd_lanes) {
    Packets<W> P = lanes;
    auto absorbed = absorbed_lanes, rd = rd_lanes;
    for (int k = 0; k < W; ++k) {
        if (!low[k]) continue;
        if (P.w[k] > 0 && double(xoshiro128_next(P.s0[k], P.s1[k], P.s2[k], P.s3[k])) * 0x1.0p-32 < kSurvive)
            P.w[k] = float(P.w[k] / kSurvive);
        else
            refill_lane(P, k, run, absorbed, rd);
    }
    lanes = P, absorbed_lanes = absorbed, rd_lanes = rd;
}

template <int W>
SeedRun seed_run(long packets, uint64_t seed, const float hgc[4]) {
    using F = typename V<W>::f;
    using I = typename V<W>::i;
    SeedRun run;
    run.seed = seed, run.packets = packets;
    Packets<W> P;
    std::memset(&P, 0, sizeof P);
    F absorbed{}, rd{};     // this packet's captures and escapes, per lane
    I renewed{}, tested{};  // lanes renewed, lanes that tested the surface (counts per lane)
    for (int k = 0; k < W; ++k) refill_lane(P, k, run, absorbed, rd);
    P.tau = neg_log_u24<W>(next_u32(P));
    for (;; ++run.iterations) {
        const F s = P.tau * float(1 / kMutCm);
        P.px += P.nx * s, P.py += P.ny * s, P.pz += P.nz * s;
        P.budget -= s + float(kSlack);
        const I spent = P.budget <= 0.0f;
        if (any(spent)) {  // renew the lanes whose budget ran out
            ++run.renewals;
            renewed -= spent;  // a true lane is -1
            P.budget = spent ? fresh_budget(P) : P.budget;
            const I gone = spent & (P.budget <= 0.0f);
            tested -= gone;
            const I moved = gone & (P.pz >= kLo);  // out of the ball, not past the surface: a hop (scalar)
            if (any(moved)) {
                for (int k = 0; k < W; ++k)
                    if (moved[k]) ++run.hops, hop_lane(P, k);
                P.budget = gone ? fresh_budget(P) : P.budget;
            }
            const I out = gone & (P.pz < 0.0f);
            if (any(out)) surface(P, out, rd);
        }
        const F dw = P.w * float(kLoss);
        P.w -= dw;
        absorbed += dw;
        scatter<W>(P, hgc);
        const I low = P.w < float(kRoulette);
        if (any(low)) {  // the roulette, and new packets in the lanes whose packet ended
            roulette(P, low, run, absorbed, rd);
            if (!any(P.w > 0.0f) && run.launched == run.packets) break;
        }
        P.tau = neg_log_u24<W>(next_u32(P));
    }
    for (int k = 0; k < W; ++k) {  // flush the last packets
        refill_lane(P, k, run, absorbed, rd);
        run.lanes_renewed += renewed[k], run.tests += tested[k];
    }
    run.iterations += 1;
    return run;
}

double process_cpu_s() {
    timespec t;
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t);
    return double(t.tv_sec) + 1e-9 * double(t.tv_nsec);
}
template <int W>
void seed_mode(long packets, uint64_t seed, const float hgc[4]) {
    const double t0 = process_cpu_s();
    const SeedRun r = seed_run<W>(packets, seed, hgc);
    print_seed_run(r, process_cpu_s() - t0, W);
}
}  // namespace

int main(int argc, char** argv) {
    const long steps = argc > 1 ? std::atol(argv[1]) : 500000;
    const std::string mode = argc > 2 ? argv[2] : "8";
    const float hgc[4] = {float(1 - kG * kG), float(1 - kG), float(2 * kG), float(1 + kG * kG)};
    const uint64_t seed = argc > 4 ? std::strtoull(argv[4], nullptr, 10) : 1;
    if (mode == "seed" && argc > 3) {  // steps = packets here; argv[3] = lanes
        const int lanes = std::atoi(argv[3]);
        if (lanes == 4) seed_mode<4>(steps, seed, hgc);
        if (lanes == 8) seed_mode<8>(steps, seed, hgc);
        if (lanes == 16) seed_mode<16>(steps, seed, hgc);
        return 0;
    }
    if (mode == "8") run<8>(steps, hgc);
    if (mode == "16") run<16>(steps, hgc);
    if (mode == "4") run<4>(steps, hgc);
    if (mode == "scalar") {  // the engine's scalar double step, for the ratio
        const HenyeyGreenstein hg(kG);
        Scalar q[kPackets];
        for (int k = 0; k < kPackets; ++k) q[k] = start(uint64_t(k));
        const double t0 = thread_ns();
        for (long n = 0; n < steps; ++n)
            for (Scalar& x : q) scalar_step(x, hg, Vec3(0, 0, 0), Vec3(0, 0, -1));
        std::printf("scalar    %.3f ns/packet-step  (kept %.6g)\n", (thread_ns() - t0) / (double(steps) * kPackets),
                    q[0].absorbed);
    }
    return 0;
}
