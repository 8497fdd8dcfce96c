// Unit tests for ep::Fixed192, the exact fixed-point sum of grid voxels:
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

using ep::Fixed192;

Fixed192 fx(double v) {
    Fixed192 f;
    EXPECT_TRUE(Fixed192::from_double(v, f)) << v;
    return f;
}

Fixed192 sum_of(std::initializer_list<double> values) {
    Fixed192 s;
    for (double v : values) EXPECT_TRUE(s.add(fx(v)));
    return s;
}

TEST(Fixed192, ConvertsExactlyInItsRange) {
    // 1 = 2^124 last bits: word 1 holds 2^60.
    const Fixed192 one = fx(1.0);
    EXPECT_EQ(one.words()[0], 0u);
    EXPECT_EQ(one.words()[1], uint64_t(1) << 60);
    EXPECT_EQ(one.words()[2], 0u);
    // 8 is the first value of the general path: the same layout rule.
    EXPECT_EQ(fx(8.0).words()[1], uint64_t(1) << 63);
    EXPECT_EQ(fx(16.0).words()[2], 1u);
    // Every double of 2^-72 <= |v| < 2^64 comes back bit for bit, both sides of
    // the fast path's bounds (2^-72 and 8) included.
    std::mt19937_64 rng(5);
    std::uniform_real_distribution<double> mant(1.0, 2.0);
    std::uniform_int_distribution<int> exp2(-72, 63);
    std::vector<double> values = {0x1p-72, std::nextafter(0x1p-72, 1.0), std::nextafter(8.0, 0.0), 8.0,
                                  std::nextafter(0x1p64, 0.0)};
    for (int n = 0; n < 20000; ++n) values.push_back(std::ldexp(mant(rng), exp2(rng)));
    for (double v : values) {
        for (double s : {v, -v}) {
            const double back = fx(s).to_double();
            ASSERT_EQ(std::memcmp(&back, &s, sizeof s), 0) << s;
        }
    }
}

TEST(Fixed192, RoundsTinyValuesToTheLastBitTiesToEven) {
    const double lsb = std::ldexp(1.0, -Fixed192::kFracBits);
    EXPECT_TRUE(fx(0.5 * lsb).is_zero());             // a tie: to even 0
    EXPECT_EQ(fx(0.75 * lsb).to_double(), lsb);       // above half: up
    EXPECT_EQ(fx(1.5 * lsb).to_double(), 2 * lsb);    // a tie: to even 2
    EXPECT_EQ(fx(2.5 * lsb).to_double(), 2 * lsb);    // a tie: to even 2
    EXPECT_EQ(fx(-2.5 * lsb).to_double(), -2 * lsb);  // symmetric
    EXPECT_TRUE(fx(std::numeric_limits<double>::denorm_min()).is_zero());
    EXPECT_TRUE(fx(-0.0).is_zero());
    // Just below 2^-72 a value keeps fewer than 53 bits but is still the
    // nearest multiple of the last bit.
    const double v = std::nextafter(0x1p-72, 0.0);
    EXPECT_NEAR(fx(v).to_double(), v, lsb / 2);
}

TEST(Fixed192, RefusesWhatItCannotHold) {
    Fixed192 f = fx(3.0);
    for (double bad : {std::numeric_limits<double>::infinity(), -std::numeric_limits<double>::infinity(),
                       std::numeric_limits<double>::quiet_NaN(), 0x1p64, -0x1p64, 1e300}) {
        EXPECT_FALSE(Fixed192::from_double(bad, f)) << bad;
        EXPECT_EQ(f.to_double(), 3.0);  // unchanged
    }
}

TEST(Fixed192, ConversionBackRoundsOnceToNearest) {
    // 1 + 2^-53 is the tie between 1 and 1 + 2^-52: to even, 1.
    EXPECT_EQ(sum_of({1.0, 0x1p-53}).to_double(), 1.0);
    // One last bit above the tie decides upward (the sticky bit).
    EXPECT_EQ(sum_of({1.0, 0x1p-53, 0x1p-124}).to_double(), 1.0 + 0x1p-52);
    // Below the tie by one last bit: down.
    EXPECT_EQ(sum_of({1.0, 0x1p-53, -0x1p-124}).to_double(), 1.0);
    // The most negative value, -2^67, has no positive counterpart in 192 bits.
    EXPECT_EQ(Fixed192::from_words(0, 0, uint64_t(1) << 63).to_double(), -0x1p67);
    // The largest value: 2^67 less one last bit, rounded to 2^67.
    EXPECT_EQ(Fixed192::from_words(~uint64_t(0), ~uint64_t(0), ~uint64_t(0) >> 1).to_double(), 0x1p67);
    // The four-word sums of voxel totals reach 2^131: the extremes of the
    // scale (the last bit, the top word) and a rounding at the top.
    // 2^130 + 2^77 is half an ulp above 2^130 (word 3 counts 2^68).
    const uint64_t last_bit[4] = {1, 0, 0, 0}, top[4] = {0, 0, 0, uint64_t(1) << 62},
                   tie[4] = {0, 0, 0, (uint64_t(1) << 62) | 0x200}, above_tie[4] = {1, 0, 0, tie[3]};
    EXPECT_EQ(Fixed192::words_to_double(last_bit, 4), 0x1p-124);
    EXPECT_EQ(Fixed192::words_to_double(top, 4), 0x1p130);
    EXPECT_EQ(Fixed192::words_to_double(tie, 4), 0x1p130);                 // a tie: to even
    EXPECT_EQ(Fixed192::words_to_double(above_tie, 4), 0x1p130 + 0x1p78);  // the last bit decides: up
}

TEST(Fixed192, SumsDoNotDependOnOrder) {
    // Values over 60 decades, both signs: a double sum of these depends on its
    // order in most bits; the fixed-point sum must not depend on it at all.
    std::mt19937_64 rng(11);
    std::uniform_real_distribution<double> logv(-21.0, 18.0);
    std::vector<double> v;
    for (int n = 0; n < 5000; ++n) v.push_back((n % 3 ? 1 : -1) * std::pow(10.0, logv(rng)));
    Fixed192 forward, backward, shuffled;
    for (double x : v) ASSERT_TRUE(forward.add(fx(x)));
    for (auto it = v.rbegin(); it != v.rend(); ++it) ASSERT_TRUE(backward.add(fx(*it)));
    std::shuffle(v.begin(), v.end(), rng);
    Fixed192 halves[2];
    for (size_t i = 0; i < v.size(); ++i) ASSERT_TRUE(halves[i % 2].add(fx(v[i])));
    shuffled = halves[1];
    ASSERT_TRUE(shuffled.add(halves[0]));
    EXPECT_EQ(forward, backward);
    EXPECT_EQ(forward, shuffled);
    // The terms cancel one another: x + (-x) is exactly zero.
    Fixed192 zero = fx(0.1);
    ASSERT_TRUE(zero.add(fx(-0.1)));
    EXPECT_TRUE(zero.is_zero());
}

TEST(Fixed192, ReportsOverflowAndStaysUnchanged) {
    Fixed192 s;
    for (int n = 0; n < 15; ++n) ASSERT_TRUE(s.add(fx(0x1p63)));
    EXPECT_FALSE(s.add(fx(0x1p63)));  // 16 * 2^63 = 2^67: out of range
    EXPECT_EQ(s.to_double(), 15 * 0x1p63);
    Fixed192 neg;
    for (int n = 0; n < 16; ++n) ASSERT_TRUE(neg.add(fx(-0x1p63)));  // -2^67 is the least value
    EXPECT_FALSE(neg.add(fx(-0x1p-124)));
    EXPECT_EQ(neg.to_double(), -0x1p67);
}

TEST(Fixed192, TopWordOverflowMatchesWideReference) {
    // add() decides the range of the top word in two signed 64-bit steps;
    // the reference sums it in 128 bits. Edge cases first: a carry that
    // brings a wrapped first step back to INT64_MIN (in range), and one ulp
    // beyond either end.
    const uint64_t ones = ~uint64_t(0), min = uint64_t(INT64_MIN), max = uint64_t(INT64_MAX);
    Fixed192 least = Fixed192::from_words(ones, ones, min);
    ASSERT_TRUE(least.add(Fixed192::from_words(1, 0, ones)));
    EXPECT_EQ(least, Fixed192::from_words(0, 0, min));
    EXPECT_FALSE(least.add(Fixed192::from_words(ones, ones, ones)));
    EXPECT_EQ(least, Fixed192::from_words(0, 0, min));
    Fixed192 most = Fixed192::from_words(ones, ones, max);
    EXPECT_FALSE(most.add(Fixed192::from_words(1, 0, 0)));
    EXPECT_EQ(most, Fixed192::from_words(ones, ones, max));
    std::mt19937_64 rng(11);
    const uint64_t near[] = {0, 1, ones, ones - 1, min, min + 1, max, max - 1};
    const auto word = [&](bool top) { return rng() % 2 ? near[rng() % 8] : (top ? rng() >> (rng() % 64) : rng()); };
    for (int n = 0; n < 200000; ++n) {
        const uint64_t a[3] = {word(false), word(false), word(true)}, b[3] = {word(false), word(false), word(true)};
        const unsigned __int128 la = (static_cast<unsigned __int128>(a[1]) << 64) | a[0];
        const unsigned __int128 lb = (static_cast<unsigned __int128>(b[1]) << 64) | b[0];
        const unsigned __int128 low = la + lb;
        const __int128 high = __int128(int64_t(a[2])) + int64_t(b[2]) + int64_t(low < la);
        const bool fits = high == __int128(int64_t(high));
        Fixed192 s = Fixed192::from_words(a[0], a[1], a[2]);
        ASSERT_EQ(s.add(Fixed192::from_words(b[0], b[1], b[2])), fits) << n;
        if (fits)
            ASSERT_EQ(s, Fixed192::from_words(uint64_t(low), uint64_t(low >> 64), uint64_t(int64_t(high)))) << n;
        else
            ASSERT_EQ(s, Fixed192::from_words(a[0], a[1], a[2])) << n;
    }
}

TEST(Fixed192, FastPathAdditionCarriesAndStopsAtTheTop) {
    // The deposit loop adds fast_low values straight into the low 128 bits;
    // 10 x 7 = 70 carries into word 2 (16 per unit there) and equals the sum
    // of the general path.
    unsigned __int128 low;
    ASSERT_TRUE(Fixed192::fast_low(7.0, low));
    EXPECT_FALSE(Fixed192::fast_low(8.0, low));      // general path from 8 up
    EXPECT_FALSE(Fixed192::fast_low(0x1p-73, low));  // and below 2^-72
    EXPECT_FALSE(Fixed192::fast_low(-1.0, low));
    EXPECT_FALSE(Fixed192::fast_low(0.0, low));
    ASSERT_TRUE(Fixed192::fast_low(7.0, low));
    Fixed192 fast, general;
    for (int n = 0; n < 10; ++n) {
        ASSERT_TRUE(fast.add_low(low));
        ASSERT_TRUE(general.add(fx(7.0)));
    }
    EXPECT_EQ(fast, general);
    EXPECT_EQ(fast.words()[2], 4u);
    EXPECT_EQ(fast.to_double(), 70.0);
    Fixed192 top = Fixed192::from_words(~uint64_t(0), ~uint64_t(0), uint64_t(INT64_MAX));
    EXPECT_FALSE(top.add_low(1));
    EXPECT_EQ(top, Fixed192::from_words(~uint64_t(0), ~uint64_t(0), uint64_t(INT64_MAX)));
}

}  // namespace
