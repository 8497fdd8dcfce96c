// log_positive (native/fast_log.h) against std::log: the relative error stays
// below 1e-13 (the series bound of the header, 9e-16, plus a few roundings)
// over the whole range the engine feeds it -- the uniforms k 2^-53 in (0, 1],
// the smallest of them included -- and beyond, over every binade of normal doubles.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <limits>
#include <random>

#include "fast_log.h"

using ep::log_positive;

namespace {

double rel_err(double x) {
    const double ref = std::log(x);
    return ref == 0 ? std::fabs(log_positive(x)) : std::fabs(log_positive(x) - ref) / std::fabs(ref);
}

}  // namespace

TEST(FastLog, ExactPointsAndEnds) {
    EXPECT_EQ(log_positive(1.0), 0.0);
    EXPECT_LT(rel_err(0x1.0p-53), 1e-13);        // the smallest engine uniform
    EXPECT_LT(rel_err(1.0 - 0x1.0p-53), 1e-13);  // the largest below 1: ln ~ -1.1e-16
    EXPECT_LT(rel_err(std::numeric_limits<double>::min()), 1e-13);
    EXPECT_LT(rel_err(std::numeric_limits<double>::max()), 1e-13);
    EXPECT_NEAR(log_positive(2.0), std::log(2.0), 1e-16);
    // The binade edges of the reduction: sqrt(1/2) and sqrt(2) and their neighbours.
    for (double x :
         {std::sqrt(0.5), std::sqrt(2.0), std::nextafter(std::sqrt(0.5), 0.0), std::nextafter(std::sqrt(2.0), 4.0)})
        EXPECT_LT(rel_err(x), 1e-13) << x;
}

TEST(FastLog, EngineUniformsAndEveryBinade) {
    std::mt19937_64 rng(42);
    double worst = 0;
    // The engine's (0, 1] uniforms: (k + 1) 2^-53, k from the top 53 bits.
    for (int i = 0; i < 2000000; ++i) worst = std::max(worst, rel_err(double((rng() >> 11) + 1) * 0x1.0p-53));
    // Small ones, which a uniform sample of k almost never reaches: k < 2^20.
    for (uint64_t k = 1; k < (1u << 20); k += 7) worst = std::max(worst, rel_err(double(k) * 0x1.0p-53));
    // Near 1, where ln u is tiny and cancellation would show.
    for (uint64_t k = 1; k < (1u << 20); k += 7) worst = std::max(worst, rel_err(1.0 - double(k) * 0x1.0p-53));
    // Every binade of normal doubles, random mantissas.
    for (int e = -1022; e <= 1023; ++e)
        for (int j = 0; j < 200; ++j)
            worst = std::max(worst, rel_err(std::ldexp(1.0 + double(rng() >> 12) * 0x1.0p-52, e)));
    EXPECT_LT(worst, 1e-13);
    std::printf("max relative error of log_positive: %.3g\n", worst);
}
