// Unit tests for ep::Fixed128, the exact fixed-point sum of grid voxels:
// exact conversion in its documented range, rounding below it, correctly
// rounded conversion back, order-independent sums and named limits.
#include "fixed_point.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <random>
#include <vector>

namespace {

using ep::Fixed128;

Fixed128 fx(double v) {
    Fixed128 f;
    EXPECT_TRUE(Fixed128::from_double(v, f)) << v;
    return f;
}

Fixed128 sum_of(std::initializer_list<double> values) {
    Fixed128 s;
    for (double v : values) EXPECT_TRUE(s.add(fx(v)));
    return s;
}

TEST(Fixed128, ConvertsExactlyInItsRange) {
    // 1 = 2^80 last bits: word 1 holds 2^16.
    const Fixed128 one = fx(1.0);
    EXPECT_EQ(one.words()[0], 0u);
    EXPECT_EQ(one.words()[1], uint64_t(1) << 16);
    // The ends of the exact range: 2^-28 is the significand's last bit at the
    // fixed point's last bit (mant = 2^52 in word 0); 2^46 is word 1's 2^62.
    EXPECT_EQ(fx(0x1p-28).words()[0], uint64_t(1) << 52);
    EXPECT_EQ(fx(0x1p-28).words()[1], 0u);
    EXPECT_EQ(fx(0x1p46).words()[1], uint64_t(1) << 62);
    // -1 is the two's complement of 2^80.
    EXPECT_EQ(fx(-1.0).words()[0], 0u);
    EXPECT_EQ(fx(-1.0).words()[1], ~uint64_t(0) << 16);
    // Every double of 2^-28 <= |v| < 2^47 comes back bit for bit, both ends of
    // the range included.
    std::mt19937_64 rng(5);
    std::uniform_real_distribution<double> mant(1.0, 2.0);
    std::uniform_int_distribution<int> exp2(-28, 46);
    std::vector<double> values = {0x1p-28, std::nextafter(0x1p-28, 1.0), std::nextafter(0x1p47, 0.0), 0x1p46};
    for (int n = 0; n < 20000; ++n) values.push_back(std::ldexp(mant(rng), exp2(rng)));
    for (double v : values) {
        for (double s : {v, -v}) {
            const double back = fx(s).to_double();
            ASSERT_EQ(std::memcmp(&back, &s, sizeof s), 0) << s;
        }
    }
}

TEST(Fixed128, RoundsTinyValuesToTheLastBitTiesToEven) {
    const double lsb = std::ldexp(1.0, -Fixed128::kFracBits);
    ASSERT_EQ(lsb, 0x1p-80);
    EXPECT_TRUE(fx(0.5 * lsb).is_zero());             // a tie: to even 0
    EXPECT_EQ(fx(0.75 * lsb).to_double(), lsb);       // above half: up
    EXPECT_EQ(fx(1.5 * lsb).to_double(), 2 * lsb);    // a tie: to even 2
    EXPECT_EQ(fx(2.5 * lsb).to_double(), 2 * lsb);    // a tie: to even 2
    EXPECT_EQ(fx(-2.5 * lsb).to_double(), -2 * lsb);  // symmetric
    EXPECT_TRUE(fx(std::numeric_limits<double>::denorm_min()).is_zero());
    EXPECT_TRUE(fx(-0.0).is_zero());
    // Just below 2^-28 a value keeps 52 of its 53 bits: (2^53 - 1) 2^-81 is
    // a tie between 2^-28 - 2^-80 and 2^-28, to even 2^-28 (2^52 last bits).
    EXPECT_EQ(fx(std::nextafter(0x1p-28, 0.0)).to_double(), 0x1p-28);
    // 1e-12 (about 2^-40) keeps 40 bits: the nearest multiple of 2^-80.
    const double tiny = 1e-12;
    EXPECT_EQ(fx(tiny).to_double(), std::nearbyint(tiny * 0x1p80) * 0x1p-80);
    EXPECT_NE(fx(tiny).to_double(), tiny);  // the rounding is real (1e-12 needs 53 bits)
}

TEST(Fixed128, RefusesWhatItCannotHold) {
    Fixed128 f = fx(3.0);
    for (double bad : {std::numeric_limits<double>::infinity(), -std::numeric_limits<double>::infinity(),
                       std::numeric_limits<double>::quiet_NaN(), 0x1p47, -0x1p47, 1e300}) {
        EXPECT_FALSE(Fixed128::from_double(bad, f)) << bad;
        EXPECT_EQ(f.to_double(), 3.0);  // unchanged
    }
    unsigned __int128 low;
    EXPECT_FALSE(Fixed128::fast_low(0x1p47, low));
}

TEST(Fixed128, ConversionBackRoundsOnceToNearest) {
    // 1 + 2^-53 is the tie between 1 and 1 + 2^-52: to even, 1.
    EXPECT_EQ(sum_of({1.0, 0x1p-53}).to_double(), 1.0);
    // One last bit above the tie decides upward (the sticky bit).
    EXPECT_EQ(sum_of({1.0, 0x1p-53, 0x1p-80}).to_double(), 1.0 + 0x1p-52);
    // Below the tie by one last bit: down.
    EXPECT_EQ(sum_of({1.0, 0x1p-53, -0x1p-80}).to_double(), 1.0);
    // The most negative value, -2^47, has no positive counterpart in 128 bits.
    EXPECT_EQ(Fixed128::from_words(0, uint64_t(1) << 63).to_double(), -0x1p47);
    // The largest value: 2^47 less one last bit, rounded to 2^47.
    EXPECT_EQ(Fixed128::from_words(~uint64_t(0), ~uint64_t(0) >> 1).to_double(), 0x1p47);
    // The three-word sums of voxel totals reach 2^111: the extremes of the
    // scale (the last bit, the top word) and a rounding at the top.
    // 2^110 + 2^57 is half an ulp above 2^110 (word 2 counts 2^48).
    const uint64_t last_bit[3] = {1, 0, 0}, top[3] = {0, 0, uint64_t(1) << 62},
                   tie[3] = {0, 0, (uint64_t(1) << 62) | 0x200}, above_tie[3] = {1, 0, tie[2]};
    EXPECT_EQ(Fixed128::words_to_double(last_bit, 3), 0x1p-80);
    EXPECT_EQ(Fixed128::words_to_double(top, 3), 0x1p110);
    EXPECT_EQ(Fixed128::words_to_double(tie, 3), 0x1p110);                 // a tie: to even
    EXPECT_EQ(Fixed128::words_to_double(above_tie, 3), 0x1p110 + 0x1p58);  // the last bit decides: up
}

TEST(Fixed128, SumsDoNotDependOnOrder) {
    // Values over 40 decades, both signs: a double sum of these depends on its
    // order in most bits; the fixed-point sum must not depend on it at all.
    std::mt19937_64 rng(11);
    std::uniform_real_distribution<double> logv(-22.0, 10.0);
    std::vector<double> v;
    for (int n = 0; n < 5000; ++n) v.push_back((n % 3 ? 1 : -1) * std::pow(10.0, logv(rng)));
    Fixed128 forward, backward, shuffled;
    for (double x : v) ASSERT_TRUE(forward.add(fx(x)));
    for (auto it = v.rbegin(); it != v.rend(); ++it) ASSERT_TRUE(backward.add(fx(*it)));
    std::shuffle(v.begin(), v.end(), rng);
    Fixed128 halves[2];
    for (size_t i = 0; i < v.size(); ++i) ASSERT_TRUE(halves[i % 2].add(fx(v[i])));
    shuffled = halves[1];
    ASSERT_TRUE(shuffled.add(halves[0]));
    EXPECT_EQ(forward, backward);
    EXPECT_EQ(forward, shuffled);
    // The terms cancel one another: x + (-x) is exactly zero.
    Fixed128 zero = fx(0.1);
    ASSERT_TRUE(zero.add(fx(-0.1)));
    EXPECT_TRUE(zero.is_zero());
}

TEST(Fixed128, ReportsOverflowAndStaysUnchanged) {
    Fixed128 s;
    for (int n = 0; n < 15; ++n) ASSERT_TRUE(s.add(fx(0x1p43)));
    EXPECT_FALSE(s.add(fx(0x1p43)));  // 16 * 2^43 = 2^47: out of range
    EXPECT_EQ(s.to_double(), 15 * 0x1p43);
    Fixed128 neg;
    for (int n = 0; n < 16; ++n) ASSERT_TRUE(neg.add(fx(-0x1p43)));  // -2^47 is the least value
    EXPECT_FALSE(neg.add(fx(-0x1p-80)));
    EXPECT_EQ(neg.to_double(), -0x1p47);
}

TEST(Fixed128, OverflowMatchesWideReference) {
    // add() takes the signed overflow flag of a 128-bit addition; the
    // reference sums the two values in three words and checks that the top
    // word is the sign extension of the second.
    const uint64_t ones = ~uint64_t(0), min = uint64_t(INT64_MIN), max = uint64_t(INT64_MAX);
    Fixed128 least = Fixed128::from_words(0, min);
    EXPECT_FALSE(least.add(Fixed128::from_words(ones, ones)));  // -2^47 - 2^-80
    EXPECT_EQ(least, Fixed128::from_words(0, min));
    Fixed128 most = Fixed128::from_words(ones, max);
    EXPECT_FALSE(most.add(Fixed128::from_words(1, 0)));
    EXPECT_EQ(most, Fixed128::from_words(ones, max));
    std::mt19937_64 rng(11);
    const uint64_t near[] = {0, 1, ones, ones - 1, min, min + 1, max, max - 1};
    const auto word = [&](bool top) { return rng() % 2 ? near[rng() % 8] : (top ? rng() >> (rng() % 64) : rng()); };
    for (int n = 0; n < 200000; ++n) {
        const uint64_t a[2] = {word(false), word(true)}, b[2] = {word(false), word(true)};
        const uint64_t low = a[0] + b[0];
        const unsigned __int128 carry = low < a[0];
        // Words 1 and 2 of the exact sum, each operand sign-extended into word 2.
        const __int128 high = __int128(int64_t(a[1])) + int64_t(b[1]) + __int128(carry);
        const bool fits = high == __int128(int64_t(high));
        Fixed128 s = Fixed128::from_words(a[0], a[1]);
        ASSERT_EQ(s.add(Fixed128::from_words(b[0], b[1])), fits) << n;
        if (fits)
            ASSERT_EQ(s, Fixed128::from_words(low, uint64_t(int64_t(high)))) << n;
        else
            ASSERT_EQ(s, Fixed128::from_words(a[0], a[1])) << n;
    }
}

TEST(Fixed128, FastPathAdditionCarriesAndStopsAtTheTop) {
    // The deposit loop adds fast_low values straight into the 128 bits; 2^48
    // x (1 - 2^-53) carries across the word boundary and equals the sum of
    // the general path.
    unsigned __int128 low;
    const double v = std::nextafter(1.0, 0.0);
    EXPECT_FALSE(Fixed128::fast_low(std::nextafter(0x1p-28, 0.0), low));  // general path below 2^-28
    EXPECT_FALSE(Fixed128::fast_low(-1.0, low));
    EXPECT_FALSE(Fixed128::fast_low(0.0, low));
    ASSERT_TRUE(Fixed128::fast_low(std::nextafter(0x1p47, 0.0), low));
    ASSERT_TRUE(Fixed128::fast_low(v, low));
    Fixed128 fast, general;
    for (int n = 0; n < 3; ++n) {
        ASSERT_TRUE(fast.add_low(low));
        ASSERT_TRUE(general.add(fx(v)));
    }
    EXPECT_EQ(fast, general);
    EXPECT_EQ(fast.to_double(), 3 * v);
    Fixed128 top = Fixed128::from_words(~uint64_t(0), uint64_t(INT64_MAX));
    EXPECT_FALSE(top.add_low(1));
    EXPECT_EQ(top, Fixed128::from_words(~uint64_t(0), uint64_t(INT64_MAX)));
}

}  // namespace
