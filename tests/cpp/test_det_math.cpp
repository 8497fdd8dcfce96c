// det_exp, det_expm1, det_sincos, det_cos, det_sin, det_log, det_pow, det_tan
// and det_atan (native/det_math.h) against long double references (glibc's x87
// expl, expm1l, sinl, cosl, logl, powl, tanl, atanl: 64-bit
// significands, far finer than the double being checked): within SLEEF's
// bound of 1.0 unit in the last place over the ranges the engine feeds them,
// and their exact values at the special points. That they give the same bits
// on every machine is tests/python/test_isa_bits.py's to show.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <limits>
#include <random>

#include "det_math.h"

using ep::det_atan;
using ep::det_cos;
using ep::det_exp;
using ep::det_expm1;
using ep::det_log;
using ep::det_pow;
using ep::det_sin;
using ep::det_sincos;
using ep::det_tan;

namespace {

// |got - ref| in units of the last place of the double nearest ref.
double ulps(double got, long double ref) {
    const double r = double(ref);
    const double ulp = std::nextafter(std::fabs(r), std::numeric_limits<double>::infinity()) - std::fabs(r);
    return double(std::fabs((long double)got - ref) / (long double)ulp);
}

template <class F, class R>
double worst_ulps(F f, R ref, double lo, double hi, int n, uint64_t seed) {
    std::mt19937_64 gen(seed);
    std::uniform_real_distribution<double> u(lo, hi);
    double worst = 0;
    for (int i = 0; i < n; ++i) {
        const double x = u(gen);
        worst = std::max(worst, ulps(f(x), ref(x)));
    }
    return worst;
}

// An odd function with f(x) = x + O(x^3) at 0 (sin, tan, atan): within 1 ulp
// over [-1e-3, 1e-3], and exact at +0, -0 (its sign kept) and a tiny argument.
template <class F, class R>
void expect_odd_and_x_near_zero(F f, R ref, uint64_t seed) {
    EXPECT_LE(worst_ulps(f, ref, -1e-3, 1e-3, 100000, seed), 1.0);
    EXPECT_EQ(f(0.0), 0.0);
    EXPECT_TRUE(std::signbit(f(-0.0)));
    EXPECT_EQ(f(1e-300), 1e-300);
}

double sin_of(double x) {
    double s, c;
    det_sincos(x, &s, &c);
    return s;
}

double cos_of(double x) {
    double s, c;
    det_sincos(x, &s, &c);
    return c;
}

}  // namespace

// The camera's attenuation exp(-tau) and depth roulette exp(tau_cut - tau):
// tau from 0 to where exp underflows.
TEST(DetMath, ExpWithinOneUlp) {
    const auto ref = [](double x) { return std::exp((long double)x); };
    EXPECT_LE(worst_ulps(det_exp, ref, -1.0, 0.0, 200000, 1), 1.0);
    EXPECT_LE(worst_ulps(det_exp, ref, -700.0, 0.0, 200000, 2), 1.0);
    EXPECT_LE(worst_ulps(det_exp, ref, 0.0, 700.0, 50000, 3), 1.0);
}

TEST(DetMath, ExpSpecialValues) {
    EXPECT_EQ(det_exp(0.0), 1.0);
    EXPECT_EQ(det_exp(-0.0), 1.0);
    EXPECT_EQ(det_exp(-std::numeric_limits<double>::infinity()), 0.0);
    EXPECT_EQ(det_exp(-800.0), 0.0);  // below the smallest subnormal
    EXPECT_EQ(det_exp(800.0), std::numeric_limits<double>::infinity());
    EXPECT_TRUE(std::isnan(det_exp(std::numeric_limits<double>::quiet_NaN())));
}

// A clear region's absorbed part -expm1(-mua t): tiny to total.
TEST(DetMath, Expm1WithinOneUlp) {
    const auto ref = [](double x) { return std::expm1((long double)x); };
    EXPECT_LE(worst_ulps(det_expm1, ref, -1e-6, 0.0, 100000, 4), 1.0);
    EXPECT_LE(worst_ulps(det_expm1, ref, -1.0, 0.0, 200000, 5), 1.0);
    EXPECT_LE(worst_ulps(det_expm1, ref, -60.0, 0.0, 100000, 6), 1.0);
}

TEST(DetMath, Expm1SpecialValues) {
    EXPECT_EQ(det_expm1(0.0), 0.0);
    EXPECT_TRUE(std::signbit(det_expm1(-0.0)));
    EXPECT_EQ(det_expm1(-1e-300), -1e-300);  // expm1(x) = x below half an ulp of x^2/2
    EXPECT_EQ(det_expm1(-std::numeric_limits<double>::infinity()), -1.0);
    EXPECT_EQ(det_expm1(-800.0), -1.0);
    EXPECT_TRUE(std::isnan(det_expm1(std::numeric_limits<double>::quiet_NaN())));
}

// Azimuths 2 pi u of the sources and the camera's look-back, and the probe
// rays' golden-angle azimuths (up to 64 turns).
TEST(DetMath, SinCosWithinOneUlp) {
    const auto sin_ref = [](double x) { return std::sin((long double)x); };
    const auto cos_ref = [](double x) { return std::cos((long double)x); };
    const double two_pi = 6.283185307179586;
    EXPECT_LE(worst_ulps(sin_of, sin_ref, 0.0, two_pi, 200000, 7), 1.0);
    EXPECT_LE(worst_ulps(cos_of, cos_ref, 0.0, two_pi, 200000, 8), 1.0);
    EXPECT_LE(worst_ulps(sin_of, sin_ref, 0.0, 64 * two_pi, 100000, 9), 1.0);
    EXPECT_LE(worst_ulps(cos_of, cos_ref, 0.0, 64 * two_pi, 100000, 10), 1.0);
    // A cone's half angle in [0, pi/2].
    EXPECT_LE(worst_ulps(det_cos, cos_ref, 0.0, 1.5707963267948966, 100000, 11), 1.0);
}

TEST(DetMath, SinCosSpecialValues) {
    double s, c;
    det_sincos(0.0, &s, &c);
    EXPECT_EQ(s, 0.0);
    EXPECT_EQ(c, 1.0);
    EXPECT_EQ(det_cos(0.0), 1.0);
    det_sincos(-0.0, &s, &c);
    EXPECT_TRUE(s == 0.0 && std::signbit(s));
    det_sincos(1e-300, &s, &c);  // sin x = x, cos x = 1 for tiny x
    EXPECT_EQ(s, 1e-300);
    EXPECT_EQ(c, 1.0);
    det_sincos(std::numeric_limits<double>::infinity(), &s, &c);
    EXPECT_TRUE(std::isnan(s) && std::isnan(c));
    // Quarter and half turns, to within an ulp of the rounded pi.
    det_sincos(1.5707963267948966, &s, &c);
    EXPECT_EQ(s, 1.0);
    EXPECT_LE(std::fabs(c), 1e-16);
    det_sincos(3.141592653589793, &s, &c);
    EXPECT_LE(std::fabs(s), 1e-15);
    EXPECT_EQ(c, -1.0);
}

// The package's own uses (endophoton.det): an endoscope's pose from beta
// (sin and cos of angles within a turn), generated meshes' rings.
TEST(DetMath, SinWithinOneUlp) {
    const auto ref = [](double x) { return std::sin((long double)x); };
    EXPECT_LE(worst_ulps(det_sin, ref, 0.0, 6.283185307179586, 200000, 12), 1.0);
    expect_odd_and_x_near_zero(det_sin, ref, 13);
    EXPECT_TRUE(std::isnan(det_sin(std::numeric_limits<double>::infinity())));
}

// Media's power laws: ln of wavelength and coefficient ratios, and ln 10.
TEST(DetMath, LogWithinOneUlp) {
    const auto ref = [](double x) { return std::log((long double)x); };
    EXPECT_LE(worst_ulps(det_log, ref, 0.5, 2.0, 200000, 14), 1.0);  // near 1, where ln x is small
    EXPECT_LE(worst_ulps(det_log, ref, 1e-3, 1e3, 200000, 15), 1.0);
    EXPECT_LE(worst_ulps(det_log, ref, 1.0, 1e300, 100000, 16), 1.0);
    EXPECT_EQ(det_log(1.0), 0.0);
    EXPECT_EQ(det_log(0.0), -std::numeric_limits<double>::infinity());
    EXPECT_EQ(det_log(std::numeric_limits<double>::infinity()), std::numeric_limits<double>::infinity());
    EXPECT_TRUE(std::isnan(det_log(-1.0)));
    EXPECT_TRUE(std::isnan(det_log(std::numeric_limits<double>::quiet_NaN())));
}

// mus'(lambda) = a (lambda / 500 nm)^-b: ratios over the wavelength range of a
// Spectrum (1 nm to 1 mm, 0.002 to 2000), powers b in [0, 4] and their negatives.
TEST(DetMath, PowWithinOneUlp) {
    std::mt19937_64 gen(17);
    std::uniform_real_distribution<double> base(0.002, 2000.0), power(-4.0, 4.0);
    double worst = 0;
    for (int i = 0; i < 200000; ++i) {
        const double x = base(gen), y = power(gen);
        worst = std::max(worst, ulps(det_pow(x, y), std::pow((long double)x, (long double)y)));
    }
    EXPECT_LE(worst, 1.0);
    EXPECT_EQ(det_pow(2.0, 10.0), 1024.0);
    EXPECT_EQ(det_pow(0.25, 0.5), 0.5);
    EXPECT_EQ(det_pow(1.6, 0.0), 1.0);
    EXPECT_EQ(det_pow(1.0, -3.7), 1.0);
    EXPECT_EQ(det_pow(0.0, 1.5), 0.0);
    EXPECT_EQ(det_pow(0.0, -1.5), std::numeric_limits<double>::infinity());
    EXPECT_TRUE(std::isnan(det_pow(-2.0, 0.5)));
}

// The endoscope view's camera: tan of half the field of view, which is in
// (0, 179] degrees, so x in (0, 89.5 degrees].
TEST(DetMath, TanWithinOneUlp) {
    const auto ref = [](double x) { return std::tan((long double)x); };
    EXPECT_LE(worst_ulps(det_tan, ref, 0.0, 1.5620696805349248, 200000, 18), 1.0);
    expect_odd_and_x_near_zero(det_tan, ref, 19);
    EXPECT_LE(ulps(det_tan(0.7853981633974483), std::tan((long double)0.7853981633974483)), 1.0);  // 45 degrees
    EXPECT_TRUE(std::isnan(det_tan(std::numeric_limits<double>::infinity())));
}

// The pixels' solid angles: atan(x y / sqrt(1 + x^2 + y^2)) over the image
// plane at depth 1, |x|, |y| <= tan 89.5 degrees (115), so |argument| < 115.
TEST(DetMath, AtanWithinOneUlp) {
    const auto ref = [](double x) { return std::atan((long double)x); };
    EXPECT_LE(worst_ulps(det_atan, ref, -1.0, 1.0, 200000, 20), 1.0);
    EXPECT_LE(worst_ulps(det_atan, ref, -120.0, 120.0, 200000, 21), 1.0);
    expect_odd_and_x_near_zero(det_atan, ref, 22);
    EXPECT_EQ(det_atan(1.0), 0.7853981633974483);  // pi/4, rounded
    EXPECT_EQ(det_atan(std::numeric_limits<double>::infinity()), 1.5707963267948966);
    EXPECT_EQ(det_atan(-std::numeric_limits<double>::infinity()), -1.5707963267948966);
    EXPECT_TRUE(std::isnan(det_atan(std::numeric_limits<double>::quiet_NaN())));
}
