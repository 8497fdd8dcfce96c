// Issue 39, step 1 continued: the interior step of scripts/lane_step_bench.cpp (the free path, the move,
// the clearance budget, the depth, the capture, the HG cosine, the azimuth, the frame turn and its
// renormalisation every 16th scattering, the next free path) in single precision, 8 packets in the lanes of
// AVX2 registers, against the engine's own scalar double step. §18 of docs/performance.md found that 4 lanes
// of doubles, bit-identical to the scalar step, take a step only 1.74-1.88x faster on this processor; this
// measures what float32 lanes would give, before any engine is built on them. The float32 step cannot keep
// the double step's bits, so instead of comparing bits it checks its sampling against the laws (mean free
// path, <cos theta> = g, the azimuth's moments, |n| after a million turns). Throwaway measurement, not part
// of the build:
//   g++ -O3 -mavx2 -ffp-contract=off -std=c++17 -Inative scripts/lane_step_f32_bench.cpp -o /tmp/f32_bench
//   /tmp/f32_bench [steps per lane] [scalar|f32|f32pos64|check]
//   /tmp/f32_bench [steps per lane] check [g [small]]   (small: the HG form for |g| < 1/4)
//   /tmp/f32_bench [packets] seed [seed [mua_per_cm mus_per_cm g n]]   (a semi-infinite medium under air)
// f32: everything in float32 (positions too); f32pos64: positions and depth kept in double (a scene in
// metres, or far from the origin, needs them), the rest in float32.
#include <immintrin.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <ctime>
#include <string>

#include "lane_step_scalar.h"

using namespace ep;
using namespace lane_bench;

namespace {

// ---- eight packets in float32 lanes ----
using F = __m256;
using I = __m256i;
inline F bc(float x) { return _mm256_set1_ps(x); }
inline I bci(uint32_t x) { return _mm256_set1_epi32(int32_t(x)); }
inline F add(F a, F b) { return _mm256_add_ps(a, b); }
inline F sub(F a, F b) { return _mm256_sub_ps(a, b); }
inline F mul(F a, F b) { return _mm256_mul_ps(a, b); }

struct Lanes8 {
    I s0, s1, s2, s3, count;                    // xoshiro128++ state, scatterings
    F px, py, pz;                               // positions (f32 mode)
    __m256d pxd[2], pyd[2], pzd[2], depthd[2];  // positions and depth in double (f32pos64 mode)
    F tx, ty, tz, bx, by, bz, nx, ny, nz, w, tau, absorbed, depth, budget;
    F cx, cy, cz;  // the centre of the lane's zone (mode seed)
};

// xoshiro128++ 1.0, one 32-bit output a lane.
inline I next_u32(Lanes8& L) { return xoshiro_next<32, 7, 9, 11>(L.s0, L.s1, L.s2, L.s3); }

// -ln u for u = (k + 1) 2^-24, k the top 24 bits of x: u in [2^-24, 1], exact in float, so the free path
// is cut at 16.6 mean free paths (a step in 6e7 would go farther; the double engine's lattice of 2^-53
// cuts at 36.7). ln u = e ln 2 + ln(1 + r) with 1 + r in [sqrt(1/2), sqrt(2)) and ln(1 + r) = r + r^2 q(r),
// q a Chebyshev fit of degree 7 (`scripts/fit_log1p.py f32`: relative error 1.1e-7 over the range, in float).
inline F neg_log_u24(I x) {
    const F u = mul(_mm256_cvtepi32_ps(_mm256_add_epi32(_mm256_srli_epi32(x, 8), bci(1))), bc(0x1.0p-24f));
    const I bits = _mm256_castps_si256(u);
    const I e = _mm256_srai_epi32(_mm256_sub_epi32(bits, bci(0x3F3504F3u)), 23);  // sqrt(1/2)'s bits
    const F m = _mm256_castsi256_ps(_mm256_sub_epi32(bits, _mm256_slli_epi32(e, 23)));
    const F r = sub(m, bc(1.0f)), r2 = mul(r, r);
    F q = bc(0.08787265419960022f);
    const float c[] = {-0.1415964663028717f,  0.148347869515419f,  -0.16588488221168518f, 0.19972050189971924f,
                       -0.25001147389411926f, 0.3333367109298706f, -0.4999999701976776f};
    for (float k : c) q = add(mul(q, r), bc(k));
    const F ln = add(mul(_mm256_cvtepi32_ps(e), bc(0.6931471805599453f)), add(r, mul(r2, q)));
    return sub(_mm256_setzero_ps(), ln);
}

// (cos phi, sin phi) of phi = 2 pi x 2^-32: the quarter turn q nearest phi from the top bits, the rest
// d in [-2^29, 2^29) as an angle a in [-pi/4, pi/4), whose sine and cosine are Taylor polynomials to a^9
// and a^8 (remainders below 2e-9 and 3e-8), then turned by q quarter turns: swaps and sign flips.
inline void azimuth8(I x, F* cos_phi, F* sin_phi) {
    const I q = _mm256_srli_epi32(_mm256_add_epi32(x, bci(1u << 29)), 30);
    const I d = _mm256_sub_epi32(x, _mm256_slli_epi32(q, 30));
    const F a = mul(_mm256_cvtepi32_ps(d), bc(float(2 * kPi * 0x1.0p-32)));
    const F a2 = mul(a, a);
    const F s = add(
        a,
        mul(mul(a, a2), add(bc(-1.0f / 6),
                            mul(a2, add(bc(1.0f / 120), mul(a2, add(bc(-1.0f / 5040), mul(a2, bc(1.0f / 362880)))))))));
    const F c = add(
        bc(1.0f),
        mul(a2, add(bc(-0.5f), mul(a2, add(bc(1.0f / 24), mul(a2, add(bc(-1.0f / 720), mul(a2, bc(1.0f / 40320)))))))));
    // q = 1, 3 swap; cos is negated for q = 1, 2, sin for q = 2, 3.
    const F swap = _mm256_castsi256_ps(_mm256_slli_epi32(q, 31));  // sign bit set when q is odd
    const F cs = _mm256_blendv_ps(c, s, swap), sn = _mm256_blendv_ps(s, c, swap);
    const I neg_c = _mm256_slli_epi32(_mm256_add_epi32(q, bci(1)), 30);  // bit 31 = bit 1 of q + 1
    const I neg_s = _mm256_slli_epi32(q, 30);                            // bit 31 = bit 1 of q
    *cos_phi = _mm256_xor_ps(cs, _mm256_and_ps(_mm256_castsi256_ps(neg_c), bc(-0.0f)));
    *sin_phi = _mm256_xor_ps(sn, _mm256_and_ps(_mm256_castsi256_ps(neg_s), bc(-0.0f)));
}

inline F dot3(F ax, F ay, F az, F bx, F by, F bz) { return add(add(mul(ax, bx), mul(ay, by)), mul(az, bz)); }

// DirectionFrame::renormalize in the lanes of `mask` (orthonormal_basis, Duff et al. 2017), in float.
inline void renormalize8(Lanes8& L, F mask) {
    const F k = sub(bc(1.5f), mul(bc(0.5f), dot3(L.nx, L.ny, L.nz, L.nx, L.ny, L.nz)));
    const F x = mul(L.nx, k), y = mul(L.ny, k), z = mul(L.nz, k);
    const F sign = _mm256_or_ps(_mm256_and_ps(z, bc(-0.0f)), bc(1.0f));
    const F a = _mm256_div_ps(bc(-1.0f), add(sign, z));
    const F c = mul(mul(x, y), a);
    const F sx = mul(sign, x);
    auto set = [&](F& dst, F v) { dst = _mm256_blendv_ps(dst, v, mask); };
    set(L.tx, add(bc(1.0f), mul(mul(sx, x), a)));
    set(L.ty, mul(sign, c));
    set(L.tz, mul(_mm256_xor_ps(sign, bc(-0.0f)), x));
    set(L.bx, c);
    set(L.by, add(sign, mul(mul(y, y), a)));
    set(L.bz, _mm256_xor_ps(y, bc(-0.0f)));
    set(L.nx, x);
    set(L.ny, y);
    set(L.nz, z);
}

// MCML's form of the HG cosine cancels in float32 as g -> 0 (see scatter8): 'check G small' takes the other.
bool g_small_form = false;

// Sampled quantities, for the check only (the timed loops discard them).
struct Samples {
    F cos_theta, cos_phi, sin_phi, tau;
};

// HG (MCML eq. 3.28) with u = k 2^-24 from the top 24 bits, one division (the other a product with 1/(2g)),
// then the azimuth and the turn as in phase.h's scatter.
inline void scatter8(Lanes8& L, const float hgc[4], Samples* out) {
    const F u = mul(_mm256_cvtepi32_ps(_mm256_srli_epi32(next_u32(L), 8)), bc(0x1.0p-24f));
    F c0;
    if (g_small_form) {
        // The same inverse CDF with v = 1 - 2u (exact) and D = 1 - g v: cos = (-v + g ((3 + v^2)/2 - g v +
        // g^2 (v^2 - 1)/2)) / D^2, which has no (1 + g^2 - s^2) / (2g) to cancel as g -> 0 (it tends to
        // 2u - 1, the isotropic law) but cancels as g -> 1 instead; so it serves |g| < 1/4 only.
        const F g = bc(hgc[2] * 0.5f), v = sub(bc(1.0f), add(u, u)), v2 = mul(v, v), D = sub(bc(1.0f), mul(g, v));
        const F inner =
            add(sub(mul(add(bc(3.0f), v2), bc(0.5f)), mul(g, v)), mul(mul(g, g), mul(sub(v2, bc(1.0f)), bc(0.5f))));
        c0 = _mm256_div_ps(sub(mul(g, inner), v), mul(D, D));
    } else {
        const F sq = _mm256_div_ps(bc(hgc[0]), add(bc(hgc[1]), mul(u, bc(hgc[2]))));
        c0 = mul(sub(bc(hgc[3]), mul(sq, sq)), bc(1.0f / hgc[2]));
    }
    const F ct = _mm256_max_ps(_mm256_min_ps(c0, bc(1.0f)), bc(-1.0f));
    const F st = _mm256_sqrt_ps(mul(sub(bc(1.0f), ct), add(bc(1.0f), ct)));
    F cp, sp;
    azimuth8(next_u32(L), &cp, &sp);
    out->cos_theta = ct;
    out->cos_phi = cp;
    out->sin_phi = sp;
    const F e1x = add(mul(L.tx, cp), mul(L.bx, sp));
    const F e1y = add(mul(L.ty, cp), mul(L.by, sp));
    const F e1z = add(mul(L.tz, cp), mul(L.bz, sp));
    L.bx = sub(mul(L.bx, cp), mul(L.tx, sp));
    L.by = sub(mul(L.by, cp), mul(L.ty, sp));
    L.bz = sub(mul(L.bz, cp), mul(L.tz, sp));
    L.tx = sub(mul(e1x, ct), mul(L.nx, st));
    L.ty = sub(mul(e1y, ct), mul(L.ny, st));
    L.tz = sub(mul(e1z, ct), mul(L.nz, st));
    L.nx = add(mul(L.nx, ct), mul(e1x, st));
    L.ny = add(mul(L.ny, ct), mul(e1y, st));
    L.nz = add(mul(L.nz, ct), mul(e1z, st));
    L.count = _mm256_add_epi32(L.count, bci(1));
    const I due = _mm256_cmpeq_epi32(_mm256_and_si256(L.count, bci(DirectionFrame::kRenormalizeEvery - 1)),
                                     _mm256_setzero_si256());
    if (__builtin_expect(!_mm256_testz_si256(due, due), 0)) renormalize8(L, _mm256_castsi256_ps(due));
}

// p += n s with p in double: the float displacement widened (exact) and added in double, two halves of 4.
inline void move_double(__m256d p[2], F d) {
    p[0] = _mm256_add_pd(p[0], _mm256_cvtps_pd(_mm256_castps256_ps128(d)));
    p[1] = _mm256_add_pd(p[1], _mm256_cvtps_pd(_mm256_extractf128_ps(d, 1)));
}

template <bool kPos64>
inline void step8(Lanes8& L, const float hgc[4], const Vec3& ep, const Vec3& ei, Samples* out) {
    const F s = mul(L.tau, bc(float(1 / kMutCm)));
    const F dx = mul(L.nx, s), dy = mul(L.ny, s), dz = mul(L.nz, s);
    if (kPos64) {
        move_double(L.pxd, dx);
        move_double(L.pyd, dy);
        move_double(L.pzd, dz);
        for (int h = 0; h < 2; ++h) {
            const __m256d v = _mm256_add_pd(
                _mm256_add_pd(_mm256_mul_pd(_mm256_sub_pd(L.pxd[h], _mm256_set1_pd(ep.x)), _mm256_set1_pd(ei.x)),
                              _mm256_mul_pd(_mm256_sub_pd(L.pyd[h], _mm256_set1_pd(ep.y)), _mm256_set1_pd(ei.y))),
                _mm256_mul_pd(_mm256_sub_pd(L.pzd[h], _mm256_set1_pd(ep.z)), _mm256_set1_pd(ei.z)));
            L.depthd[h] = _mm256_max_pd(v, L.depthd[h]);
        }
    } else {
        L.px = add(L.px, dx);
        L.py = add(L.py, dy);
        L.pz = add(L.pz, dz);
        const F v = dot3(sub(L.px, bc(float(ep.x))), sub(L.py, bc(float(ep.y))), sub(L.pz, bc(float(ep.z))),
                         bc(float(ei.x)), bc(float(ei.y)), bc(float(ei.z)));
        L.depth = _mm256_max_ps(v, L.depth);
    }
    const F left = sub(L.budget, add(s, bc(float(kSlack))));
    L.budget = _mm256_blendv_ps(bc(1e30f), left, _mm256_cmp_ps(left, _mm256_setzero_ps(), _CMP_GT_OQ));
    const F dW = mul(L.w, bc(float(kLoss)));
    L.w = sub(L.w, dW);
    L.absorbed = add(L.absorbed, dW);
    L.w = _mm256_blendv_ps(L.w, bc(1.0f), _mm256_cmp_ps(L.w, bc(float(kRefill)), _CMP_LT_OQ));
    scatter8(L, hgc, out);
    L.tau = neg_log_u24(next_u32(L));
    out->tau = L.tau;
}

Lanes8 start8() {
    Lanes8 L;
    std::memset(&L, 0, sizeof L);
    uint32_t s[4][8];
    for (int i = 0; i < 8; ++i) {
        uint32_t st[4];
        stream_state(1, uint64_t(i), st);  // keyed (seed, packet) as the engine's streams
        for (int w = 0; w < 4; ++w) s[w][i] = st[w];
    }
    L.s0 = _mm256_loadu_si256(reinterpret_cast<const I*>(s[0]));
    L.s1 = _mm256_loadu_si256(reinterpret_cast<const I*>(s[1]));
    L.s2 = _mm256_loadu_si256(reinterpret_cast<const I*>(s[2]));
    L.s3 = _mm256_loadu_si256(reinterpret_cast<const I*>(s[3]));
    const DirectionFrame f(normalize(Vec3(0.3, -0.2, -1)));
    L.tx = bc(float(f.t[0])), L.ty = bc(float(f.t[1])), L.tz = bc(float(f.t[2]));
    L.bx = bc(float(f.b[0])), L.by = bc(float(f.b[1])), L.bz = bc(float(f.b[2]));
    L.nx = bc(float(f.n[0])), L.ny = bc(float(f.n[1])), L.nz = bc(float(f.n[2]));
    L.w = bc(1.0f), L.budget = bc(1e30f);
    L.tau = neg_log_u24(next_u32(L));
    return L;
}

double lanes_sum(F v) {
    float a[8];
    _mm256_storeu_ps(a, v);
    double s = 0;
    for (float x : a) s += x;
    return s;
}

// The sampling laws, from n steps of 8 lanes: <tau> = 1 and <tau^2> = 2 (Exp(1), cut at 16.6: below 1e-6),
// <cos theta> = g and <cos^2 theta> = (1 + 2 g^2) / 3 (HG's second Legendre moment g^2), <cos phi> =
// <sin phi> = 0 and <cos^2 phi> = 1/2; each printed as z = (mean - expected) / its standard error.
void check(long n, const float hgc[4]) {
    Lanes8 L = start8();
    Samples smp;
    double m[7] = {0, 0, 0, 0, 0, 0, 0}, m2[7] = {0, 0, 0, 0, 0, 0, 0};
    for (long k = 0; k < n; ++k) {
        step8<false>(L, hgc, Vec3(0, 0, 0), Vec3(0, 0, -1), &smp);
        float ct[8], cp[8], sp[8], tau[8];
        _mm256_storeu_ps(ct, smp.cos_theta), _mm256_storeu_ps(cp, smp.cos_phi), _mm256_storeu_ps(sp, smp.sin_phi);
        _mm256_storeu_ps(tau, smp.tau);
        for (int i = 0; i < 8; ++i) {
            const double v[7] = {tau[i], double(tau[i]) * tau[i], ct[i], double(ct[i]) * ct[i], cp[i],
                                 sp[i],  double(cp[i]) * cp[i]};
            for (int j = 0; j < 7; ++j) m[j] += v[j], m2[j] += v[j] * v[j];
        }
    }
    const double N = 8.0 * double(n), g = kG;
    const char* name[7] = {"<tau>", "<tau^2>", "<cos theta>", "<cos^2 theta>", "<cos phi>", "<sin phi>", "<cos^2 phi>"};
    const double want[7] = {1, 2, g, (1 + 2 * g * g) / 3, 0, 0, 0.5};
    for (int j = 0; j < 7; ++j) {
        const double mean = m[j] / N, se = std::sqrt((m2[j] / N - mean * mean) / N);
        std::printf("%-14s %.7f  expected %.7f  z = %+.2f\n", name[j], mean, want[j], (mean - want[j]) / se);
    }
    const F n2 = dot3(L.nx, L.ny, L.nz, L.nx, L.ny, L.nz), tn = dot3(L.tx, L.ty, L.tz, L.nx, L.ny, L.nz);
    float a[8], b[8];
    _mm256_storeu_ps(a, n2), _mm256_storeu_ps(b, tn);
    double worst_n = 0, worst_tn = 0;
    for (int i = 0; i < 8; ++i)
        worst_n = std::max(worst_n, std::fabs(a[i] - 1.0)), worst_tn = std::max(worst_tn, std::fabs(double(b[i])));
    std::printf("after %ld turns: max ||n|^2 - 1| %.2e, max |t.n| %.2e\n", n, worst_n, worst_tn);
}

// ---- the seed tissue end to end in float32 lanes (mode seed) ----
// A packet-per-lane Monte Carlo of the seed tissue (n 1.1 under air, semi-infinite, pencil at normal
// incidence; MCML's rules: specular loss at entry, Fresnel's all-or-none choice at the surface, roulette at
// 1e-4 with survival 1/10), to see the lane step's speed in a whole run and whether float32 keeps Rd.
// Every packet owns a xoshiro128++ stream seeded from (seed, packet index) and only its own events draw
// from it, so its path does not depend on which lane carries it. Per iteration: the move (lanes), the
// lanes that crossed z = 0 (scalar: reflect, or leave with their weight into Rd), the capture and the
// scattering (lanes), the roulette and the refills (scalar, for the lanes under the threshold), the next
// free path (lanes). A packet that left keeps weight 0 until the roulette's pass refills its lane, so
// that a new packet never takes the capture and scattering at its launch point.
// The lanes' state spilled to memory for the scalar fix-ups: one store a register, then plain loads and
// stores of single lanes, then one load a register. (A lane written into a register's memory image in place,
// field by field, cost a store-to-load forwarding stall per field: 0.64-0.66 against 0.55-0.63 CPU-s for
// the seed tissue's 10^6 packets.)
#define FLOAT_FIELDS(X) \
    X(px) X(py) X(pz) X(tx) X(ty) X(tz) X(bx) X(by) X(bz) X(nx) X(ny) X(nz) X(w) X(budget) X(cx) X(cy) X(cz)
#define INT_FIELDS(X) X(s0) X(s1) X(s2) X(s3) X(count)
struct Flat {
#define DECLARE_F(name) alignas(32) float name[8];
#define DECLARE_I(name) alignas(32) uint32_t name[8];
    FLOAT_FIELDS(DECLARE_F)
    INT_FIELDS(DECLARE_I)
};
inline void spill(const Lanes8& L, Flat& f) {
#define STORE_F(name) _mm256_store_ps(f.name, L.name);
#define STORE_I(name) _mm256_store_si256(reinterpret_cast<I*>(f.name), L.name);
    FLOAT_FIELDS(STORE_F)
    INT_FIELDS(STORE_I)
}
inline void reload(const Flat& f, Lanes8& L) {
#define LOAD_F(name) L.name = _mm256_load_ps(f.name);
#define LOAD_I(name) L.name = _mm256_load_si256(reinterpret_cast<const I*>(f.name));
    FLOAT_FIELDS(LOAD_F)
    INT_FIELDS(LOAD_I)
}

// The clearance budget (lane_step_scalar.h) is the distance to the ball's edge or to the surface, whichever
// is nearer, less the steps taken. Only when it runs out are the lanes renewed (in lanes); a lane that left
// its ball hops to its new cube (scalar), and only a lane whose renewed budget is gone tests the surface. So
// the plane test is as rare as the engine's general steps, and the renewals cost what the engine's do.
// The lanes' budgets at their points: min(the ball's inner radius less the distance to the centre, the
// depth less the surface's allowance).
inline F fresh_budget(const Lanes8& L) {
    const F dx = sub(L.px, L.cx), dy = sub(L.py, L.cy), dz = sub(L.pz, L.cz);
    const F ball = sub(bc(kInner), _mm256_sqrt_ps(dot3(dx, dy, dz, dx, dy, dz)));
    return _mm256_min_ps(ball, sub(L.pz, bc(kLo)));
}

// The lane's generator as scalar xoshiro128++ (the same sequence as next_u32 in that lane).
uint32_t lane_u32(Flat& f, int i) { return xoshiro128_next(f.s0[i], f.s1[i], f.s2[i], f.s3[i]); }

SeedRun seed_run(long packets, uint64_t seed, const float hgc[4]) {
    SeedRun run;
    run.seed = seed;
    run.packets = packets;
    Lanes8 L;
    std::memset(&L, 0, sizeof L);
    Flat f;
    alignas(32) float packet_absorbed[8] = {}, packet_rd[8] = {};
    spill(L, f);
    for (int i = 0; i < 8; ++i) refill_lane(f, i, run, packet_absorbed, packet_rd);
    reload(f, L);
    L.tau = neg_log_u24(next_u32(L));
    Samples smp;
    const F loss = bc(float(kLoss));
    for (;;) {
        const F s = mul(L.tau, bc(float(1 / kMutCm)));
        L.px = add(L.px, mul(L.nx, s));
        L.py = add(L.py, mul(L.ny, s));
        L.pz = add(L.pz, mul(L.nz, s));
        L.budget = sub(L.budget, add(s, bc(float(kSlack))));
        ++run.iterations;
        int out = 0;
        const F spent = _mm256_cmp_ps(L.budget, _mm256_setzero_ps(), _CMP_LE_OQ);
        if (_mm256_movemask_ps(spent)) {  // renew the lanes whose budget ran out
            ++run.renewals;
            run.lanes_renewed += __builtin_popcount(_mm256_movemask_ps(spent));
            L.budget = _mm256_blendv_ps(L.budget, fresh_budget(L), spent);
            // Out of the ball (and not past the surface): a hop to the new cube, scalar.
            const F gone = _mm256_and_ps(spent, _mm256_cmp_ps(L.budget, _mm256_setzero_ps(), _CMP_LE_OQ));
            int moved = _mm256_movemask_ps(_mm256_andnot_ps(_mm256_cmp_ps(L.pz, bc(kLo), _CMP_LT_OQ), gone));
            if (moved) {
                spill(L, f);
                for (; moved; moved &= moved - 1, ++run.hops) hop_lane(f, __builtin_ctz(moved));
                reload(f, L);
                L.budget = _mm256_blendv_ps(L.budget, fresh_budget(L), gone);
            }
            out = _mm256_movemask_ps(_mm256_and_ps(gone, _mm256_cmp_ps(L.pz, _mm256_setzero_ps(), _CMP_LT_OQ)));
            run.tests += __builtin_popcount(_mm256_movemask_ps(gone));
        }
        if (out) {  // lanes past the surface: Fresnel's all-or-none choice (the plane's mirror on reflection)
            spill(L, f);
            for (; out; out &= out - 1) {
                const int i = __builtin_ctz(out);
                if (double(lane_u32(f, i)) * 0x1.0p-32 < fresnel_out(-double(f.nz[i]))) {
                    f.pz[i] = -f.pz[i], f.nz[i] = -f.nz[i], f.tz[i] = -f.tz[i], f.bz[i] = -f.bz[i];
                    f.budget[i] = 0;
                } else {
                    packet_rd[i] += f.w[i];
                    f.w[i] = 0;
                }
            }
            reload(f, L);
        }
        const F dW = mul(L.w, loss);
        L.w = sub(L.w, dW);
        _mm256_store_ps(packet_absorbed, add(_mm256_load_ps(packet_absorbed), dW));
        scatter8(L, hgc, &smp);
        int low = _mm256_movemask_ps(_mm256_cmp_ps(L.w, bc(float(kRoulette)), _CMP_LT_OQ));
        if (low) {  // the roulette, and new packets in the lanes whose packet ended
            spill(L, f);
            for (; low; low &= low - 1) {
                const int i = __builtin_ctz(low);
                if (f.w[i] > 0 && double(lane_u32(f, i)) * 0x1.0p-32 < kSurvive)
                    f.w[i] = float(f.w[i] / kSurvive);
                else
                    refill_lane(f, i, run, packet_absorbed, packet_rd);
            }
            reload(f, L);
            const bool busy = _mm256_movemask_ps(_mm256_cmp_ps(L.w, _mm256_setzero_ps(), _CMP_GT_OQ)) != 0;
            if (!busy && run.launched == run.packets) break;
        }
        L.tau = neg_log_u24(next_u32(L));
    }
    spill(L, f);
    for (int i = 0; i < 8; ++i) refill_lane(f, i, run, packet_absorbed, packet_rd);  // flush the last packets
    return run;
}
}  // namespace

int main(int argc, char** argv) {
    const long steps = argc > 1 ? std::atol(argv[1]) : 2000000;
    const std::string mode = argc > 2 ? argv[2] : "f32";
    if (mode == "check" && argc > 3) set_medium(kMua, kMus, std::atof(argv[3]), kN);
    g_small_form = argc > 4 && std::string(argv[4]) == "small";
    if (mode == "seed" && argc > 7)
        set_medium(std::atof(argv[4]), std::atof(argv[5]), std::atof(argv[6]), std::atof(argv[7]));
    if (mode == "seed") g_small_form = std::fabs(kG) < 0.25;
    const HenyeyGreenstein hg(kG);
    const float hgc[4] = {float(1 - kG * kG), float(1 - kG), float(2 * kG), float(1 + kG * kG)};
    const Vec3 ep(0, 0, 0), ei(0, 0, -1);
    if (mode == "check") {
        check(steps, hgc);
        return 0;
    }
    if (mode == "seed") {  // steps = packets here
        timespec a, b;
        clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &a);
        const SeedRun r = seed_run(steps, argc > 3 ? std::strtoull(argv[3], nullptr, 10) : 1, hgc);
        clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &b);
        const double cpu = double(b.tv_sec - a.tv_sec) + 1e-9 * double(b.tv_nsec - a.tv_nsec);
        print_seed_run(r, cpu, 8);
        return 0;
    }
    auto now = [] {  // thread CPU time (ns): the shared machine's other work is not counted
        timespec t;
        clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t);
        return (unsigned long long)t.tv_sec * 1000000000ULL + (unsigned long long)t.tv_nsec;
    };
    // Every path takes 8 x steps lane-steps, so the figures compare per packet step.
    const double lane_steps = 8.0 * double(steps);
    double keep = 0;
    const unsigned long long t0 = now();
    if (mode == "scalar") {
        Scalar q[8];
        for (int i = 0; i < 8; ++i) q[i] = start(uint64_t(i));
        for (long k = 0; k < steps; ++k)
            for (int i = 0; i < 8; ++i) scalar_step(q[i], hg, ep, ei);
        for (const Scalar& x : q) keep += x.absorbed + x.depth;
    } else {
        Lanes8 L = start8();
        Samples smp;
        if (mode == "f32pos64")
            for (long k = 0; k < steps; ++k) step8<true>(L, hgc, ep, ei, &smp);
        else
            for (long k = 0; k < steps; ++k) step8<false>(L, hgc, ep, ei, &smp);
        keep =
            lanes_sum(L.absorbed) + lanes_sum(L.depth) + _mm256_cvtsd_f64(L.depthd[0]) + _mm256_cvtsd_f64(L.depthd[1]);
    }
    const unsigned long long t = now() - t0;
    std::printf("%-9s %.0f lane-steps  %.3f ns/lane-step  (kept %.6g)\n", mode.c_str(), lane_steps, t / lane_steps,
                keep);
    return 0;
}
