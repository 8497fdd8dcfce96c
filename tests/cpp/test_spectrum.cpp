// Tests for ep::Tabulated1D (native/spectrum.h).
//
// References used here are computed independently of the class: integrals by
// hand or by the test's own piecewise-linear integrator, sampling checked by a
// chi-square goodness-of-fit test whose critical value comes from the
// Wilson-Hilferty approximation (Wilson & Hilferty 1931, PNAS 17:684).
#include <gtest/gtest.h>

#include "stat_util.h"

#include <cmath>
#include <cstdint>
#include <functional>
#include <limits>
#include <random>
#include <stdexcept>
#include <string>
#include <vector>

#include "spectrum.h"

namespace {

using namespace ep_test;

using ep::Tabulated1D;

// A shape with every segment kind: rising from 0, flat, falling to 0, a zero
// gap, a steep 1 nm segment, and a decreasing end.
const std::vector<double> kX = {400, 420, 450, 460, 480, 500, 530, 531, 600};
const std::vector<double> kY = {0, 2, 2, 0, 0, 3, 1, 5, 0.5};
// By hand, segment by segment: 20*(0+2)/2 + 30*2 + 10*2/2 + 0 + 20*3/2
// + 30*(3+1)/2 + 1*(1+5)/2 + 69*(5+0.5)/2 = 20 + 60 + 10 + 0 + 30 + 60 + 3 + 189.75.
const double kIntegral = 372.75;

TEST(ChiSquareCritical, WilsonHilfertyMatchesPublishedTableValues) {
    // Published upper 0.1% points of chi-square (e.g. Abramowitz & Stegun,
    // Table 26.8): 10 dof -> 29.588, 30 dof -> 59.703, 100 dof -> 149.449.
    EXPECT_NEAR(chi_square_critical(10, 0.001), 29.588, 0.01 * 29.588);
    EXPECT_NEAR(chi_square_critical(30, 0.001), 59.703, 0.005 * 59.703);
    EXPECT_NEAR(chi_square_critical(100, 0.001), 149.449, 0.002 * 149.449);
}

TEST(Tabulated1D, EvalInterpolatesLinearlyAndIsZeroOutside) {
    const Tabulated1D f(kX, kY, "test.f");
    EXPECT_DOUBLE_EQ(f.eval(400), 0.0);
    EXPECT_DOUBLE_EQ(f.eval(410), 1.0);
    EXPECT_DOUBLE_EQ(f.eval(435), 2.0);
    EXPECT_DOUBLE_EQ(f.eval(455), 1.0);
    EXPECT_DOUBLE_EQ(f.eval(470), 0.0);
    EXPECT_DOUBLE_EQ(f.eval(515), 2.0);
    EXPECT_DOUBLE_EQ(f.eval(530.5), 3.0);
    EXPECT_DOUBLE_EQ(f.eval(600), 0.5);
    EXPECT_DOUBLE_EQ(f.eval(399.999), 0.0);
    EXPECT_DOUBLE_EQ(f.eval(600.001), 0.0);
    EXPECT_DOUBLE_EQ(f.eval(std::numeric_limits<double>::quiet_NaN()), 0.0);
    EXPECT_EQ(f.x_min(), 400.0);
    EXPECT_EQ(f.x_max(), 600.0);
    EXPECT_FALSE(f.is_constant());
}

TEST(Tabulated1D, IntegralMatchesHandComputedTrapezoids) {
    const Tabulated1D f(kX, kY, "test.f");
    EXPECT_NEAR(f.integral(), kIntegral, 1e-12 * kIntegral);
    // A single linear ramp 0 -> 4 over 10 nm: the triangle 10 * 4 / 2 = 20.
    EXPECT_DOUBLE_EQ(Tabulated1D({500, 510}, {0, 4}, "ramp").integral(), 20.0);
}

TEST(Tabulated1D, PdfIsValueOverIntegral) {
    const Tabulated1D f(kX, kY, "test.f");
    EXPECT_NEAR(f.pdf(410), 1.0 / kIntegral, 1e-15);
    EXPECT_NEAR(f.pdf(530.5), 3.0 / kIntegral, 1e-15);
    EXPECT_EQ(f.pdf(470), 0.0);
    EXPECT_EQ(f.pdf(700), 0.0);
}

TEST(Tabulated1D, SampleFollowsPiecewiseLinearDensityChiSquare) {
    const Tabulated1D f(kX, kY, "test.f");
    expect_chi_square_fit([&](std::mt19937_64& rng) { return f.sample(uniform(rng)); },
                          [](double a, double b) { return lin_integral(kX, kY, a, b) / kIntegral; }, 400, 600, 100,
                          400000, 12345);
    // Finer bins over the steep 1 nm segment and its neighbours.
    const double p_window = lin_integral(kX, kY, 528, 534) / kIntegral;
    expect_chi_square_fit(
        [&](std::mt19937_64& r) {
            // Rejection onto the window keeps the test about the shape there.
            for (;;) {
                const double x = f.sample(uniform(r));
                if (x >= 528 && x <= 534) return x;
            }
        },
        [&](double a, double b) { return lin_integral(kX, kY, a, b) / kIntegral / p_window; }, 528, 534, 24, 200000,
        4242);
}

TEST(Tabulated1D, SampleIsTheExactInverseOfTheCdf) {
    const Tabulated1D f(kX, kY, "test.f");
    double previous = -1.0;
    for (int k = 0; k <= 1000; ++k) {
        const double u = k / 1000.0;
        const double x = f.sample(u);
        const double cdf = lin_integral(kX, kY, 400, x) / kIntegral;
        EXPECT_NEAR(cdf, u, 1e-12) << "u = " << u;
        EXPECT_GE(x, previous) << "sample must be monotone in u";
        previous = x;
    }
    // Ends: u = 0 is the left end of the first segment with area (400 here),
    // u = 1 the right end of the last (600).
    EXPECT_DOUBLE_EQ(f.sample(0.0), 400.0);
    EXPECT_DOUBLE_EQ(f.sample(1.0), 600.0);
    // Leading and trailing zero segments are never sampled: the density is
    // the symmetric triangle on [1, 3], whose median is its apex 2.
    const Tabulated1D g({0, 1, 2, 3, 4}, {0, 0, 1, 0, 0}, "g");
    EXPECT_DOUBLE_EQ(g.sample(0.0), 1.0);
    EXPECT_DOUBLE_EQ(g.sample(1.0), 3.0);
    EXPECT_DOUBLE_EQ(g.sample(0.5), 2.0);
}

TEST(Tabulated1D, SampleIsAccurateOnNearlyFlatAndNearlyZeroSegments) {
    // Nearly flat: the textbook quadratic root divides by y1 - y0 = 1e-13.
    const std::vector<double> xf = {0, 10}, yf = {1, 1 + 1e-13};
    const Tabulated1D flat(xf, yf, "flat");
    // Steep from almost zero: the CDF near 0 is ~ y1 s^2 / 2.
    const std::vector<double> xs = {0, 1}, ys = {1e-12, 1};
    const Tabulated1D steep(xs, ys, "steep");
    for (double u : {1e-12, 1e-6, 0.1, 0.37, 0.5, 0.9, 1 - 1e-9}) {
        const double xa = flat.sample(u);
        EXPECT_NEAR(lin_integral(xf, yf, 0, xa) / lin_integral(xf, yf, 0, 10), u, 1e-14 + 1e-12 * u);
        const double xb = steep.sample(u);
        EXPECT_NEAR(lin_integral(xs, ys, 0, xb) / lin_integral(xs, ys, 0, 1), u, 1e-15 + 1e-12 * u);
    }
    // Exactly flat segment: uniform, so sample is linear in u.
    const Tabulated1D box({400, 700}, {2, 2}, "box");
    EXPECT_DOUBLE_EQ(box.sample(0.25), 475.0);
}

TEST(Tabulated1D, ConstantEvaluatesEverywhereAndCannotBeNormalised) {
    const Tabulated1D c = Tabulated1D::constant(20.0, "medium.mua");
    EXPECT_TRUE(c.is_constant());
    EXPECT_EQ(c.eval(-1e9), 20.0);
    EXPECT_EQ(c.eval(532.0), 20.0);
    EXPECT_EQ(c.x_min(), -std::numeric_limits<double>::infinity());
    EXPECT_EQ(c.x_max(), std::numeric_limits<double>::infinity());
    EXPECT_THROW(c.integral(), std::logic_error);
    EXPECT_THROW(c.sample(0.5), std::logic_error);
    EXPECT_THROW(c.pdf(500), std::logic_error);
    // A one-node table is the same thing.
    const Tabulated1D one({550}, {3.5}, "one");
    EXPECT_TRUE(one.is_constant());
    EXPECT_EQ(one.eval(300), 3.5);
}

TEST(Tabulated1D, IdenticallyZeroFunctionCannotBeSampled) {
    const Tabulated1D z({400, 500}, {0, 0}, "light.spectrum");
    EXPECT_EQ(z.integral(), 0.0);
    try {
        z.sample(0.5);
        ADD_FAILURE() << "no exception";
    } catch (const std::logic_error& e) {
        EXPECT_NE(std::string(e.what()).find("light.spectrum"), std::string::npos);
    }
    EXPECT_THROW(z.pdf(450), std::logic_error);
}

TEST(Tabulated1D, ValidationErrorsNameFieldIndexAndValue) {
    const double nan = std::numeric_limits<double>::quiet_NaN();
    const double inf = std::numeric_limits<double>::infinity();
    expect_invalid([] { Tabulated1D({400, 500, 600}, {1, 2}, "medium.mua"); }, {"medium.mua", "x has 3", "y has 2"});
    expect_invalid([] { Tabulated1D({}, {}, "medium.mus"); }, {"medium.mus", "got 0"});
    expect_invalid(
        [&] {
            Tabulated1D({400, nan, 600}, {1, 2, 3}, "light.spectrum");
        },
        {"light.spectrum", "x[1] = nan", "finite"});
    expect_invalid(
        [&] {
            Tabulated1D({400, 500, 600}, {1, inf, 3}, "medium.g");
        },
        {"medium.g", "y[1] = inf", "finite"});
    expect_invalid(
        [] {
            Tabulated1D({400, 500, 600}, {1, 2, -0.25}, "region 'polyp': medium.mua");
        },
        {"region 'polyp': medium.mua", "y[2] = -0.25", ">= 0"});
    expect_invalid(
        [] {
            Tabulated1D({400, 500, 450}, {1, 2, 3}, "medium.mus");
        },
        {"medium.mus", "x[2] = 450", "x[1] = 500", "strictly increasing"});
    expect_invalid(
        [] {
            Tabulated1D({400, 500, 500}, {1, 2, 3}, "medium.mus");
        },
        {"medium.mus", "x[2] = 500", "strictly increasing"});
    expect_invalid([] { Tabulated1D::constant(-1.0, "medium.mua"); }, {"medium.mua", "y[0] = -1", ">= 0"});
    expect_invalid([&] { Tabulated1D::constant(nan, "medium.n"); }, {"medium.n", "y[0] = nan"});
    const Tabulated1D f(kX, kY, "light.spectrum");
    expect_invalid([&] { f.sample(1.5); }, {"light.spectrum", "u = 1.5"});
    expect_invalid([&] { f.sample(-0.1); }, {"light.spectrum", "u = -0.1"});
    expect_invalid([&] { f.sample(nan); }, {"light.spectrum", "u = nan"});
}

}  // namespace
