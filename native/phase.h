// Henyey–Greenstein phase function (Henyey & Greenstein 1941), the seed's
// scattering model (§4) and MCML's. Interface after pbrt-v4: p, sample_p, pdf (both per
// steradian, as in pbrt), plus pdf_cos, the density per unit cos(theta) that MCML's sampling uses.
#pragma once
#include <algorithm>
#include <cmath>

#include "vecmath.h"

namespace ep {

// A uniform azimuth as (sin phi, cos phi) without a sincos call (von Neumann
// 1951): a point (x, y) uniform in the unit disc -- drawn uniform in the square
// [-1, 1]^2 and kept inside the disc, probability pi/4 -- has a uniform polar
// angle a, so phi = 2a is uniform in [0, 2 pi), and by the double-angle
// formulas cos phi = (x^2 - y^2) / r^2, sin phi = 2 x y / r^2 (unit to
// rounding; one division instead of a normalising square root). `uniform`
// returns numbers in [0, 1); it is called 2 / (pi/4) = 2.55 times on average,
// about 40 instructions with the engine's generator against ~130 for sincos.
template <class Uniform>
inline void sample_azimuth(Uniform&& uniform, Float* sin_phi, Float* cos_phi) {
    while (true) {
        const Float x = 2 * uniform() - 1, y = 2 * uniform() - 1;
        const Float r2 = x * x + y * y;
        if (r2 > 1 || r2 < 1e-200) continue;  // outside the disc, or its centre (no angle)
        const Float inv = 1 / r2;
        *cos_phi = (x * x - y * y) * inv;
        *sin_phi = 2 * x * y * inv;
        return;
    }
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
          one_plus_g2_(1 + g * g) {}
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
        if (kind_ == Kind::kHG) {
            // s = (1 - g^2) / (1 - g + 2 g u), cos = (1 + g^2 - s^2) / (2 g).
            const Float s = one_minus_g2_ / (one_minus_g_ + two_g_ * u);
            const Float c = (one_plus_g2_ - s * s) / two_g_;
            return std::clamp(c, Float(-1), Float(1));
        }
        if (kind_ == Kind::kForward) return 1;
        if (kind_ == Kind::kBackward) return -1;
        return 2 * u - 1;
    }

    // New direction about `dir`: cosine from HG, the azimuth given as
    // (sin phi, cos phi) of a uniform phi (sample_azimuth).
    Vec3 sample_p(const Vec3& dir, Float u_cos, Float sin_phi, Float cos_phi) const {
        const Float cos_theta = sample_cos(u_cos);
        if (cos_theta >= 1) return dir;
        if (cos_theta <= -1) return -dir;
        return spherical_about(dir, cos_theta, sin_phi, cos_phi);
    }

  private:
    enum class Kind { kHG, kForward, kBackward, kIsotropic };
    Float g_;
    Kind kind_;
    Float one_minus_g2_, one_minus_g_, two_g_, one_plus_g2_;
};

}  // namespace ep
