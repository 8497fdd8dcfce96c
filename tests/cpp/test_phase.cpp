// Scattering directions (native/phase.h, native/vecmath.h): the azimuth from
// 32 random bits (azimuth_from_bits), the frame that scatterings turn
// (DirectionFrame) and HenyeyGreenstein::scatter, which draws both from one
// 64-bit number. Distributions are checked by chi-square tests (shared helper
// stat_util.h, p = 0.001) against the analytic ones -- phi uniform on
// [0, 2 pi), cos(theta) about the old direction distributed as HG, the two
// independent -- and the arithmetic against independent computations
// (std::sin / std::cos, a rotation matrix by Rodrigues' formula).
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>

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
// Gram-Schmidt from the x or y axis (independent of the engine's frames), in [0, 1) turns.
double azimuth_turns(const Vec3& n, const Vec3& v) {
    const Vec3 ref0 = std::fabs(n.x) < 0.9 ? Vec3(1, 0, 0) : Vec3(0, 1, 0);
    const Vec3 e1 = normalize(ref0 - n * dot(ref0, n)), e2 = cross(n, e1);
    const double a = std::atan2(dot(v, e2), dot(v, e1)) / (2 * kPi);
    return a < 0 ? a + 1 : a;
}

// A pair (a, b) in [0, 1)^2 as the centre of its cell in a k x k grid, scaled
// to [0, 1): a uniform pair gives a uniform cell number (a 2-D test in 1-D bins).
double cell(double a, double b, int k) {
    const int i = std::min(int(a * k), k - 1), j = std::min(int(b * k), k - 1);
    return (double(i * k + j) + 0.5) / double(k * k);
}

// Rotation of v by the angle a about the unit axis k (Rodrigues' formula).
Vec3 rotate(const Vec3& v, const Vec3& k, double a) {
    return v * std::cos(a) + cross(k, v) * std::sin(a) + k * (dot(k, v) * (1 - std::cos(a)));
}

// The largest departure of a frame from orthonormal.
double frame_error(const DirectionFrame& f) {
    double e = 0;
    for (const Vec3& v : {f.tangent(), f.bitangent(), f.dir()}) e = std::max(e, std::fabs(dot(v, v) - 1));
    e = std::max({e, std::fabs(dot(f.tangent(), f.bitangent())), std::fabs(dot(f.tangent(), f.dir())),
                  std::fabs(dot(f.bitangent(), f.dir()))});
    return e;
}

}  // namespace

// The azimuth's arithmetic: (cos, sin) of 2 pi v / 2^32 against std::cos and
// std::sin (long double angle) for random v, and for the ends and centres of
// all 256 sectors of the table, where the offset is largest or zero.
TEST(Azimuth, FromBitsMatchesLibmToAFewUlps) {
    double worst = 0;
    auto check = [&](uint32_t v) {
        Float s, c;
        azimuth_from_bits(v, &s, &c);
        const long double phi = 2 * 3.141592653589793238462643383279502884L * v / 4294967296.0L;
        worst = std::max({worst, double(std::fabs(c - std::cos(phi))), double(std::fabs(s - std::sin(phi)))});
        ASSERT_NEAR(s * s + c * c, 1.0, 1e-15);
    };
    Rng rng(3, 1);
    for (int i = 0; i < 2000000; ++i) check(uint32_t(rng.next_u64()));
    for (uint32_t sector = 0; sector < 256; ++sector)
        for (uint32_t offset : {0u, 1u, 0x7FFFFFu, 0x800000u, 0x800001u, 0xFFFFFFu}) check((sector << 24) | offset);
    EXPECT_LT(worst, 4e-16);
    std::printf("max error of azimuth_from_bits: %.3g\n", worst);
}

TEST(Azimuth, FromBitsIsUniform) {
    Rng rng(5, 1);
    ep_test::expect_chi_square_fit(
        [&](std::mt19937_64&) {
            Float s, c;
            azimuth_from_bits(uint32_t(rng.next_u64()), &s, &c);
            const double a = std::atan2(s, c) / (2 * kPi);
            return a < 0 ? a + 1 : a;
        },
        equal_bins, 0.0, 1.0, 1000, 2000000, 0);
}

// One turn of the frame against an independent construction: phi about n
// from t (a rotation about n), then theta towards the turned t (a rotation
// about n x turned-t), both by Rodrigues' formula.
TEST(DirectionFrame, TurnIsTheRotationByThetaAndPhi) {
    Rng rng(9, 4);
    for (const Vec3 axis : {normalize(Vec3(0.48, 0.6, 0.64)), Vec3(0, 0, 1), Vec3(0, 0, -1),
                            normalize(Vec3(1e-9, 0, -1)), normalize(Vec3(-0.3, 0.9, 0.1))}) {
        for (int i = 0; i < 1000; ++i) {
            const double theta = kPi * rng.uniform(), phi = 2 * kPi * rng.uniform();
            DirectionFrame f(axis);
            const Vec3 t0 = f.tangent();
            f.turn(std::cos(theta), std::sin(theta), std::cos(phi), std::sin(phi));
            const Vec3 e1 = rotate(t0, axis, phi);
            const Vec3 want = rotate(axis, cross(axis, e1), theta);
            EXPECT_NEAR(f.dir().x, want.x, 2e-15);
            EXPECT_NEAR(f.dir().y, want.y, 2e-15);
            EXPECT_NEAR(f.dir().z, want.z, 2e-15);
            EXPECT_NEAR(std::acos(std::clamp(dot(f.dir(), axis), -1.0, 1.0)), theta, 1e-7);
            ASSERT_LT(frame_error(f), 1e-15);
        }
    }
}

// A long chain of scatterings (g = 0.9, 1e6 of them): between two
// renormalisations the frame drifts at most linearly (each turn adds a few
// roundings), so it stays orthonormal to 1e-14; and each scattering's
// cosine to the previous direction is HG, its azimuth about it (from an
// independent reference) uniform, and the two independent -- although the
// frame that measures the engine's phi is a function of the whole history.
TEST(DirectionFrame, ChainedScatteringsStayOrthonormalAndFollowHg) {
    const double g = 0.9;
    const HenyeyGreenstein hg(g);
    Rng rng(8, 2);
    DirectionFrame f(normalize(Vec3(0.2, -0.5, 0.7)));
    uint32_t count = 0;
    double worst = 0;
    auto step = [&] {
        const Vec3 before = f.dir();
        hg.scatter(rng.next_u64(), ++count, &f);
        worst = std::max(worst, frame_error(f));
        if (count % DirectionFrame::kRenormalizeEvery == 0) EXPECT_LT(std::fabs(dot(f.dir(), f.dir()) - 1), 5e-16);
        return std::make_pair(dot(f.dir(), before), azimuth_turns(before, f.dir()));
    };
    ep_test::expect_chi_square_fit([&](std::mt19937_64&) { return step().first; },
                                   [&](double a, double b) { return hg_cdf(g, b) - hg_cdf(g, a); }, -1.0, 1.0, 200,
                                   300000, 0);
    ep_test::expect_chi_square_fit([&](std::mt19937_64&) { return step().second; }, equal_bins, 0.0, 1.0, 200, 300000,
                                   0);
    // Joint: the HG CDF of the cosine and the azimuth, a uniform pair.
    ep_test::expect_chi_square_fit(
        [&](std::mt19937_64&) {
            const auto [c, a] = step();
            return cell(std::clamp(hg_cdf(g, c), 0.0, 1.0), a, 20);
        },
        equal_bins, 0.0, 1.0, 400, 400000, 0);
    EXPECT_LT(worst, 1e-14);
    std::printf("max departure from orthonormal over %u scatterings: %.3g\n", count, worst);
}

// scatter about fixed axes, including the poles where the basis switches
// sign: the new direction is unit, its cosine to the axis is HG, its azimuth uniform.
TEST(DirectionFrame, ScatterAboutFixedAxesFollowsHgAndAUniformAzimuth) {
    for (const double g : {0.9, -0.5, 0.0}) {
        const HenyeyGreenstein hg(g);
        for (const Vec3 axis :
             {normalize(Vec3(0.48, 0.6, 0.64)), Vec3(0, 0, 1), Vec3(0, 0, -1), normalize(Vec3(1e-9, 0, -1))}) {
            Rng rng(8, 3);
            auto scatter = [&] {
                DirectionFrame f(axis);
                hg.scatter(rng.next_u64(), 1, &f);
                EXPECT_NEAR(dot(f.dir(), f.dir()), 1.0, 1e-15);
                return f.dir();
            };
            const auto cdf = [&](double m) { return g == 0 ? (m + 1) / 2 : hg_cdf(g, m); };
            ep_test::expect_chi_square_fit([&](std::mt19937_64&) { return dot(scatter(), axis); },
                                           [&](double a, double b) { return cdf(b) - cdf(a); }, -1.0, 1.0, 200, 200000,
                                           0);
            ep_test::expect_chi_square_fit([&](std::mt19937_64&) { return azimuth_turns(axis, scatter()); }, equal_bins,
                                           0.0, 1.0, 100, 200000, 0);
        }
    }
}

// |g| = 1 are deltas: the frame's direction is kept, or reversed, exactly.
TEST(DirectionFrame, DeltaPhaseFunctionsKeepOrReverseTheDirectionExactly) {
    const Vec3 d = normalize(Vec3(0.3, -0.4, 0.5));
    Rng rng(2, 2);
    for (int i = 0; i < 100; ++i) {
        DirectionFrame f(d), b(d);
        HenyeyGreenstein(1.0).scatter(rng.next_u64(), 1, &f);
        HenyeyGreenstein(-1.0).scatter(rng.next_u64(), 1, &b);
        EXPECT_TRUE(f.about(d));
        EXPECT_TRUE(b.about(-d));
    }
}

// scatter's arithmetic is the plain one, bit for bit: the cosine from the
// lattice constant 2g 2^-32 is sample_cos(k 2^-32), sin(theta) is
// std::sqrt((1 - c)(1 + c)), and the turn uses azimuth_from_bits' (cos, sin),
// for every kind of phase function.
TEST(HenyeyGreenstein, ScatterIsThePlainArithmeticBitForBit) {
    Rng rng(5, 6);
    const Vec3 axis = normalize(Vec3(0.48, -0.6, 0.64));
    for (const double g : {0.9, -0.5, 0.3, 1e-3, 0.0, 1.0, -1.0}) {
        const HenyeyGreenstein hg(g);
        for (int i = 0; i < 100000; ++i) {
            const uint64_t bits = rng.next_u64();
            DirectionFrame got(axis), want(axis);
            hg.scatter(bits, 1, &got);
            const double c = hg.sample_cos(double(bits >> 32) * 0x1.0p-32);
            double sin_phi, cos_phi;
            azimuth_from_bits(uint32_t(bits), &sin_phi, &cos_phi);
            want.turn(c, std::sqrt((1 - c) * (1 + c)), cos_phi, sin_phi);
            for (int k = 0; k < 3; ++k) {
                ASSERT_EQ(std::memcmp(&got.n[k], &want.n[k], sizeof(double)), 0) << g << " " << i;
                ASSERT_EQ(std::memcmp(&got.t[k], &want.t[k], sizeof(double)), 0) << g << " " << i;
                ASSERT_EQ(std::memcmp(&got.b[k], &want.b[k], sizeof(double)), 0) << g << " " << i;
            }
        }
    }
}

// min_select, max_select and sqrt_nonneg (vecmath.h, one instruction each)
// give the bits of x < y ? x : y, x > y ? x : y and std::sqrt, signed zeros,
// infinities, NaN and subnormals included.
TEST(Vecmath, SelectsAndSqrtAreThePlainExpressions) {
    const double inf = std::numeric_limits<double>::infinity(), nan = std::numeric_limits<double>::quiet_NaN();
    const double values[] = {0.0, -0.0, 1.0, -1.0, 0.5, -2.5, 1e-310, -1e-310, 1e300, inf, -inf, nan, 1 + 0x1.0p-52};
    auto same = [](double a, double b) { return std::memcmp(&a, &b, sizeof a) == 0; };
    for (const double x : values) {
        for (const double y : values) {
            EXPECT_TRUE(same(min_select(x, y), x < y ? x : y)) << x << " " << y;
            EXPECT_TRUE(same(max_select(x, y), x > y ? x : y)) << x << " " << y;
        }
        if (x >= 0) EXPECT_TRUE(same(sqrt_nonneg(x), std::sqrt(x))) << x;
    }
    Rng rng(3, 1);
    for (int i = 0; i < 100000; ++i) {
        const double x = rng.uniform() * 4 - 2, y = rng.uniform() * 4 - 2;
        ASSERT_TRUE(same(min_select(x, y), x < y ? x : y));
        ASSERT_TRUE(same(max_select(x, y), x > y ? x : y));
        ASSERT_TRUE(same(sqrt_nonneg(x * x), std::sqrt(x * x)));
    }
}
