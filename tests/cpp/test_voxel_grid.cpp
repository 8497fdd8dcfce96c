// Unit tests for ep::VoxelAccumulator: indexing, conservation, exact sums
// that no order or grouping of deposits and merges can change, and rejection
// of unusable deposits.
#include "voxel_grid.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <limits>
#include <map>
#include <random>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

namespace {

using ep::VoxelAccumulator;
using Coord = VoxelAccumulator::Coord;

uint64_t bits(double v) {
    uint64_t b;
    std::memcpy(&b, &v, sizeof b);
    return b;
}

Coord index_or_fail(const VoxelAccumulator& acc, double x, double y, double z) {
    Coord c{};
    EXPECT_TRUE(acc.index_of(x, y, z, c)) << "position (" << x << ", " << y << ", " << z << ")";
    return c;
}

TEST(VoxelAccumulator, RejectsVoxelSizeThatIsNotPositiveFinite) {
    const double bad[] = {0.0, -0.5, std::numeric_limits<double>::quiet_NaN(), std::numeric_limits<double>::infinity()};
    for (double h : bad) {
        try {
            VoxelAccumulator acc(h);
            FAIL() << "voxel_size " << h << " was accepted";
        } catch (const std::invalid_argument& e) {
            const std::string msg = e.what();
            EXPECT_NE(msg.find("grids.voxel_size"), std::string::npos) << msg;
            EXPECT_NE(msg.find("positive finite"), std::string::npos) << msg;
            if (h == -0.5) {
                EXPECT_NE(msg.find("= -0.5 "), std::string::npos) << msg;
            }
        }
    }
}

TEST(VoxelAccumulator, DepositLandsInExpectedVoxel) {
    VoxelAccumulator acc(0.25);
    // 1.0/0.25 = 4, -0.5/0.25 = -2, 0.3/0.25 = 1.2 -> rounds to 1.
    acc.add(1.0, -0.5, 0.3, 2.0);
    ASSERT_EQ(acc.voxel_count(), 1u);
    EXPECT_EQ(acc.value({4, -2, 1}), 2.0);
    EXPECT_EQ(acc.value({4, -2, 0}), 0.0);
    const auto all = acc.sorted();
    ASSERT_EQ(all.size(), 1u);
    EXPECT_EQ(all[0].first, (Coord{4, -2, 1}));
    EXPECT_EQ(all[0].second, 2.0);
}

TEST(VoxelAccumulator, CellCentredRoundingAtHalfBoundaries) {
    // Voxel size 1 makes x / h exact, so the boundaries are tested exactly.
    VoxelAccumulator acc(1.0);
    // Voxel i covers [i - 0.5, i + 0.5): a point exactly on a boundary belongs
    // to the voxel above it, on both sides of zero.
    EXPECT_EQ(index_or_fail(acc, 0.5, 0, 0)[0], 1);
    EXPECT_EQ(index_or_fail(acc, -0.5, 0, 0)[0], 0);
    EXPECT_EQ(index_or_fail(acc, 1.5, 0, 0)[0], 2);
    EXPECT_EQ(index_or_fail(acc, -1.5, 0, 0)[0], -1);
    EXPECT_EQ(index_or_fail(acc, std::nextafter(0.5, 0.0), 0, 0)[0], 0);
    EXPECT_EQ(index_or_fail(acc, std::nextafter(-0.5, -1.0), 0, 0)[0], -1);
    // Same rule on every axis.
    EXPECT_EQ(index_or_fail(acc, 0, -2.5, 3.5), (Coord{0, -2, 4}));
    // Points at the voxel centre map to that voxel.
    VoxelAccumulator fine(0.5);
    for (int i = -5; i <= 5; ++i)
        EXPECT_EQ(index_or_fail(fine, i * 0.5, -i * 0.5, 0.0), (Coord{i, -i, 0})) << "i = " << i;
}

TEST(VoxelAccumulator, RoundingNearHalfMatchesExtendedPrecisionReference) {
    // Reference: floor(f + 1/2) in 64-bit-mantissa long double, where the sum
    // is exact for every f whose rounding is in doubt (|f| < 2^30, near k + 1/2).
    VoxelAccumulator acc(1.0);
    auto check = [&](double f) {
        Coord c{};
        ASSERT_TRUE(acc.index_of(f, -f, 0.0, c));
        ASSERT_EQ(c[0], static_cast<int32_t>(std::floor(static_cast<long double>(f) + 0.5L))) << "f = " << f;
        ASSERT_EQ(c[1], static_cast<int32_t>(std::floor(-static_cast<long double>(f) + 0.5L))) << "f = " << -f;
    };
    auto around = [&](double centre, int max_ulps) {
        double up = centre, down = centre;
        check(centre);
        for (int s = 0; s < max_ulps; ++s) {
            up = std::nextafter(up, 1e300);
            down = std::nextafter(down, -1e300);
            check(up);
            check(down);
        }
    };
    // Half-way points just below a power of two are where f + 0.5 in double
    // crosses into the next binade and rounds: the classic slip.
    for (int m = 0; m < 30; ++m) around(std::ldexp(1.0, m) - 0.5, 4);
    std::mt19937_64 rng(2024);
    std::uniform_int_distribution<int> k(-100000, 100000);
    for (int n = 0; n < 5000; ++n) around(k(rng) + 0.5, 3);
}

TEST(VoxelAccumulator, RoundingAtZeroAndAtTheIndexLimits) {
    // Expected voxels written out: halves go up, tiny and subnormal f of
    // either sign land in voxel 0, and the largest accepted |f| = 2^30 keeps
    // its exact index.
    VoxelAccumulator acc(1.0);
    const double tiny = std::numeric_limits<double>::denorm_min();
    const double below_half = std::nextafter(0.5, 0.0);
    const double cases[][2] = {{0.0, 0},
                               {-0.0, 0},
                               {tiny, 0},
                               {-tiny, 0},
                               {-0x1p-1060, 0},
                               {0.5, 1},
                               {-0.5, 0},
                               {below_half, 0},
                               {-below_half, 0},
                               {-std::nextafter(0.5, 1.0), -1},
                               {-1.5, -1},
                               {1.5, 2},
                               {0x1p30, 0x1p30},
                               {-0x1p30, -0x1p30},
                               {0x1p30 - 0.5, 0x1p30},
                               {-0x1p30 + 0.5, -0x1p30 + 1}};
    for (const auto& c : cases) {
        const Coord v = index_or_fail(acc, c[0], -c[0], 0.0);
        EXPECT_EQ(v[0], int32_t(c[1])) << "f = " << c[0];
        // -f: the mirrored half-way points round up as well
        const double mirrored = std::floor(-static_cast<long double>(c[0]) + 0.5L);
        EXPECT_EQ(v[1], int32_t(mirrored)) << "f = " << -c[0];
    }
    Coord out{};
    EXPECT_FALSE(acc.index_of(std::nextafter(0x1p30, 1e300), 0.0, 0.0, out));
}

TEST(VoxelAccumulator, MatchesReferenceMapThroughGrowthAndCache) {
    // Mix runs of repeated voxels (cache hits) with jumps (cache misses) over
    // enough voxels to force several table growths.
    VoxelAccumulator acc(0.1);
    // The reference sums exactly in integers of 2^-100 (every value of (0, 1)
    // drawn here is such an integer, and no voxel total reaches 2^7), then
    // rounds once: what the fixed-point accumulator must give.
    std::map<Coord, __int128> ref;
    std::mt19937_64 rng(12345);
    std::uniform_real_distribution<double> pos(-3.0, 3.0), val(0.0, 1.0);
    std::uniform_int_distribution<int> run(1, 6);
    for (int n = 0; n < 20000; ++n) {
        const double x = pos(rng), y = pos(rng), z = pos(rng);
        const int repeats = run(rng);
        for (int r = 0; r < repeats; ++r) {
            const double v = val(rng);
            acc.add(x, y, z, v);
            Coord c{};
            ASSERT_TRUE(acc.index_of(x, y, z, c));
            const double scaled = std::ldexp(v, 100);
            ASSERT_EQ(scaled, std::floor(scaled));
            ref[c] += static_cast<__int128>(scaled);
        }
    }
    ASSERT_EQ(acc.voxel_count(), ref.size());
    const auto all = acc.sorted();
    ASSERT_EQ(all.size(), ref.size());
    size_t i = 0;
    for (const auto& kv : ref) {
        const double exact = std::ldexp(static_cast<double>(kv.second), -100);
        EXPECT_EQ(all[i].first, kv.first);
        EXPECT_EQ(bits(all[i].second), bits(exact));
        EXPECT_EQ(bits(acc.value(kv.first)), bits(exact));
        ++i;
    }
    EXPECT_EQ(acc.dropped(), 0u);
}

TEST(VoxelAccumulator, SumIsConserved) {
    VoxelAccumulator acc(0.05);
    std::mt19937_64 rng(7);
    std::uniform_real_distribution<double> pos(-1.0, 1.0), logv(-12.0, 2.0);
    long double reference = 0.0L;
    for (int n = 0; n < 200000; ++n) {
        // Values over 14 decades, like absorbed weight near and far from a source.
        const double v = std::pow(10.0, logv(rng));
        acc.add(pos(rng), pos(rng), pos(rng), v);
        reference += v;
    }
    const double s = acc.sum();
    EXPECT_NEAR(s, double(reference), 1e-12 * double(reference));
    EXPECT_EQ(acc.dropped(), 0u);
    // The order in which voxels are visited does not enter the result.
    EXPECT_EQ(bits(s), bits(acc.sum()));
}

TEST(VoxelAccumulator, MergeOrderDoesNotChangeBits) {
    std::mt19937_64 rng(99);
    std::uniform_real_distribution<double> pos(-0.5, 0.5), val(1e-6, 1.0);
    VoxelAccumulator a(0.02), b(0.02);
    for (int n = 0; n < 30000; ++n) a.add(pos(rng), pos(rng), pos(rng), val(rng));
    for (int n = 0; n < 30000; ++n) b.add(pos(rng), pos(rng), pos(rng), val(rng));
    a.add(std::nan(""), 0, 0, 1.0);  // dropped counters must merge too

    VoxelAccumulator ab(0.02), ba(0.02);
    ab.merge_from(a);
    ab.merge_from(b);
    ba.merge_from(b);
    ba.merge_from(a);
    VoxelAccumulator a_into_copy = a, b_into_copy = b;
    a_into_copy.merge_from(b);
    b_into_copy.merge_from(a);

    const auto r1 = ab.sorted_fixed(), r2 = ba.sorted_fixed(), r3 = a_into_copy.sorted_fixed(),
               r4 = b_into_copy.sorted_fixed();
    ASSERT_EQ(r1.size(), r2.size());
    ASSERT_EQ(r1.size(), r3.size());
    ASSERT_EQ(r1.size(), r4.size());
    // Overlap is expected at this density; check the test exercises additions.
    ASSERT_LT(r1.size(), a.voxel_count() + b.voxel_count());
    for (size_t i = 0; i < r1.size(); ++i) {
        ASSERT_EQ(r1[i].first, r2[i].first);
        ASSERT_EQ(r1[i].first, r3[i].first);
        ASSERT_EQ(r1[i].first, r4[i].first);
        ASSERT_EQ(r1[i].second, r2[i].second);
        ASSERT_EQ(r1[i].second, r3[i].second);
        ASSERT_EQ(r1[i].second, r4[i].second);
        ep::Fixed128 sum = a.fixed(r1[i].first);
        ASSERT_TRUE(sum.add(b.fixed(r1[i].first)));
        ASSERT_EQ(r1[i].second, sum);
    }
    EXPECT_EQ(bits(ab.sum()), bits(ba.sum()));
    EXPECT_EQ(ab.dropped(), 1u);
    EXPECT_EQ(ba.dropped(), 1u);
}

TEST(VoxelAccumulator, AnySplitOfTheDepositsMergesToTheSameBits) {
    // The engine's threads (and Dask chunks) each sum a different share of
    // the deposits; any split, merged in any grouping, must give the bits of
    // one accumulator that saw every deposit in order. Values span 40
    // decades, where float sums would differ from one grouping to another.
    std::mt19937_64 rng(2027);
    std::uniform_real_distribution<double> pos(-0.2, 0.2), logv(-30.0, 10.0);
    std::uniform_int_distribution<int> share(0, 2);
    VoxelAccumulator all(0.05), part[3] = {VoxelAccumulator(0.05), VoxelAccumulator(0.05), VoxelAccumulator(0.05)};
    for (int n = 0; n < 50000; ++n) {
        const double x = pos(rng), y = pos(rng), z = pos(rng), v = std::pow(10.0, logv(rng));
        all.add(x, y, z, v);
        part[share(rng)].add(x, y, z, v);
    }
    VoxelAccumulator left(0.05), right = part[2];  // ((0 + 1) + 2) and (2 + (1 + 0))
    left.merge_from(part[0]);
    left.merge_from(part[1]);
    left.merge_from(part[2]);
    VoxelAccumulator inner = part[1];
    inner.merge_from(part[0]);
    right.merge_from(inner);
    const auto want = all.sorted_fixed();
    EXPECT_EQ(left.sorted_fixed(), want);
    EXPECT_EQ(right.sorted_fixed(), want);
    EXPECT_EQ(bits(left.sum()), bits(all.sum()));
    EXPECT_EQ(bits(right.sum()), bits(all.sum()));
}

TEST(VoxelAccumulator, OverflowOfAVoxelIsANamedError) {
    VoxelAccumulator acc(1.0);
    const double big = std::ldexp(1.0, 43);  // below the deposit limit 2^47; 16 of them reach 2^47
    try {
        for (int n = 0; n < 16; ++n) acc.add(2, -3, 4, big);
        FAIL() << "a voxel total of 2^47 was accepted";
    } catch (const std::overflow_error& e) {
        const std::string msg = e.what();
        EXPECT_NE(msg.find("voxel (2, -3, 4)"), std::string::npos) << msg;
        EXPECT_NE(msg.find("2^47"), std::string::npos) << msg;
    }
    // The failed addition left the voxel as it was: 15 deposits.
    EXPECT_EQ(acc.value({2, -3, 4}), 15 * big);
}

TEST(VoxelAccumulator, SelfMergeDoubles) {
    VoxelAccumulator a(1.0);
    a.add(0, 0, 0, 1.5);
    a.add(3, 0, 0, 0.25);
    a.merge_from(a);
    EXPECT_EQ(a.value({0, 0, 0}), 3.0);
    EXPECT_EQ(a.value({3, 0, 0}), 0.5);
    EXPECT_EQ(a.voxel_count(), 2u);
}

TEST(VoxelAccumulator, MergeRejectsDifferentVoxelSize) {
    VoxelAccumulator a(0.1), b(0.2);
    b.add(0, 0, 0, 1.0);
    try {
        a.merge_from(b);
        FAIL() << "merge of different voxel sizes was accepted";
    } catch (const std::invalid_argument& e) {
        const std::string msg = e.what();
        EXPECT_NE(msg.find("voxel_size = 0.20000000000000001"), std::string::npos) << msg;
        EXPECT_NE(msg.find("voxel_size = 0.10000000000000001"), std::string::npos) << msg;
    }
    EXPECT_EQ(a.voxel_count(), 0u);
}

TEST(VoxelAccumulator, UnusableDepositsAreDroppedAndCounted) {
    const double nan = std::numeric_limits<double>::quiet_NaN();
    const double inf = std::numeric_limits<double>::infinity();
    VoxelAccumulator acc(0.1);
    acc.add(0.0, 0.0, 0.0, 1.0);
    acc.add(nan, 0.0, 0.0, 2.0);
    acc.add(0.0, nan, 0.0, 4.0);
    acc.add(0.0, 0.0, -inf, 8.0);
    acc.add(1e300, 0.0, 0.0, 16.0);  // finite but beyond the int32 index range
    acc.add(0.0, 0.0, 0.0, nan);     // position fine, value unusable
    acc.add(0.0, 0.0, 0.0, inf);
    acc.add(0.0, 0.0, 0.0, 0x1p47);  // beyond the fixed-point range of one deposit: counted only
    acc.add_index({VoxelAccumulator::kMaxIndex + 1, 0, 0}, 32.0);
    EXPECT_EQ(acc.dropped(), 8u);
    EXPECT_EQ(acc.dropped_value(), 2.0 + 4.0 + 8.0 + 16.0 + 32.0);
    EXPECT_EQ(acc.voxel_count(), 1u);
    EXPECT_EQ(acc.value({0, 0, 0}), 1.0);
    EXPECT_EQ(acc.sum(), 1.0);
    for (const auto& kv : acc.sorted()) EXPECT_TRUE(std::isfinite(kv.second));
}

TEST(VoxelAccumulator, ZeroDepositCreatesNoVoxel) {
    VoxelAccumulator acc(0.1);
    acc.add(0.3, 0.3, 0.3, 0.0);
    acc.add(0.3, 0.3, 0.3, -0.0);
    EXPECT_EQ(acc.voxel_count(), 0u);
    EXPECT_EQ(acc.dropped(), 0u);
}

TEST(VoxelAccumulator, AddIndexMatchesAddAtVoxelCentre) {
    VoxelAccumulator by_pos(0.3), by_index(0.3);
    by_pos.add(0.6, -0.9, 1.2, 0.75);
    by_index.add_index({2, -3, 4}, 0.75);
    EXPECT_EQ(by_pos.sorted(), by_index.sorted());
}

TEST(VoxelAccumulator, MemoryGrowsWithVoxelsAndClearReleasesIt) {
    VoxelAccumulator acc(1.0);
    const size_t empty = acc.memory_bytes();
    for (int i = 0; i < 10000; ++i) acc.add(i, 0, 0, 1.0);
    const size_t full = acc.memory_bytes();
    // At least the key and value of every voxel must be accounted for.
    EXPECT_GE(full - empty, 10000u * (3 * sizeof(int32_t) + sizeof(ep::Fixed128)));
    acc.clear();
    EXPECT_EQ(acc.voxel_count(), 0u);
    EXPECT_EQ(acc.memory_bytes(), empty);
    EXPECT_EQ(acc.voxel_size(), 1.0);
}

// GridSet::deposit computes the voxel index and the weight's fixed-point form
// once for its grids; every grid must still get what add() would give it,
// including the general path (negative, zero, large values) and the drops.
TEST(GridSet, DepositEqualsAddIntoEachGrid) {
    const double nan = std::numeric_limits<double>::quiet_NaN();
    ep::GridSet g(0.5, 2);
    g.deposit(0.2, 0.3, -0.2, true, 0.25, false, 0, 8.0);  // not fluorescent: absorbed only
    g.deposit(0.7, 0.3, -0.2, true, 0.5, true, 1, 0.75);   // voxel (1, 1, 0)
    g.deposit(0.6, 0.3, -0.2, true, 0.0, true, 1, 0.125);  // zero absorbed: no voxel, no drop
    g.deposit(0.6, 0.3, -0.2, true, -1.0, true, 0, 16.0);  // negative and >= 8: add_general
    g.deposit(1e300, 0.0, 0.0, true, 2.0, true, 0, 4.0);   // out of range: dropped with value
    g.deposit(nan, 0.0, 0.0, true, 0.5, true, 1, nan);     // bad position; NaN weight counted only
    EXPECT_EQ(g.absorbed.sorted(), (std::vector<std::pair<Coord, double>>{{{0, 1, 0}, 0.25}, {{1, 1, 0}, -0.5}}));
    EXPECT_EQ(g.fluorescence.sorted(), (std::vector<std::pair<Coord, double>>{{{1, 1, 0}, 16.875}}));
    EXPECT_EQ(g.per_fluorophore[0].sorted(), (std::vector<std::pair<Coord, double>>{{{1, 1, 0}, 16.0}}));
    EXPECT_EQ(g.per_fluorophore[1].sorted(), (std::vector<std::pair<Coord, double>>{{{1, 1, 0}, 0.875}}));
    EXPECT_EQ(g.absorbed.dropped(), 2u);
    EXPECT_EQ(g.absorbed.dropped_value(), 2.5);
    EXPECT_EQ(g.fluorescence.dropped(), 2u);
    EXPECT_EQ(g.fluorescence.dropped_value(), 4.0);
    EXPECT_EQ(g.per_fluorophore[0].dropped(), 1u);
    EXPECT_EQ(g.per_fluorophore[1].dropped(), 1u);
    EXPECT_EQ(g.per_fluorophore[1].dropped_value(), 0.0);
}

// A run that asks for some of the grids only (RunConfig::grid_absorbed,
// grid_fluorescent_light) deposits into those only: the others stay empty,
// with no voxel and no dropped counter, and the asked-for ones get what a
// deposit into every grid gives them.
TEST(GridSet, DepositIntoTheAskedForGridsOnly) {
    const double nan = std::numeric_limits<double>::quiet_NaN();
    for (const bool with_absorbed : {false, true})
        for (const bool with_fluorescence : {false, true}) {
            ep::GridSet all(0.5, 2), some(0.5, 2);
            const double at[3][3] = {{0.2, 0.3, -0.2}, {0.7, 0.3, -0.2}, {nan, 0.0, 0.0}};
            for (const auto& p : at) {
                all.deposit(p[0], p[1], p[2], true, 0.25, true, 1, 0.75);
                some.deposit(p[0], p[1], p[2], with_absorbed, 0.25, with_fluorescence, 1, 0.75);
            }
            const auto expect = [](const VoxelAccumulator& got, const VoxelAccumulator& ref, bool asked) {
                using Voxels = std::vector<std::pair<Coord, double>>;
                EXPECT_EQ(got.sorted(), asked ? ref.sorted() : Voxels());
                EXPECT_EQ(got.dropped(), asked ? ref.dropped() : 0u);
            };
            expect(some.absorbed, all.absorbed, with_absorbed);
            expect(some.fluorescence, all.fluorescence, with_fluorescence);
            expect(some.per_fluorophore[1], all.per_fluorophore[1], with_fluorescence);
            EXPECT_EQ(all.absorbed.voxel_count(), 2u);
        }
}

// The emission grids (one per fluorophore) take emit()'s weight at the
// conversion point only; deposit() never reaches them. They follow the
// per-fluorophore grids in the numbering, and merge and clear with the set.
TEST(GridSet, EmissionGridsTakeOnlyEmitAndMergeWithTheSet) {
    ep::GridSet g(0.5, 1, 2);
    ASSERT_EQ(g.grid_count(), 5u);
    EXPECT_EQ(&g.grid(2), &g.per_fluorophore[0]);
    EXPECT_EQ(&g.grid(3), &g.emission[0]);
    EXPECT_EQ(&g.grid(4), &g.emission[1]);
    g.deposit(0.2, 0.3, -0.2, true, 0.25, true, 0, 0.5);
    g.emit(0.7, 0.3, -0.2, 1, 0.75);
    g.emit(0.6, 0.3, -0.2, 1, 0.125);
    EXPECT_EQ(g.emission[0].voxel_count(), 0u);
    EXPECT_EQ(g.emission[1].sorted(), (std::vector<std::pair<Coord, double>>{{{1, 1, 0}, 0.875}}));
    ep::GridSet h(0.5, 1, 2);
    h.emit(0.7, 0.3, -0.2, 1, 0.125);
    h.merge_from(g);
    EXPECT_EQ(h.emission[1].sorted(), (std::vector<std::pair<Coord, double>>{{{1, 1, 0}, 1.0}}));
    EXPECT_THROW(h.merge_from(ep::GridSet(0.5, 1, 1)), std::invalid_argument);
    h.clear_keep_capacity();
    EXPECT_EQ(h.emission[1].voxel_count(), 0u);
}

}  // namespace
