// The float32 lane kernel (lane_block.h), written once in GCC's vector
// extensions for W lanes and included by one translation unit per
// instruction set (lane_steps_sse2.cpp: 4 lanes, lane_steps_avx2.cpp: 8,
// lane_steps_avx512.cpp: 16). Everything here has internal linkage: a
// function compiled for AVX-512 must never be the copy the linker keeps for
// code that runs on an older processor, so this header includes nothing of
// the engine but the block's plain data.
//
// The step is §28's (docs/performance.md): -ln u from a degree-7
// polynomial of the mantissa (scripts/fit_log1p.py f32: relative error
// 1.1e-7), the azimuth from quarter turns and Taylor polynomials, HG's cosine
// in MCML's form for |g| >= 1/4 and, below, in a form without its
// cancellation as g -> 0 (docs/numerics.md, "Float32 lanes").
#pragma once
#include <immintrin.h>

#include <cstdint>
#include <cstring>

#include "lane_block.h"

namespace ep {
namespace {

template <int W>
struct LaneTypes {
    typedef float F __attribute__((vector_size(4 * W)));
    typedef uint32_t U __attribute__((vector_size(4 * W)));
    typedef int32_t I __attribute__((vector_size(4 * W)));
};

template <class T>
inline T lane_load(const void* p) {
    T v;
    std::memcpy(&v, p, sizeof v);
    return v;
}
template <class T>
inline void lane_store(void* p, const T& v) {
    std::memcpy(p, &v, sizeof v);
}
template <class V, class T>
inline V lane_splat(T x) {
    return V{} + x;
}
template <class F>
inline F lane_min(F a, F b) {
    return a < b ? a : b;
}
template <class F>
inline F lane_max(F a, F b) {
    return a > b ? a : b;
}
template <class F>
inline F lane_dot(F ax, F ay, F az, F bx, F by, F bz) {
    return (ax * bx + ay * by) + az * bz;
}

// The register's own square root (exact, so the bits do not depend on the
// width); GCC's vector extensions have none, and its element loop took a
// third of §28's run.
template <class F>
inline F lane_sqrt(F x) {
#if defined(__AVX512F__)
    // The zero-masked form: the plain one starts from _mm512_undefined_ps,
    // which GCC 12 takes for an uninitialised read (-Wmaybe-uninitialized).
    if constexpr (sizeof(F) == 64) return F(_mm512_maskz_sqrt_ps(__mmask16(0xFFFF), __m512(x)));
#endif
#if defined(__AVX__)
    if constexpr (sizeof(F) == 32) return F(_mm256_sqrt_ps(__m256(x)));
#endif
    if constexpr (sizeof(F) == 16) return F(_mm_sqrt_ps(__m128(x)));
    F r = x;
    for (unsigned k = 0; k < sizeof(F) / 4; ++k) r[k] = __builtin_sqrtf(x[k]);
    return r;
}
// Bit k set when lane k of the mask m (lanes of 0 or -1) is set.
template <class M>
inline uint32_t lane_bits(M m) {
#if defined(__AVX512F__)
    if constexpr (sizeof(M) == 64) return _mm512_cmpneq_epi32_mask(__m512i(m), _mm512_setzero_si512());
#endif
#if defined(__AVX__)
    if constexpr (sizeof(M) == 32) return uint32_t(_mm256_movemask_ps(__m256(m)));
#endif
    if constexpr (sizeof(M) == 16) return uint32_t(_mm_movemask_ps(__m128(m)));
    uint32_t b = 0;
    for (unsigned k = 0; k < sizeof(M) / 4; ++k) b |= uint32_t(m[k] != 0) << k;
    return b;
}

// xoshiro128++ 1.0 (Blackman & Vigna 2021, ACM TOMS 47:36): one 32-bit output a lane.
template <class U>
inline U lane_rotl(U x, int k) {
    return (x << k) | (x >> (32 - k));
}
template <class U>
inline U lane_next(U& s0, U& s1, U& s2, U& s3) {
    const U out = lane_rotl(s0 + s3, 7) + s0;
    const U t = s1 << 9;
    s2 ^= s0;
    s3 ^= s1;
    s1 ^= s2;
    s0 ^= s3;
    s2 ^= t;
    s3 = lane_rotl(s3, 11);
    return out;
}

// -ln u for u = (k + 1) 2^-24, k the top 24 bits of x: u in (0, 1], so the
// free path is finite (at most 16.6). ln u = e ln 2 + ln m with m in
// [sqrt(1/2), sqrt(2)), ln m = r + r^2 q(r), r = m - 1 (fit: relative error
// 1.1e-7 over the interval, scripts/fit_log1p.py f32).
template <int W>
inline typename LaneTypes<W>::F lane_neg_log(typename LaneTypes<W>::U x) {
    using F = typename LaneTypes<W>::F;
    using I = typename LaneTypes<W>::I;
    const F u = __builtin_convertvector(I((x >> 8) + 1), F) * 0x1.0p-24f;
    const I bits = I(u);
    const I e = (bits - 0x3F3504F3) >> 23;  // arithmetic shift; 0x3F3504F3: sqrt(1/2)'s bits
    const F m = F(bits - (e << 23));
    const F r = m - 1.0f, r2 = r * r;
    F q = lane_splat<F>(0.08787265419960022f);
    const float c[] = {-0.1415964663028717f,  0.148347869515419f,  -0.16588488221168518f, 0.19972050189971924f,
                       -0.25001147389411926f, 0.3333367109298706f, -0.4999999701976776f};
    for (float k : c) q = q * r + k;
    return 0.0f - (__builtin_convertvector(e, F) * 0.6931471805599453f + (r + r2 * q));
}

// (cos phi, sin phi) of phi = 2 pi x 2^-32: the quarter turn from the top
// bits, the rest (|a| <= pi/4) by Taylor polynomials to a^9 and a^8
// (truncation below 4e-9), no table and so no gather.
template <int W>
inline void lane_azimuth(typename LaneTypes<W>::U x, typename LaneTypes<W>::F* cos_phi,
                         typename LaneTypes<W>::F* sin_phi) {
    using F = typename LaneTypes<W>::F;
    using I = typename LaneTypes<W>::I;
    const auto q = (x + (1u << 29)) >> 30;
    const F a = __builtin_convertvector(I(x - (q << 30)), F) * float(2 * 3.14159265358979323846 * 0x1.0p-32);
    const F a2 = a * a;
    const F s = a + (a * a2) * (-1.0f / 6 + a2 * (1.0f / 120 + a2 * (-1.0f / 5040 + a2 * (1.0f / 362880))));
    const F c = 1.0f + a2 * (-0.5f + a2 * (1.0f / 24 + a2 * (-1.0f / 720 + a2 * (1.0f / 40320))));
    const I odd = I(q & 1) != 0;
    const F cs = odd ? s : c, sn = odd ? c : s;
    *cos_phi = ((q + 1) & 2) != 0 ? -cs : cs;
    *sin_phi = (q & 2) != 0 ? -sn : sn;
}

// The packets of one group of W slots in registers.
template <int W>
struct LaneGroup {
    using F = typename LaneTypes<W>::F;
    using U = typename LaneTypes<W>::U;
    using I = typename LaneTypes<W>::I;
    U s0, s1, s2, s3, count, steps;
    F qx, qy, qz, tx, ty, tz, bx, by, bz, nx, ny, nz, w, tau, depth, budget;

    void load(const LaneBlock& B, int o) {
        s0 = lane_load<U>(B.s0 + o), s1 = lane_load<U>(B.s1 + o), s2 = lane_load<U>(B.s2 + o);
        s3 = lane_load<U>(B.s3 + o), count = lane_load<U>(B.count + o), steps = lane_load<U>(B.steps + o);
        qx = lane_load<F>(B.qx + o), qy = lane_load<F>(B.qy + o), qz = lane_load<F>(B.qz + o);
        tx = lane_load<F>(B.tx + o), ty = lane_load<F>(B.ty + o), tz = lane_load<F>(B.tz + o);
        bx = lane_load<F>(B.bx + o), by = lane_load<F>(B.by + o), bz = lane_load<F>(B.bz + o);
        nx = lane_load<F>(B.nx + o), ny = lane_load<F>(B.ny + o), nz = lane_load<F>(B.nz + o);
        w = lane_load<F>(B.w + o), tau = lane_load<F>(B.tau + o);
        depth = lane_load<F>(B.depth + o), budget = lane_load<F>(B.budget + o);
    }
    void store(LaneBlock& B, int o) const {
        lane_store(B.s0 + o, s0), lane_store(B.s1 + o, s1), lane_store(B.s2 + o, s2), lane_store(B.s3 + o, s3);
        lane_store(B.count + o, count), lane_store(B.steps + o, steps);
        lane_store(B.qx + o, qx), lane_store(B.qy + o, qy), lane_store(B.qz + o, qz);
        lane_store(B.tx + o, tx), lane_store(B.ty + o, ty), lane_store(B.tz + o, tz);
        lane_store(B.bx + o, bx), lane_store(B.by + o, by), lane_store(B.bz + o, bz);
        lane_store(B.nx + o, nx), lane_store(B.ny + o, ny), lane_store(B.nz + o, nz);
        lane_store(B.w + o, w), lane_store(B.tau + o, tau);
        lane_store(B.depth + o, depth), lane_store(B.budget + o, budget);
    }
};

// The constants of a group's slots.
template <int W>
struct LaneConstants {
    using F = typename LaneTypes<W>::F;
    using U = typename LaneTypes<W>::U;
    using I = typename LaneTypes<W>::I;
    F inv_mut, loss, hg0, hg1, hg2, hg3, hg_inv2g, g, threshold, inner, inner_r2, slack;
    F ex, ey, ez, ix, iy, iz;
    U room;
    I small_g;
    bool any_small, any_large, track_depth;
    LaneConstants(const LaneBlock& B, int o) {
        inv_mut = lane_load<F>(B.inv_mut + o), loss = lane_load<F>(B.loss + o);
        hg0 = lane_load<F>(B.hg0 + o), hg1 = lane_load<F>(B.hg1 + o), hg2 = lane_load<F>(B.hg2 + o);
        hg3 = lane_load<F>(B.hg3 + o), hg_inv2g = lane_load<F>(B.hg_inv2g + o), g = lane_load<F>(B.g + o);
        threshold = lane_load<F>(B.threshold + o);
        inner = lane_load<F>(B.inner + o), inner_r2 = lane_load<F>(B.inner_r2 + o), slack = lane_load<F>(B.slack + o);
        ex = lane_load<F>(B.ex + o), ey = lane_load<F>(B.ey + o), ez = lane_load<F>(B.ez + o);
        ix = lane_load<F>(B.ix + o), iy = lane_load<F>(B.iy + o), iz = lane_load<F>(B.iz + o);
        room = lane_load<U>(B.room + o);
        small_g = lane_load<I>(B.small_g + o);
        const I act = lane_load<I>(B.active + o);
        any_small = lane_bits(act & small_g) != 0;
        any_large = lane_bits(act & ~small_g) != 0;
        track_depth = B.track_depth;
    }
};

// HG's cosine for u in [0, 1): MCML's inverse CDF (its manual, eq. 3.28)
// where |g| >= 1/4; below, the same function written as
// (-v + g ((3 + v^2)/2 - g v + g^2 (v^2 - 1)/2)) / (1 - g v)^2, v = 1 - 2u,
// which does not cancel as g -> 0 (MCML's form lost the mean cosine in float32
// at g = 1e-4 by 3.5 sigma over 1.6e8 samples, this one kept it: §28).
template <int W>
inline typename LaneTypes<W>::F lane_hg_cos(const LaneConstants<W>& c, typename LaneTypes<W>::F u) {
    using F = typename LaneTypes<W>::F;
    F large{}, small{};
    if (c.any_large) {
        const F sq = c.hg0 / (c.hg1 + u * c.hg2);
        large = (c.hg3 - sq * sq) * c.hg_inv2g;
    }
    if (c.any_small) {
        const F v = 1.0f - 2.0f * u, v2 = v * v, gv = c.g * v, den = 1.0f - gv;
        small = (c.g * (((3.0f + v2) * 0.5f - gv) + (c.g * c.g) * ((v2 - 1.0f) * 0.5f)) - v) / (den * den);
    }
    const F ct = c.small_g ? small : large;
    return lane_max(lane_min(ct, lane_splat<F>(1.0f)), lane_splat<F>(-1.0f));
}

// The frame's renormalisation (DirectionFrame::renormalize in float32: one
// Newton step for 1/|n|, then orthonormal_basis, Duff et al. 2017) in the
// lanes where `due`; P: any packets with the frame's lanes tx ... nz.
template <int W, class Packets>
inline void lane_renormalize(Packets& P, typename LaneTypes<W>::I due) {
    using F = typename LaneTypes<W>::F;
    using I = typename LaneTypes<W>::I;
    const F k = 1.5f - 0.5f * lane_dot(P.nx, P.ny, P.nz, P.nx, P.ny, P.nz);
    const F x = P.nx * k, y = P.ny * k, z = P.nz * k;
    const F sign = F((I(z) & int32_t(0x80000000u)) | I(lane_splat<F>(1.0f)));  // +-1 with z's sign
    const F a = -1.0f / (sign + z);
    const F c = x * y * a, sx = sign * x;
    P.tx = due ? 1.0f + sx * x * a : P.tx;
    P.ty = due ? sign * c : P.ty;
    P.tz = due ? -sign * x : P.tz;
    P.bx = due ? c : P.bx;
    P.by = due ? sign + y * y * a : P.by;
    P.bz = due ? -y : P.bz;
    P.nx = due ? x : P.nx;
    P.ny = due ? y : P.ny;
    P.nz = due ? z : P.nz;
}

// `a` where the lane goes on, else `b`; kAll: every lane goes on (no blend).
template <bool kAll, class V, class M>
inline V lane_pick(M go, V a, V b) {
    if constexpr (kAll) return a;
    return go ? a : b;
}

// The first part of interact() in the lanes where `go`, the step to b
// taken: the move, the depth, the capture (seed eq. 3). Lanes where not `go`
// keep every bit of their state. kAll: all W lanes go (no blends). This and
// lane_scatter are always inlined: called from four places, GCC kept
// lane_scatter out of line, and the packets' state then went through
// memory (seed tissue: 7 % slower).
template <int W, bool kAll>
inline __attribute__((always_inline)) void lane_move(LaneGroup<W>& P, const LaneConstants<W>& c,
                                                     typename LaneTypes<W>::I go, typename LaneTypes<W>::F bx,
                                                     typename LaneTypes<W>::F by, typename LaneTypes<W>::F bz,
                                                     typename LaneTypes<W>::F budget) {
    using F = typename LaneTypes<W>::F;
    using U = typename LaneTypes<W>::U;
    P.qx = lane_pick<kAll>(go, bx, P.qx), P.qy = lane_pick<kAll>(go, by, P.qy), P.qz = lane_pick<kAll>(go, bz, P.qz);
    P.budget = lane_pick<kAll>(go, budget, P.budget);
    if (c.track_depth) {
        const F d = lane_dot(P.qx - c.ex, P.qy - c.ey, P.qz - c.ez, c.ix, c.iy, c.iz);
        P.depth = lane_pick<kAll>(go, lane_max(P.depth, d), P.depth);
    }
    const F dw = P.w * c.loss;
    P.w = lane_pick<kAll>(go, P.w - dw, P.w);
    P.steps -= U(go);  // go is -1 where true
}

// fluoresce()'s trials (seed §4) in the lanes where `go` and the weight is
// left: fluorophore j fires where u1 < d_j and u2 < c_j, two draws of the
// slot's own stream, and the first that fires ends them. A lane draws only
// for its own trials, so its stream does not depend on its neighbours'.
// Returns the lanes that fired; B.tried counts the trials, B.fired names the
// fluorophore.
template <int W>
inline typename LaneTypes<W>::I lane_trials(LaneBlock& B, int o, LaneGroup<W>& P, typename LaneTypes<W>::I go) {
    using F = typename LaneTypes<W>::F;
    using U = typename LaneTypes<W>::U;
    using I = typename LaneTypes<W>::I;
    const I n = lane_load<I>(B.trials + o);
    const I trying = go & (P.w > 0.0f) & (n > 0);
    if (lane_bits(trying) == 0) return I{};
    U tried = lane_load<U>(B.tried + o);
    I fired{}, which = lane_load<I>(B.fired + o);
    for (int j = 0; j < B.max_trials; ++j) {
        const I t = trying & (lane_splat<I>(j) < n) & ~fired;
        if (lane_bits(t) == 0) break;
        U s0 = P.s0, s1 = P.s1, s2 = P.s2, s3 = P.s3;
        const U x1 = lane_next(s0, s1, s2, s3), x2 = lane_next(s0, s1, s2, s3);
        P.s0 = t ? s0 : P.s0, P.s1 = t ? s1 : P.s1, P.s2 = t ? s2 : P.s2, P.s3 = t ? s3 : P.s3;
        tried -= U(t);
        const F u1 = __builtin_convertvector(I(x1 >> 8), F) * 0x1.0p-24f;
        const F u2 = __builtin_convertvector(I(x2 >> 8), F) * 0x1.0p-24f;
        const I hit = t & (u1 < lane_load<F>(B.trial_d[j] + o)) & (u2 < lane_load<F>(B.trial_c[j] + o));
        fired |= hit;
        which = hit ? lane_splat<I>(j) : which;
    }
    lane_store(B.tried + o, tried);
    lane_store(B.fired + o, which);
    return fired;
}

// The rest of interact() in the lanes where `go`: three draws (the cosine,
// the azimuth, the next free path), HG's scattering with the frame turned
// about n (DirectionFrame::turn, seed §4). Lanes where not `go` keep every
// bit of their state. kAll: all W lanes go (the common case: no blends).
template <int W, bool kAll>
inline __attribute__((always_inline)) void lane_scatter(LaneGroup<W>& P, const LaneConstants<W>& c,
                                                        typename LaneTypes<W>::I go) {
    using F = typename LaneTypes<W>::F;
    using U = typename LaneTypes<W>::U;
    using I = typename LaneTypes<W>::I;
    U s0 = P.s0, s1 = P.s1, s2 = P.s2, s3 = P.s3;
    const U x_cos = lane_next(s0, s1, s2, s3), x_phi = lane_next(s0, s1, s2, s3);
    const U x_tau = lane_next(s0, s1, s2, s3);
    P.s0 = lane_pick<kAll>(go, s0, P.s0), P.s1 = lane_pick<kAll>(go, s1, P.s1);
    P.s2 = lane_pick<kAll>(go, s2, P.s2), P.s3 = lane_pick<kAll>(go, s3, P.s3);
    const F u = __builtin_convertvector(I(x_cos >> 8), F) * 0x1.0p-24f;
    const F ct = lane_hg_cos<W>(c, u);
    const F st = lane_sqrt((1.0f - ct) * (1.0f + ct));
    F cp, sp;
    lane_azimuth<W>(x_phi, &cp, &sp);
    const F e1x = P.tx * cp + P.bx * sp, e1y = P.ty * cp + P.by * sp, e1z = P.tz * cp + P.bz * sp;
    const F nbx = P.bx * cp - P.tx * sp, nby = P.by * cp - P.ty * sp, nbz = P.bz * cp - P.tz * sp;
    const F ntx = e1x * ct - P.nx * st, nty = e1y * ct - P.ny * st, ntz = e1z * ct - P.nz * st;
    const F nnx = P.nx * ct + e1x * st, nny = P.ny * ct + e1y * st, nnz = P.nz * ct + e1z * st;
    P.bx = lane_pick<kAll>(go, nbx, P.bx), P.by = lane_pick<kAll>(go, nby, P.by);
    P.bz = lane_pick<kAll>(go, nbz, P.bz);
    P.tx = lane_pick<kAll>(go, ntx, P.tx), P.ty = lane_pick<kAll>(go, nty, P.ty);
    P.tz = lane_pick<kAll>(go, ntz, P.tz);
    P.nx = lane_pick<kAll>(go, nnx, P.nx), P.ny = lane_pick<kAll>(go, nny, P.ny);
    P.nz = lane_pick<kAll>(go, nnz, P.nz);
    P.count -= U(go);
    const I due = go & I((P.count & 15u) == 0);
    if (__builtin_expect(lane_bits(due) != 0, 0)) lane_renormalize<W>(P, due);
    P.tau = lane_pick<kAll>(go, lane_neg_log<W>(x_tau), P.tau);
}

// Steps group [o, o + W) until one of its active slots leaves; returns the
// mask of those that left (bits o ...). kTrials: spectral packets, whose
// fluorescence trials come between the capture and the scattering (plain
// runs keep a loop without them). The slots' steps are independent: each
// reads and writes its own lane only, so a packet's bits do not depend on
// its slot, its neighbours or the width.
template <int W, bool kTrials>
uint32_t run_group(LaneBlock& B, int o) {
    using F = typename LaneTypes<W>::F;
    using I = typename LaneTypes<W>::I;
    constexpr uint32_t kFull = W == 32 ? ~0u : (1u << W) - 1;
    I act = lane_load<I>(B.active + o);
    if (lane_bits(act) == 0) return 0;
    const LaneConstants<W> c(B, o);
    LaneGroup<W> P;
    P.load(B, o);
    const int n_planes = B.n_planes;
    while (true) {
        // The move and its clearance (ClearSteps::clear in float32): the
        // budget of the last tested point pays for the step, else the end
        // point b is tested against the ball and the planes. The zone is
        // convex, so a segment between two clear points is clear.
        const F s = P.tau * c.inv_mut;
        const F bx = P.qx + P.nx * s, by = P.qy + P.ny * s, bz = P.qz + P.nz * s;
        const F left = P.budget - (s + c.slack);
        const I spent = act & (left <= 0.0f);
        F budget = left;
        I blocked{};
        if (__builtin_expect(lane_bits(spent) != 0, 1)) {
            const F q2 = lane_dot(bx, by, bz, bx, by, bz);
            F fresh = c.inner - lane_sqrt(q2);
            for (int k = 0; k < n_planes; ++k) {
                const F m = lane_dot(lane_load<F>(B.pnx[k] + o), lane_load<F>(B.pny[k] + o), lane_load<F>(B.pnz[k] + o),
                                     bx, by, bz) -
                            lane_load<F>(B.poff[k] + o);
                fresh = lane_min(fresh, m);
            }
            const I ok = (q2 < c.inner_r2) & (fresh > 0.0f);
            budget = spent ? fresh - c.slack : left;
            blocked = spent & ~ok;
        }
        // interact(): the move and capture, the fluorescence trials of
        // spectral packets (an event leaves the lanes unscattered), the
        // scattering of the rest.
        const I go = act & ~blocked;
        const bool all = lane_bits(go) == kFull;
        if (all)
            lane_move<W, true>(P, c, go, bx, by, bz, budget);
        else
            lane_move<W, false>(P, c, go, bx, by, bz, budget);
        I fired{};
        if constexpr (kTrials) fired = lane_trials<W>(B, o, P, go);
        const I on = go & ~fired;
        if (all && (!kTrials || lane_bits(fired) == 0))
            lane_scatter<W, true>(P, c, on);
        else
            lane_scatter<W, false>(P, c, on);
        // Roulette and the caps are the walk's (survives_roulette, over_caps).
        const I slow = on & ((P.w < c.threshold) | I(P.steps >= c.room));
        const I leave = (act & blocked) | slow | fired;
        if (__builtin_expect(lane_bits(leave) != 0, 0)) {
            I reason = lane_load<I>(B.reason + o);
            reason = blocked ? lane_splat<I>(int32_t(kLaneBlocked))
                             : (slow ? lane_splat<I>(int32_t(kLaneSlow))
                                     : (fired ? lane_splat<I>(int32_t(kLaneFluoresced)) : reason));
            act &= ~leave;
            P.store(B, o);
            lane_store(B.active + o, act);
            lane_store(B.reason + o, reason);
            return lane_bits(leave) << o;
        }
    }
}

template <int W>
uint32_t run_lanes_w(LaneBlock& B) {
    uint32_t left = 0;
    // Spectral packets' trials (B.max_trials > 0) in a loop of their own.
    const bool trials = B.max_trials > 0;
    for (int o = 0; o < LaneBlock::kSlots; o += W)
        left |= trials ? run_group<W, true>(B, o) : run_group<W, false>(B, o);
    return left;
}

}  // namespace
}  // namespace ep
