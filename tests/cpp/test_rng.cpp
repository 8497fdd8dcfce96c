// Statistical tests of the engine's random numbers (native/rng.h): uniformity
// of single draws, independence of consecutive draws in one stream, and of the
// streams of neighbouring packet indices (a packet draws few numbers, so what
// matters most is that packet k and packet k + 1 do not look alike). Every
// test is a chi-square test at p = 0.001 through the shared helper.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>

#include "rng.h"
#include "stat_util.h"

using ep::Rng;

namespace {

// A pair (a, b) in [0, 1)^2 as the centre of its cell in a k x k grid, numbered
// row by row and scaled to [0, 1): uniform pairs give a uniform cell number,
// so a 1-D chi-square over k^2 equal bins tests the 2-D uniformity.
double cell(double a, double b, int k) {
    const int i = int(a * k), j = int(b * k);
    return (double(i * k + j) + 0.5) / double(k * k);
}

double equal_bins(double a, double b) { return b - a; }

}  // namespace

TEST(Rng, SingleDrawsAreUniform) {
    Rng rng(11, 0);
    ep_test::expect_chi_square_fit([&](std::mt19937_64&) { return rng.uniform(); }, equal_bins, 0.0, 1.0, 1000, 1000000,
                                   0);
}

TEST(Rng, ConsecutivePairsAreUniform) {
    Rng rng(12, 5);
    ep_test::expect_chi_square_fit(
        [&](std::mt19937_64&) {
            const double a = rng.uniform();
            return cell(a, rng.uniform(), 32);
        },
        equal_bins, 0.0, 1.0, 32 * 32, 1000000, 0);
}

// The j-th draws of packets k and k + 1, for the first draw (the packet's first
// step length), a later one, and the first draw of the open-low form.
TEST(Rng, NeighbouringPacketStreamsAreIndependent) {
    for (const int j : {0, 1, 7}) {
        uint64_t k = 0;
        ep_test::expect_chi_square_fit(
            [&](std::mt19937_64&) {
                Rng a(3, k), b(3, k + 1);
                k += 2;
                for (int s = 0; s < j; ++s) {
                    a.next_u64();
                    b.next_u64();
                }
                return cell(a.uniform(), b.uniform(), 32);
            },
            equal_bins, 0.0, 1.0, 32 * 32, 500000, 0);
    }
    // First draws of consecutive packets, one stream each: uniform on their own.
    uint64_t k = 0;
    ep_test::expect_chi_square_fit([&](std::mt19937_64&) { return Rng(4, k++).uniform(); }, equal_bins, 0.0, 1.0, 1000,
                                   1000000, 0);
}

// Neighbouring seeds (same packet index) are as independent as neighbouring packets.
TEST(Rng, NeighbouringSeedsAreIndependent) {
    uint64_t s = 0;
    ep_test::expect_chi_square_fit(
        [&](std::mt19937_64&) {
            Rng a(s, 9), b(s + 1, 9);
            ++s;
            return cell(a.uniform(), b.uniform(), 32);
        },
        equal_bins, 0.0, 1.0, 32 * 32, 500000, 0);
}

TEST(Rng, OpenLowIsInZeroOneAndMatchesUniform) {
    // uniform_open_low is uniform() + 2^-53 on the same draw: in (0, 1], never 0.
    Rng a(21, 3), b(21, 3);
    for (int i = 0; i < 100000; ++i) {
        const double u = a.uniform(), v = b.uniform_open_low();
        ASSERT_GT(v, 0.0);
        ASSERT_LE(v, 1.0);
        ASSERT_EQ(v, u + 0x1.0p-53);
    }
}
