// Issue 39, step 1: one interior step of zone_steps (transport.cpp) for a plain
// run -- the free path, the move, the clearance budget, the depth, the capture,
// the HG cosine, the azimuth, the frame turn (and its renormalisation every 16th
// scattering), the next free path -- scalar (the engine's own inline functions)
// against a 4-lane AVX2 version over a structure of arrays, with the same IEEE
// operations in the same order. Checks that each lane's state stays bit-identical
// to the scalar packet's, then times both (thread CPU time; run under callgrind for the
// instructions). Throwaway measurement, not part of the build:
//   g++ -O3 -mavx2 -ffp-contract=off -std=c++17 -Inative scripts/lane_step_bench.cpp -o /tmp/lane_step_bench
//   /tmp/lane_step_bench [steps per lane] [scalar|lanes|both]
#include <immintrin.h>
#include <x86intrin.h>
#include <ctime>

#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>

#include "lane_step_scalar.h"

using namespace ep;
using namespace lane_bench;

namespace {

// ---- four packets in the lanes of AVX2 registers ----
struct Lanes {
    __m256i s0, s1, s2, s3, count;
    __m256d px, py, pz, tx, ty, tz, bx, by, bz, nx, ny, nz, W, tau, absorbed, depth, budget;
};

// A gather of 4 doubles: the AVX2 instruction, or (-DMANUAL_GATHER) four scalar loads.
inline __m256d gather(const double* base, __m256i idx) {
#ifdef MANUAL_GATHER
    alignas(32) int64_t i[4];
    _mm256_store_si256(reinterpret_cast<__m256i*>(i), idx);
    return _mm256_set_pd(base[i[3]], base[i[2]], base[i[1]], base[i[0]]);
#else
    return _mm256_i64gather_pd(base, idx, 8);
#endif
}
inline __m256d bc(double x) { return _mm256_set1_pd(x); }
inline __m256i bci(uint64_t x) { return _mm256_set1_epi64x(int64_t(x)); }
// xoshiro256++ (rng.h), lane-wise.
inline __m256i next_u64(Lanes& L) { return xoshiro_next<64, 23, 17, 45>(L.s0, L.s1, L.s2, L.s3); }
// double(x) for 0 <= x < 2^52, exact: 2^52 + x has x's bits as its mantissa.
inline __m256d small_to_double(__m256i x) {
    return _mm256_sub_pd(_mm256_castsi256_pd(_mm256_or_si256(x, bci(0x4330000000000000ULL))), bc(0x1.0p52));
}
// neg_log_lattice (fast_log.h), lane-wise, for m in [1, 2^53].
inline __m256d neg_log_lattice4(__m256i m) {
    using namespace log_detail;
    // double(m) exactly: the high and low 32 bits converted apart (both exact) and summed (exact: m <= 2^53).
    const __m256d dm = _mm256_add_pd(_mm256_mul_pd(small_to_double(_mm256_srli_epi64(m, 32)), bc(0x1.0p32)),
                                     small_to_double(_mm256_and_si256(m, bci(0xFFFFFFFFULL))));
    const __m256i off = _mm256_sub_epi64(_mm256_castpd_si256(dm), bci(kOffBits + (uint64_t(53) << 52)));
    const __m256i idx = _mm256_slli_epi64(_mm256_and_si256(_mm256_srli_epi64(off, kPieceShift), bci(127)), 2);
    const double* base = &kPieces.at[0].c;
    const __m256d c = gather(base, idx), inv_c = gather(base + 1, idx);
    const __m256d ln_c = gather(base + 2, idx);
    const __m256i z_bits = _mm256_add_epi64(_mm256_and_si256(off, bci((uint64_t(1) << 52) - 1)), bci(kOffBits));
    const __m256d r = _mm256_mul_pd(_mm256_sub_pd(_mm256_castsi256_pd(z_bits), c), inv_c);
    // e = int64(off) >> 52 (arithmetic): the top 12 bits sign-extended; double(e) by the 1.5 2^52 trick.
    const __m256i e12 = _mm256_srli_epi64(off, 52);
    const __m256i e = _mm256_sub_epi64(_mm256_xor_si256(e12, bci(0x800)), bci(0x800));
    const __m256d de =
        _mm256_sub_pd(_mm256_castsi256_pd(_mm256_add_epi64(e, bci(0x4338000000000000ULL))), bc(0x1.8p52));
    const __m256d r2 = _mm256_mul_pd(r, r);
    const __m256d q = _mm256_add_pd(
        _mm256_add_pd(bc(-0.5), _mm256_mul_pd(bc(0.33333333332293896), r)),
        _mm256_mul_pd(r2,
                      _mm256_add_pd(_mm256_add_pd(bc(-0.24999999999090491), _mm256_mul_pd(bc(0.20000272481609913), r)),
                                    _mm256_mul_pd(r2, bc(-0.16666905088156186)))));
    const __m256d l1p = _mm256_add_pd(r, _mm256_mul_pd(r2, q));
    return _mm256_sub_pd(_mm256_sub_pd(_mm256_mul_pd(de, bc(-kLn2)), ln_c), l1p);
}
inline __m256d dot3(__m256d ax, __m256d ay, __m256d az, __m256d bx, __m256d by, __m256d bz) {
    return _mm256_add_pd(_mm256_add_pd(_mm256_mul_pd(ax, bx), _mm256_mul_pd(ay, by)), _mm256_mul_pd(az, bz));
}
// DirectionFrame::renormalize in the lanes of `mask` (orthonormal_basis, Duff et al. 2017).
inline void renormalize4(Lanes& L, __m256d mask) {
    const __m256d k = _mm256_sub_pd(bc(1.5), _mm256_mul_pd(bc(0.5), dot3(L.nx, L.ny, L.nz, L.nx, L.ny, L.nz)));
    const __m256d x = _mm256_mul_pd(L.nx, k), y = _mm256_mul_pd(L.ny, k), z = _mm256_mul_pd(L.nz, k);
    const __m256d sign = _mm256_or_pd(_mm256_and_pd(z, bc(-0.0)), bc(1.0));
    const __m256d a = _mm256_div_pd(bc(-1.0), _mm256_add_pd(sign, z));
    const __m256d c = _mm256_mul_pd(_mm256_mul_pd(x, y), a);
    const __m256d sx = _mm256_mul_pd(sign, x);
    auto set = [&](__m256d& dst, __m256d v) { dst = _mm256_blendv_pd(dst, v, mask); };
    set(L.tx, _mm256_add_pd(bc(1.0), _mm256_mul_pd(_mm256_mul_pd(sx, x), a)));
    set(L.ty, _mm256_mul_pd(sign, c));
    set(L.tz, _mm256_mul_pd(_mm256_xor_pd(sign, bc(-0.0)), x));
    set(L.bx, c);
    set(L.by, _mm256_add_pd(sign, _mm256_mul_pd(_mm256_mul_pd(y, y), a)));
    set(L.bz, _mm256_xor_pd(y, bc(-0.0)));
    set(L.nx, x);
    set(L.ny, y);
    set(L.nz, z);
}
// HenyeyGreenstein::scatter (phase.h), lane-wise.
inline void scatter4(Lanes& L, __m256i bits, const HenyeyGreenstein& hg) {
    const double g = hg.g(), one_minus_g2 = 1 - g * g, one_minus_g = 1 - g, two_g = 2 * g, one_plus_g2 = 1 + g * g;
    const __m256d k = small_to_double(_mm256_srli_epi64(bits, 32));
    const __m256d sq =
        _mm256_div_pd(bc(one_minus_g2), _mm256_add_pd(bc(one_minus_g), _mm256_mul_pd(k, bc(two_g * 0x1.0p-32))));
    const __m256d c0 = _mm256_div_pd(_mm256_sub_pd(bc(one_plus_g2), _mm256_mul_pd(sq, sq)), bc(two_g));
    const __m256d ct = _mm256_max_pd(_mm256_min_pd(c0, bc(1.0)), bc(-1.0));
    const __m256d st = _mm256_sqrt_pd(_mm256_mul_pd(_mm256_sub_pd(bc(1.0), ct), _mm256_add_pd(bc(1.0), ct)));
    // azimuth_from_bits: sector from the top 8 of the low 32 bits, offset from the low 24.
    const __m256i sector = _mm256_slli_epi64(_mm256_and_si256(_mm256_srli_epi64(bits, 24), bci(255)), 1);
    const double* tab = &azimuth_detail::kSectors.at[0].c;
    const __m256d ac = gather(tab, sector), as = gather(tab + 1, sector);
    const __m256d delta = _mm256_mul_pd(
        _mm256_sub_pd(small_to_double(_mm256_and_si256(bits, bci(0xFFFFFF))), bc(double(int32_t(1) << 23))),
        bc(2 * kPi * 0x1.0p-32));
    const __m256d w = _mm256_mul_pd(delta, delta);
    const __m256d sin_d =
        _mm256_add_pd(delta, _mm256_mul_pd(_mm256_mul_pd(delta, w),
                                           _mm256_add_pd(bc(double(-1) / 6), _mm256_mul_pd(w, bc(double(1) / 120)))));
    const __m256d m = _mm256_mul_pd(
        w, _mm256_add_pd(bc(double(1) / 2),
                         _mm256_mul_pd(w, _mm256_sub_pd(_mm256_mul_pd(w, bc(double(1) / 720)), bc(double(1) / 24)))));
    const __m256d cp = _mm256_sub_pd(ac, _mm256_add_pd(_mm256_mul_pd(ac, m), _mm256_mul_pd(as, sin_d)));
    const __m256d sp = _mm256_add_pd(as, _mm256_sub_pd(_mm256_mul_pd(ac, sin_d), _mm256_mul_pd(as, m)));
    // DirectionFrame::turn
    const __m256d e1x = _mm256_add_pd(_mm256_mul_pd(L.tx, cp), _mm256_mul_pd(L.bx, sp));
    const __m256d e1y = _mm256_add_pd(_mm256_mul_pd(L.ty, cp), _mm256_mul_pd(L.by, sp));
    const __m256d e1z = _mm256_add_pd(_mm256_mul_pd(L.tz, cp), _mm256_mul_pd(L.bz, sp));
    L.bx = _mm256_sub_pd(_mm256_mul_pd(L.bx, cp), _mm256_mul_pd(L.tx, sp));
    L.by = _mm256_sub_pd(_mm256_mul_pd(L.by, cp), _mm256_mul_pd(L.ty, sp));
    L.bz = _mm256_sub_pd(_mm256_mul_pd(L.bz, cp), _mm256_mul_pd(L.tz, sp));
    L.tx = _mm256_sub_pd(_mm256_mul_pd(e1x, ct), _mm256_mul_pd(L.nx, st));
    L.ty = _mm256_sub_pd(_mm256_mul_pd(e1y, ct), _mm256_mul_pd(L.ny, st));
    L.tz = _mm256_sub_pd(_mm256_mul_pd(e1z, ct), _mm256_mul_pd(L.nz, st));
    L.nx = _mm256_add_pd(_mm256_mul_pd(L.nx, ct), _mm256_mul_pd(e1x, st));
    L.ny = _mm256_add_pd(_mm256_mul_pd(L.ny, ct), _mm256_mul_pd(e1y, st));
    L.nz = _mm256_add_pd(_mm256_mul_pd(L.nz, ct), _mm256_mul_pd(e1z, st));
    L.count = _mm256_add_epi64(L.count, bci(1));
    const __m256i due = _mm256_cmpeq_epi64(_mm256_and_si256(L.count, bci(DirectionFrame::kRenormalizeEvery - 1)),
                                           _mm256_setzero_si256());
    if (__builtin_expect(!_mm256_testz_si256(due, due), 0)) renormalize4(L, _mm256_castsi256_pd(due));
}

inline void lanes_step(Lanes& L, const HenyeyGreenstein& hg, const Vec3& ep, const Vec3& ei) {
    const __m256d s = _mm256_div_pd(L.tau, bc(kMutCm));
    L.px = _mm256_add_pd(L.px, _mm256_mul_pd(L.nx, s));
    L.py = _mm256_add_pd(L.py, _mm256_mul_pd(L.ny, s));
    L.pz = _mm256_add_pd(L.pz, _mm256_mul_pd(L.nz, s));
    const __m256d left = _mm256_sub_pd(L.budget, _mm256_add_pd(s, bc(kSlack)));
    L.budget = _mm256_blendv_pd(bc(1e300), left, _mm256_cmp_pd(left, _mm256_setzero_pd(), _CMP_GT_OQ));
    // The seed tissue is in cm: the engine's depth * unit_cm is * 1, exact, so left out here as in scalar_step.
    const __m256d v = dot3(_mm256_sub_pd(L.px, bc(ep.x)), _mm256_sub_pd(L.py, bc(ep.y)), _mm256_sub_pd(L.pz, bc(ep.z)),
                           bc(ei.x), bc(ei.y), bc(ei.z));
    L.depth = _mm256_max_pd(v, L.depth);  // std::max(depth, v): depth < v ? v : depth
    const __m256d dW = _mm256_mul_pd(L.W, bc(kLoss));
    L.W = _mm256_sub_pd(L.W, dW);
    L.absorbed = _mm256_add_pd(L.absorbed, dW);
    L.W = _mm256_blendv_pd(L.W, bc(1.0), _mm256_cmp_pd(L.W, bc(kRefill), _CMP_LT_OQ));
    scatter4(L, next_u64(L), hg);
    L.tau = neg_log_lattice4(_mm256_add_epi64(_mm256_srli_epi64(next_u64(L), 11), bci(1)));
}

// ---- lane <-> packet ----
template <class T, class V>
T lane(V v, int i) {
    T out[4];
    std::memcpy(out, &v, sizeof out);
    return out[i];
}
template <class T, class V>
void set_lane(V& v, int i, T x) {
    T a[4];
    std::memcpy(a, &v, sizeof a);
    a[i] = x;
    std::memcpy(&v, a, sizeof a);
}

void load(Lanes& L, int i, const Scalar& q) {
    uint64_t s[4];
    std::memcpy(s, &q.rng, sizeof s);  // the generator's state (Rng holds only s_[4])
    set_lane<uint64_t>(L.s0, i, s[0]);
    set_lane<uint64_t>(L.s1, i, s[1]);
    set_lane<uint64_t>(L.s2, i, s[2]);
    set_lane<uint64_t>(L.s3, i, s[3]);
    set_lane<uint64_t>(L.count, i, q.scatterings);
    const double* f[] = {&q.p[0],       &q.p[1],       &q.p[2],       &q.frame.t[0], &q.frame.t[1], &q.frame.t[2],
                         &q.frame.b[0], &q.frame.b[1], &q.frame.b[2], &q.frame.n[0], &q.frame.n[1], &q.frame.n[2]};
    __m256d* d[] = {&L.px, &L.py, &L.pz, &L.tx, &L.ty, &L.tz, &L.bx, &L.by, &L.bz, &L.nx, &L.ny, &L.nz};
    for (int k = 0; k < 12; ++k) set_lane<double>(*d[k], i, *f[k]);
    set_lane<double>(L.W, i, q.W);
    set_lane<double>(L.tau, i, q.tau);
    set_lane<double>(L.absorbed, i, q.absorbed);
    set_lane<double>(L.depth, i, q.depth);
    set_lane<double>(L.budget, i, q.budget);
}
bool same(const Lanes& L, int i, const Scalar& q) {
    uint64_t s[4];
    std::memcpy(s, &q.rng, sizeof s);
    bool ok = lane<uint64_t>(L.s0, i) == s[0] && lane<uint64_t>(L.s3, i) == s[3];
    const double want[] = {q.p[0],       q.p[1],       q.p[2],       q.frame.t[0], q.frame.t[1], q.frame.t[2],
                           q.frame.b[0], q.frame.b[1], q.frame.b[2], q.frame.n[0], q.frame.n[1], q.frame.n[2],
                           q.W,          q.tau,        q.absorbed,   q.depth,      q.budget};
    const __m256d got[] = {L.px, L.py, L.pz, L.tx, L.ty,  L.tz,       L.bx,    L.by,    L.bz,
                           L.nx, L.ny, L.nz, L.W,  L.tau, L.absorbed, L.depth, L.budget};
    for (int k = 0; k < 17; ++k) {
        const double g = lane<double>(got[k], i);
        ok = ok && std::memcmp(&g, &want[k], sizeof g) == 0;
    }
    return ok;
}

}  // namespace

int main(int argc, char** argv) {
    const long steps = argc > 1 ? std::atol(argv[1]) : 2000000;
    const std::string mode = argc > 2 ? argv[2] : "both";
    const HenyeyGreenstein hg(kG);
    const Vec3 ep(0, 0, 0), ei(0, 0, -1);
    Scalar q[4];
    Lanes L;
    std::memset(&L, 0, sizeof L);
    for (int i = 0; i < 4; ++i) load(L, i, q[i] = start(i));
    // Thread CPU time (ns): the shared machine's other work is not counted.
    auto now = [] {
        timespec t;
        clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t);
        return (unsigned long long)t.tv_sec * 1000000000ULL + (unsigned long long)t.tv_nsec;
    };
    unsigned long long t_scalar = 0, t_lanes = 0;
    if (mode != "lanes") {
        const unsigned long long t0 = now();
        for (long k = 0; k < steps; ++k)
            for (int i = 0; i < 4; ++i) scalar_step(q[i], hg, ep, ei);
        t_scalar = now() - t0;
    }
    if (mode != "scalar") {
        const unsigned long long t0 = now();
        for (long k = 0; k < steps; ++k) lanes_step(L, hg, ep, ei);
        t_lanes = now() - t0;
    }
    int identical = 0;
    if (mode == "both")
        for (int i = 0; i < 4; ++i) identical += same(L, i, q[i]);
    const double lane_steps = 4.0 * double(steps);
    std::printf(
        "lane-steps %.0f  scalar %.3f ns/step  lanes %.3f ns/lane-step  ratio %.2f  "
        "bit-identical lanes %d/4  (absorbed %.17g)\n",
        lane_steps, t_scalar / lane_steps, t_lanes / lane_steps, t_lanes ? double(t_scalar) / t_lanes : 0.0, identical,
        lane<double>(L.absorbed, 0) + q[0].absorbed);
    return 0;
}
