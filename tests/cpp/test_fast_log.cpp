// log_positive (native/fast_log.h) against std::log: the relative error stays
// below 1e-15 (the polynomial's 3.2e-17 plus a few roundings, relative to
// |ln x|) over the whole range the engine feeds it -- the uniforms k 2^-53 in
// (0, 1], the smallest of them included -- and beyond, over every binade of
// normal doubles, and at both ends of each of the table's 128 pieces.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <cstring>
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
    EXPECT_LT(rel_err(0x1.0p-53), 1e-15);        // the smallest engine uniform
    EXPECT_LT(rel_err(1.0 - 0x1.0p-53), 1e-15);  // the largest below 1: ln ~ -1.1e-16
    EXPECT_LT(rel_err(std::numeric_limits<double>::min()), 1e-15);
    EXPECT_LT(rel_err(std::numeric_limits<double>::max()), 1e-15);
    EXPECT_NEAR(log_positive(2.0), std::log(2.0), 1e-16);
    // The binade edges of the reduction: sqrt(1/2) and sqrt(2) and their neighbours.
    for (double x :
         {std::sqrt(0.5), std::sqrt(2.0), std::nextafter(std::sqrt(0.5), 0.0), std::nextafter(std::sqrt(2.0), 4.0)})
        EXPECT_LT(rel_err(x), 1e-15) << x;
}

// The ends of every piece of the table (where |r| is largest) in the binades
// of the engine's uniforms, and the tabulated ln c against a long double log.
TEST(FastLog, PieceEnds) {
    for (int i = 0; i < 128; ++i) {
        const uint64_t start = ep::log_detail::kOffBits + (uint64_t(i) << ep::log_detail::kPieceShift);
        for (const uint64_t bits : {start, start + 1, start - 1, start + (uint64_t(1) << 44)}) {
            double z;
            std::memcpy(&z, &bits, sizeof z);
            for (int e = -53; e <= 1; ++e) EXPECT_LT(rel_err(std::ldexp(z, e)), 1e-15) << i << " " << e;
        }
        const ep::log_detail::Piece& p = ep::log_detail::kPieces.at[i];
        // Within 0.51 units in the last place of ln c (long double reference).
        const long double ref = std::log((long double)p.c);
        const double ulp = std::nextafter(std::fabs(p.ln_c), 2.0) - std::fabs(p.ln_c);
        if (i != 74) EXPECT_LE(std::fabs((long double)p.ln_c - ref), 0.51L * ulp) << i;
        if (i == 74) EXPECT_TRUE(p.c == 1 && p.ln_c == 0);  // the piece across 1
        EXPECT_EQ(p.inv_c, 1 / p.c);
    }
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
    EXPECT_LT(worst, 1e-15);
    std::printf("max relative error of log_positive: %.3g\n", worst);
}

// neg_log_lattice(m) is -log_positive(m 2^-53) bit for bit: the engine draws
// its free paths with it, and the bits must not depend on which one a path
// takes. Random m, every power of two and its neighbours, the smallest and
// the largest m, and small m (the longest paths).
TEST(FastLog, NegLogLatticeIsMinusLogPositiveBitForBit) {
    auto same = [](uint64_t m) {
        const double a = ep::neg_log_lattice(m), b = -log_positive(double(m) * 0x1.0p-53);
        return std::memcmp(&a, &b, sizeof a) == 0;
    };
    std::mt19937_64 rng(7);
    for (int i = 0; i < 2000000; ++i) ASSERT_TRUE(same((rng() >> 11) + 1)) << i;
    for (int k = 0; k <= 53; ++k) {
        const uint64_t p = uint64_t(1) << k;
        for (const uint64_t m : {p - 1, p, p + 1})
            if (m >= 1 && m <= (uint64_t(1) << 53)) ASSERT_TRUE(same(m)) << m;
    }
    for (uint64_t m = 1; m < (1u << 16); ++m) ASSERT_TRUE(same(m)) << m;
    const double at_one = ep::neg_log_lattice(uint64_t(1) << 53);
    EXPECT_EQ(at_one, 0.0);  // u = 1: a zero-length path
    EXPECT_NEAR(ep::neg_log_lattice(1), 53 * std::log(2.0), 1e-14);
}
