// Henyey–Greenstein phase function (Henyey & Greenstein 1941), the seed's
// scattering model (§4) and MCML's. Interface after pbrt-v4: p, sample_p, pdf (both per
// steradian, as in pbrt), plus pdf_cos, the density per unit cos(theta) that MCML's sampling uses.
#pragma once
#include <cmath>
#include <cstdint>

#include "vecmath.h"

namespace ep {

namespace azimuth_detail {

struct CosSin {
    double c = 0, s = 0;
};

// cos and sin of m pi / 256 for an odd m in [1, 511], at compile time: m is
// reduced by whole quarter turns (exact: integers) to |m'| <= 63, where the
// Taylor series of the angle (|x| <= 0.78) are summed until their terms
// fall below 1e-20; then the quarter turns are exact swaps and negations.
// Each entry is within about one unit in the last place.
constexpr CosSin cos_sin_of_odd_256th(int m) {
    const int q = (m + 64) / 128;  // nearest quarter turn (|m - 128 q| < 64)
    const double x = (m - 128 * q) * (3.14159265358979323846 / 256);
    double c = 1, s = x, term_c = 1, term_s = x;
    for (int k = 1; k < 20; ++k) {
        term_c *= -x * x / ((2 * k - 1) * (2 * k));
        term_s *= -x * x / ((2 * k) * (2 * k + 1));
        c += term_c;
        s += term_s;
    }
    switch (q % 4) {
        case 0:
            return {c, s};
        case 1:
            return {-s, c};
        case 2:
            return {-c, -s};
        default:
            return {s, -c};
    }
}

// The azimuths 2 pi (i + 1/2) / 256 of the centres of 256 equal sectors.
struct SectorTable {
    CosSin at[256];
    constexpr SectorTable() {
        for (int i = 0; i < 256; ++i) at[i] = cos_sin_of_odd_256th(2 * i + 1);
    }
};
// Internal linkage (no inline): addressed directly, not through the GOT.
constexpr SectorTable kSectors{};

}  // namespace azimuth_detail

// A uniform azimuth phi = 2 pi v / 2^32 from 32 random bits v, as (sin phi,
// cos phi): one draw, no branch and no libm call (the disc rejection it
// replaces took 2.55 draws and a mispredicted loop exit one step in five).
// The top 8 bits pick a sector, whose centre's cosine and sine come from a
// table (kSectors); the low 24 bits give the offset delta from that centre,
// an exact integer in [-2^23, 2^23) times 2 pi / 2^32, so |delta| <= pi/256.
// cos delta - 1 and sin delta are their Taylor polynomials to delta^6 and
// delta^5 (remainders below 2e-20 and 9e-18), and the angle-addition formulas
// add the offset, written as a small correction to the centre's (cos, sin).
// Max error against std::cos / std::sin: see tests/cpp/test_phase.cpp.
// Always inline, as DirectionFrame's constructor and TriangleCache::covers:
// when the lanes' walk for spectral packets joined transport.cpp, GCC kept
// these three out of line, and the seed tissue ran 4 % slower.
inline __attribute__((always_inline)) void azimuth_from_bits(uint32_t v, Float* sin_phi, Float* cos_phi) {
    const azimuth_detail::CosSin& a = azimuth_detail::kSectors.at[v >> 24];
    const Float delta = Float(int32_t(v & 0xFFFFFFu) - (int32_t(1) << 23)) * (2 * kPi * 0x1.0p-32);
    const Float w = delta * delta;
    const Float sin_d = delta + (delta * w) * (Float(-1) / 6 + w * (Float(1) / 120));
    // m = 1 - cos delta = w (1/2 - w (1/24 - w / 720)), the signs written so
    // that no constant is a minuend (a - b = -(b - a) exactly): the bits of
    // cos delta - 1 negated, one register load fewer.
    const Float m = w * (Float(1) / 2 + w * (w * (Float(1) / 720) - Float(1) / 24));
    *cos_phi = a.c - (a.c * m + a.s * sin_d);
    *sin_phi = a.s + (a.c * sin_d - a.s * m);
}

class HenyeyGreenstein {
  public:
    // The constants of sample_cos are computed once here: the same
    // subexpressions, so the samples are bit-identical to evaluating them
    // at every call.
    explicit HenyeyGreenstein(Float g)
        : g_(g),
          kind_(g >= 1                ? Kind::kForward
                : g <= -1             ? Kind::kBackward
                : std::fabs(g) < 1e-6 ? Kind::kIsotropic
                                      : Kind::kHG),
          one_minus_g2_(1 - g * g),
          one_minus_g_(1 - g),
          two_g_(2 * g),
          one_plus_g2_(1 + g * g),
          two_g_lattice_(two_g_ * 0x1.0p-32) {}
    Float g() const { return g_; }

    // Density per unit cos(theta) on [-1, 1] (not per steradian):
    // p_cos(cos) = (1 - g^2) / (2 (1 + g^2 - 2 g cos)^(3/2)), normalised to 1 over cos.
    Float pdf_cos(Float cos_theta) const {
        if (g_ >= 1 || g_ <= -1) return 0;  // a delta: no finite density
        const Float denom = 1 + g_ * g_ - 2 * g_ * cos_theta;
        return (1 - g_ * g_) / (2 * denom * std::sqrt(denom));
    }
    // Phase function per steradian (pbrt-v4's p): the cos-density over 2*pi, the azimuth being uniform.
    Float p(Float cos_theta) const { return pdf_cos(cos_theta) / (2 * kPi); }
    // pbrt-v4's pdf of sample_p, per steradian: sample_p draws exactly from p, so pdf == p.
    Float pdf(Float cos_theta) const { return p(cos_theta); }

    // Inverse CDF (MCML manual eq. 3.28). It divides by 2g, so g -> 0 uses the
    // exact isotropic branch; |g| = 1 are deltas (no deflection / reversal).
    Float sample_cos(Float u) const {
        if (likely_hg()) return hg_cos(two_g_ * u);
        if (kind_ == Kind::kForward) return 1;
        if (kind_ == Kind::kBackward) return -1;
        return 2 * u - 1;
    }

    // New direction about `dir`: cosine from HG, the azimuth given as
    // (sin phi, cos phi) of a uniform phi (azimuth_from_bits).
    Vec3 sample_p(const Vec3& dir, Float u_cos, Float sin_phi, Float cos_phi) const {
        const Float cos_theta = sample_cos(u_cos);
        if (cos_theta >= 1) return dir;
        if (cos_theta <= -1) return -dir;
        return spherical_about(dir, cos_theta, sin_phi, cos_phi);
    }

    // One scattering of the direction frame->n (seed §4) from one 64-bit draw:
    // u for sample_cos from its high 32 bits (the cosine's CDF on a lattice of
    // 2^-32, far finer than any Monte Carlo resolution), the azimuth from its
    // low 32 bits (azimuth_from_bits; xoshiro256++ is good in all bits). The
    // frame turns instead of being rebuilt (DirectionFrame::turn); `count`
    // numbers the packet's scatterings, and every kRenormalizeEvery-th
    // renormalises it, which bounds its drift from orthonormal to a few units
    // in the last place (tests/cpp/test_phase.cpp). The samples depend only on
    // the bits, the frame and count, so a packet scattered by any caller with
    // the same frame gets the same direction. Always inline: with the grid
    // runs' interior loops GCC had more callers and called it out of line in
    // the general loop (callgrind, seed tissue: 14,862 -> 15,193 instructions
    // a packet, 14,794 so).
    __attribute__((always_inline)) void scatter(uint64_t bits, uint32_t count, DirectionFrame* frame) const {
        // 2g u for u = k 2^-32 as k (2g 2^-32): both are the exact 2g k 2^-32
        // rounded once (2g 2^-32 is exact), one multiplication fewer.
        const uint32_t k = uint32_t(bits >> 32);
        const Float cos_theta = likely_hg() ? hg_cos(Float(k) * two_g_lattice_) : sample_cos(Float(k) * 0x1.0p-32);
        // (1 - c)(1 + c): no cancellation near c = 1 (1 - c is exact there).
        // Both factors are >= 0 for cos_theta in [-1, 1].
        const Float sin_theta = sqrt_nonneg((1 - cos_theta) * (1 + cos_theta));
        Float sin_phi, cos_phi;
        azimuth_from_bits(uint32_t(bits), &sin_phi, &cos_phi);
        frame->turn(cos_theta, sin_theta, cos_phi, sin_phi);
        if (count % DirectionFrame::kRenormalizeEvery == 0) frame->renormalize();
    }

  private:
    enum class Kind { kHG, kForward, kBackward, kIsotropic };
    // The HG cosine from two_g_u = 2 g u: s = (1 - g^2) / (1 - g + 2 g u),
    // cos = (1 + g^2 - s^2) / (2 g), clamped to [-1, 1] (rounding) as
    // minsd/maxsd, not branches.
    Float hg_cos(Float two_g_u) const {
        const Float s = one_minus_g2_ / (one_minus_g_ + two_g_u);
        const Float c = (one_plus_g2_ - s * s) / two_g_;
        return max_select(min_select(c, 1), -1);
    }
    // The HG branch is the common one: laid out on the straight path.
    bool likely_hg() const {
#if defined(__GNUC__)
        return __builtin_expect(kind_ == Kind::kHG, 1);
#else
        return kind_ == Kind::kHG;
#endif
    }
    Float g_;
    Kind kind_;
    Float one_minus_g2_, one_minus_g_, two_g_, one_plus_g2_, two_g_lattice_;
};

}  // namespace ep
