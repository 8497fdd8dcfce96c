// Unit tests for ep::SharedGridSet (the run's grids, added to by several
// threads at once) and VoxelAccumulator::add_entries (its prefetched batch
// insert). Every deposit is a multiple of 2^-20 below 2^20, so each voxel's
// exact total is an integer count of 2^-20 that a plain int64 map computes
// independently of the accumulators; the sums must equal it exactly.
#include "grid_shards.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <map>
#include <random>
#include <set>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

namespace {

using ep::GridSet;
using ep::SharedGridSet;
using ep::VoxelAccumulator;
using Coord = VoxelAccumulator::Coord;

constexpr double kQuantum = 0x1p-20;  // every deposit is a whole number of these
using Reference = std::map<Coord, int64_t>;

// A deposit of `q` quanta at voxel c, both into the accumulator and the
// integer reference.
void deposit(VoxelAccumulator& acc, Reference& ref, const Coord& c, int64_t q) {
    acc.add_index(c, double(q) * kQuantum);
    ref[c] += q;
}

// Random voxels clustered like photon deposits (a dense core, a sparse
// tail), with negative and positive indices on every axis.
Coord random_voxel(std::mt19937_64& rng) {
    std::uniform_int_distribution<int> core(-12, 12), tail(-3000, 3000), pick(0, 3);
    auto axis = [&]() { return pick(rng) == 0 ? tail(rng) : core(rng); };
    return Coord{axis(), axis(), axis()};
}

// The value of voxel c in grid k of `shared`, found in the part its shard
// names; also checks no other part holds it.
double shared_value(const SharedGridSet& shared, size_t k, const Coord& c) {
    const auto parts = shared.parts(k);
    const size_t home = SharedGridSet::shard_of(c);
    for (size_t s = 0; s < parts.size(); ++s)
        if (s != home) EXPECT_EQ(parts[s]->fixed(c), ep::Fixed128()) << "voxel in a foreign shard " << s;
    return parts[home]->value(c);
}

TEST(AddEntries, MatchesIntegerReferenceThroughGrowth) {
    // Batches into a table that grows inside the batch (starting empty, then
    // small), with keys both new and already present.
    std::mt19937_64 rng(11);
    std::uniform_int_distribution<int64_t> quanta(1, 1 << 20);
    VoxelAccumulator acc(0.5);
    Reference ref;
    for (int batch = 0; batch < 6; ++batch) {
        std::vector<VoxelAccumulator::Entry> entries;
        std::set<Coord> in_batch;  // keys of one batch are distinct, as in a source accumulator
        const size_t n = batch == 0 ? 5 : 3000;
        while (entries.size() < n) {
            const Coord c = random_voxel(rng);
            if (!in_batch.insert(c).second) continue;
            const int64_t q = quanta(rng);
            ep::Fixed128 f;
            ASSERT_TRUE(ep::Fixed128::from_double(double(q) * kQuantum, f));
            entries.push_back({c, f});
            ref[c] += q;
        }
        acc.add_entries(entries.data(), entries.size());
    }
    ASSERT_EQ(acc.voxel_count(), ref.size());
    int64_t total = 0;
    for (const auto& [c, q] : ref) {
        EXPECT_EQ(acc.value(c), double(q) * kQuantum) << c[0] << "," << c[1] << "," << c[2];
        total += q;
    }
    EXPECT_EQ(acc.sum(), double(total) * kQuantum);
}

TEST(SharedGridSet, ConcurrentAddsEqualIntegerReference) {
    // Four threads each add 40 unit-sized grid sets (three grids: absorbed,
    // fluorescence, one per-fluorophore grid) at the same time.
    constexpr int kThreads = 4, kUnits = 40, kDeposits = 600;
    const double h = 0.25;
    SharedGridSet shared(h, 1);
    std::vector<std::vector<Reference>> refs(kThreads, std::vector<Reference>(3));
    std::vector<uint64_t> dropped(kThreads, 0);
    std::vector<std::thread> pool;
    for (int t = 0; t < kThreads; ++t) {
        pool.emplace_back([&, t]() {
            std::mt19937_64 rng(100 + t);
            std::uniform_int_distribution<int64_t> quanta(1, 1 << 24);
            std::uniform_int_distribution<int> which(0, 2);
            GridSet unit(h, 1);
            for (int u = 0; u < kUnits; ++u) {
                for (int d = 0; d < kDeposits; ++d) {
                    const int k = which(rng);
                    deposit(unit.grid(k), refs[t][k], random_voxel(rng), quanta(rng));
                }
                unit.absorbed.add(NAN, 0, 0, 1.0);  // dropped: counted, value summed
                ++dropped[t];
                unit.packets = 64;
                shared.add(unit);
                unit.clear_keep_capacity();
            }
        });
    }
    for (auto& th : pool) th.join();

    EXPECT_EQ(shared.packets(), uint64_t(kThreads * kUnits * 64));
    for (size_t k = 0; k < 3; ++k) {
        Reference all;
        for (int t = 0; t < kThreads; ++t)
            for (const auto& [c, q] : refs[t][k]) all[c] += q;
        ASSERT_EQ(shared.voxel_count(k), all.size()) << "grid " << k;
        int64_t total = 0;
        for (const auto& [c, q] : all) {
            ASSERT_EQ(shared_value(shared, k, c), double(q) * kQuantum) << "grid " << k;
            total += q;
        }
        EXPECT_EQ(VoxelAccumulator::sum(shared.parts(k)), double(total) * kQuantum) << "grid " << k;
        uint64_t n_dropped = 0;
        double dropped_value = 0;
        for (const VoxelAccumulator* p : shared.parts(k)) {
            n_dropped += p->dropped();
            dropped_value += p->dropped_value();
        }
        EXPECT_EQ(n_dropped, k == 0 ? uint64_t(kThreads * kUnits) : 0u) << "grid " << k;
        EXPECT_EQ(dropped_value, k == 0 ? double(kThreads * kUnits) : 0.0) << "grid " << k;
    }
}

TEST(SharedGridSet, ShardKeepsLeafBlocksTogether) {
    // The writer relies on a shard holding whole 8^3 blocks (leaf nodes).
    std::mt19937_64 rng(5);
    std::set<size_t> used;
    for (int n = 0; n < 2000; ++n) {
        const Coord c = random_voxel(rng);
        const Coord origin{c[0] & ~7, c[1] & ~7, c[2] & ~7};
        const size_t s = SharedGridSet::shard_of(c);
        ASSERT_LT(s, SharedGridSet::kShards);
        EXPECT_EQ(s, SharedGridSet::shard_of(origin));
        EXPECT_EQ(s, SharedGridSet::shard_of(Coord{origin[0] + 7, origin[1] + 7, origin[2] + 7}));
        used.insert(s);
    }
    EXPECT_GT(used.size(), SharedGridSet::kShards / 2);  // the blocks spread over the shards
}

TEST(SharedGridSet, RejectsAnotherShapeOrVoxelSize) {
    SharedGridSet shared(0.5, 2);
    EXPECT_THROW(shared.add(GridSet(0.5, 1)), std::invalid_argument);
    try {
        shared.add(GridSet(0.25, 2));
        FAIL() << "a grid set of another voxel size was accepted";
    } catch (const std::invalid_argument& e) {
        EXPECT_NE(std::string(e.what()).find("grids.voxel_size = 0.25"), std::string::npos) << e.what();
    }
}

// release(k, s) frees grid k's voxels in shard s and leaves the others.
TEST(SharedGridSet, ReleaseFreesOneShardOfOneGrid) {
    GridSet g(0.5, 0, 1);
    std::mt19937_64 rng(4);
    for (int n = 0; n < 5000; ++n) {
        const Coord c = random_voxel(rng);
        g.absorbed.add_index(c, 1.0);
        g.fluorescence.add_index(c, 2.0);
        g.emission[0].add_index(c, 0.5);
    }
    SharedGridSet shared(0.5, 0, 0, 1);
    shared.add(g);
    const size_t voxels = shared.voxel_count(0);
    // Shard by shard, as the writer hands them back: a released shard is
    // empty and frees its table; the others and the other grids keep theirs.
    const auto parts = shared.parts(0);
    const size_t first = parts[0]->voxel_count();
    ASSERT_GT(first, 0u);
    shared.release(0, 0);
    EXPECT_EQ(shared.voxel_count(0), voxels - first);
    EXPECT_EQ(parts[0]->memory_bytes(), sizeof(*parts[0]));
    for (size_t s = 1; s < parts.size(); ++s) shared.release(0, s);
    EXPECT_EQ(shared.voxel_count(0), 0u);
    EXPECT_EQ(shared.voxel_count(1), voxels);
    EXPECT_EQ(shared.voxel_count(2), voxels);
    for (const ep::VoxelAccumulator* p : shared.parts(0)) EXPECT_EQ(p->memory_bytes(), sizeof(*p));
}

// The run's voxel tables stop at their memory limit with an error naming
// grids.voxel_size: 20,000 scattered voxels (~0.9 MB of slots and more with
// the tables' doubling) under a 1 MiB limit; the same voxels under no limit
// and under an ample one are all kept.
TEST(SharedGridSet, VoxelTablesStopAtTheirMemoryLimit) {
    GridSet g(0.5, 0);
    std::mt19937_64 rng(9);
    for (int n = 0; n < 20000; ++n) g.absorbed.add_index(random_voxel(rng), 1.0);
    const size_t voxels = g.absorbed.voxel_count();
    for (const uint64_t limit : {uint64_t(0), uint64_t(256) << 20}) {
        SharedGridSet ample(0.5, 0, limit);
        ample.add(g);
        EXPECT_EQ(ample.voxel_count(0), voxels);
    }
    SharedGridSet tight(0.5, 0, uint64_t(1) << 20);
    try {
        tight.add(g);
        FAIL() << "20,000 voxels fit a 1 MiB limit";
    } catch (const std::runtime_error& e) {
        const std::string what = e.what();
        EXPECT_NE(what.find("grids.voxel_size = 0.5: the run's voxel tables took"), std::string::npos) << what;
        EXPECT_NE(what.find("more than the 1 MiB"), std::string::npos) << what;
    }
}

}  // namespace
