// Scattering directions (native/phase.h): the azimuth drawn by disc rejection
// and the new direction of sample_p, checked by chi-square tests (shared
// helper, p = 0.001) against the analytic distributions: phi uniform on
// [0, 2 pi), cos(theta) about the old direction distributed as HG.
#include <gtest/gtest.h>

#include <cmath>

#include "phase.h"
#include "rng.h"
#include "stat_util.h"

using namespace ep;

namespace {

// HG CDF over cos(theta), integrated by hand from the density (phase.h's pdf_cos):
// F(m) = (1 - g^2) / (2 g) (1 / sqrt(1 + g^2 - 2 g m) - 1 / (1 + g)).
double hg_cdf(double g, double m) {
    return (1 - g * g) / (2 * g) * (1 / std::sqrt(1 + g * g - 2 * g * m) - 1 / (1 + g));
}

double equal_bins(double a, double b) { return b - a; }

// Angle of v about the axis n, measured from a reference direction built by
// Gram-Schmidt from the x or y axis (independent of the engine's basis), in [0, 1) turns.
double azimuth_turns(const Vec3& n, const Vec3& v) {
    const Vec3 ref0 = std::fabs(n.x) < 0.9 ? Vec3(1, 0, 0) : Vec3(0, 1, 0);
    const Vec3 e1 = normalize(ref0 - n * dot(ref0, n)), e2 = cross(n, e1);
    const double a = std::atan2(dot(v, e2), dot(v, e1)) / (2 * kPi);
    return a < 0 ? a + 1 : a;
}

}  // namespace

TEST(Azimuth, DiscRejectionGivesAUniformUnitAngle) {
    Rng rng(5, 1);
    auto uniform = [&] { return rng.uniform(); };
    ep_test::expect_chi_square_fit(
        [&](std::mt19937_64&) {
            Float s, c;
            sample_azimuth(uniform, &s, &c);
            EXPECT_NEAR(s * s + c * c, 1.0, 1e-15);  // a few roundings
            const double a = std::atan2(s, c) / (2 * kPi);
            return a < 0 ? a + 1 : a;
        },
        equal_bins, 0.0, 1.0, 360, 1000000, 0);
}

// sample_p about a few axes, including the poles where the basis switches
// sign: the new direction is unit, its cosine to the axis is HG, its azimuth uniform.
TEST(Azimuth, ScatteredDirectionsFollowHgAndAUniformAzimuth) {
    const double g = 0.9;
    const HenyeyGreenstein hg(g);
    for (const Vec3 axis :
         {normalize(Vec3(0.48, 0.6, 0.64)), Vec3(0, 0, 1), Vec3(0, 0, -1), normalize(Vec3(1e-9, 0, -1))}) {
        Rng rng(8, 2);
        auto uniform = [&] { return rng.uniform(); };
        auto scatter = [&] {
            const Float u = rng.uniform();
            Float s, c;
            sample_azimuth(uniform, &s, &c);
            const Vec3 d = hg.sample_p(axis, u, s, c);
            EXPECT_NEAR(dot(d, d), 1.0, 1e-15);
            return d;
        };
        ep_test::expect_chi_square_fit([&](std::mt19937_64&) { return dot(scatter(), axis); },
                                       [&](double a, double b) { return hg_cdf(g, b) - hg_cdf(g, a); }, -1.0, 1.0, 200,
                                       200000, 0);
        ep_test::expect_chi_square_fit([&](std::mt19937_64&) { return azimuth_turns(axis, scatter()); }, equal_bins,
                                       0.0, 1.0, 100, 200000, 0);
    }
}
