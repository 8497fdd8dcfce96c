// A run in pieces (engine.h: trace_units, UnitReducer; unit_io.h): units traced
// in chunks, packed to bytes, unpacked and reduced in any arrival order give
// the bits of one local run. Byte forms that are not a unit batch are refused.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <stdexcept>
#include <string>
#include <tuple>
#include <vector>

#include "engine.h"
#include "scene.h"
#include "source.h"
#include "unit_io.h"

using namespace ep;

namespace {

void box(float x0, float y0, float z0, float x1, float y1, float z1, std::vector<float>& v, std::vector<uint32_t>& t) {
    v = {x0, y0, z0, x1, y0, z0, x1, y1, z0, x0, y1, z0, x0, y0, z1, x1, y0, z1, x1, y1, z1, x0, y1, z1};
    t = {0, 2, 1, 0, 3, 2, 4, 5, 6, 4, 6, 7, 0, 1, 5, 0, 5, 4, 1, 2, 6, 1, 6, 5, 2, 3, 7, 2, 7, 6, 3, 0, 4, 3, 4, 7};
}

struct Slab {
    Scene scene{1.0, 1.0};
    Source source;
    Slab() : source(lights()) {
        std::vector<float> v;
        std::vector<uint32_t> t;
        box(-50, -50, -0.05f, 50, 50, 0, v, t);
        scene.add_region("slab", v.data(), 8, t.data(), 12, tissue(), 0);
        scene.commit();
    }
    static Medium tissue() {  // MCML's slab optics with a mismatched index n = 1.4
        Medium m;
        std::tie(m.mua, m.mus, m.g, m.n) = std::make_tuple(10.0, 90.0, 0.75, 1.4);
        return m;
    }
    static std::vector<Light> lights() {
        Light l;
        l.center = Vec3(0, 0, 1);
        l.axis = Vec3(0, 0, -1);
        return {l};
    }
};

RunConfig two_threads(uint64_t seed) {
    RunConfig c;
    c.seed = seed;
    c.threads = 2;
    return c;
}

// Traces the run's units in chunks of `chunk`, packs each, and reduces them in
// reverse chunk order (the reducer must restore unit order itself).
RunResult in_pieces(const Slab& s, const RunConfig& c, uint64_t chunk) {
    UnitReducer reducer(s.scene, s.source, c);
    const uint64_t n = reducer.plan().n_units_max;
    std::vector<std::string> packed;
    for (uint64_t first = 0; first < n; first += chunk)
        packed.push_back(pack_units(trace_units(s.scene, s.source, c, first, chunk, nullptr)));
    for (auto it = packed.rbegin(); it != packed.rend(); ++it)
        reducer.add_batch(unpack_units(*it, c.grid_voxel_size, grids_per_unit(c)));
    EXPECT_TRUE(reducer.stopped());
    return reducer.finish(1);
}

}  // namespace

TEST(UnitIo, ChunkedPackedReducedRunIsBitIdenticalWithGrids) {
    Slab s;
    RunConfig c = two_threads(11);
    c.photons = 6000;
    c.grid_voxel_size = 0.01;
    c.grid_path = ::testing::TempDir() + "/unit_io_local.vdb";
    const RunResult local = run(s.scene, s.source, c, nullptr, nullptr);
    c.grid_path = ::testing::TempDir() + "/unit_io_pieces.vdb";
    const RunResult pieces = in_pieces(s, c, 7);
    double sum = 0;
    for (int k = 0; k < kScalarTallies; ++k) {
        EXPECT_EQ(local.scalar[k].mean, pieces.scalar[k].mean) << tally_name(k);
        EXPECT_EQ(local.scalar[k].stderr_, pieces.scalar[k].stderr_) << tally_name(k);
        if (k <= kRoulette) sum += pieces.scalar[k].mean;
    }
    EXPECT_NEAR(sum, 1.0, 1e-9);  // the energy balance
    // Rsp at normal incidence is exact: ((n - 1) / (n + 1))^2.
    EXPECT_NEAR(pieces.scalar[kSpecular].mean, std::pow(0.4 / 2.4, 2), 1e-15);
    EXPECT_EQ(local.packets, pieces.packets);
    EXPECT_EQ(local.records.weight, pieces.records.weight);
    EXPECT_EQ(local.records.position, pieces.records.position);
    EXPECT_EQ(local.records.packet, pieces.records.packet);
    EXPECT_EQ(local.grid_absorbed_sum, pieces.grid_absorbed_sum);
    // The grid holds what was absorbed (no voxel dropped in this slab).
    EXPECT_NEAR(pieces.grid_absorbed_sum, pieces.scalar[kAbsorbed].mean, 1e-12);
    std::remove((::testing::TempDir() + "/unit_io_local.vdb").c_str());
    std::remove(c.grid_path.c_str());
}

TEST(UnitIo, StoreRunStopsAtTheSameUnitAndRecord) {
    Slab s;
    RunConfig c = two_threads(3);
    c.store = 700;
    c.max_photons = 200000;
    const RunResult local = run(s.scene, s.source, c, nullptr, nullptr);
    UnitReducer reducer(s.scene, s.source, c);
    for (uint64_t first = 0; !reducer.stopped(); first += 2) {  // speculative chunks of 2 units
        reducer.add_batch(unpack_units(pack_units(trace_units(s.scene, s.source, c, first, 2, nullptr)), 0, false));
    }
    const RunResult pieces = reducer.finish(1);
    EXPECT_EQ(pieces.records.size(), 700u);
    EXPECT_EQ(local.packets, pieces.packets);
    EXPECT_EQ(local.packets_traced, pieces.packets_traced);
    EXPECT_EQ(local.records.packet, pieces.records.packet);
    EXPECT_EQ(local.scalar[kDiffuse].mean, pieces.scalar[kDiffuse].mean);
    EXPECT_EQ(local.scalar[kDiffuse].stderr_, pieces.scalar[kDiffuse].stderr_);
    EXPECT_EQ(pieces.stop, StopReason::kStore);
}

TEST(UnitIo, RefusesBytesThatAreNotABatch) {
    Slab s;
    RunConfig c;
    c.photons = 1000;
    const std::string good = pack_units(trace_units(s.scene, s.source, c, 0, 2, nullptr));
    EXPECT_THROW(unpack_units("not a batch", 0, false), std::invalid_argument);
    EXPECT_THROW(unpack_units(good.substr(0, good.size() - 3), 0, false), std::invalid_argument);
    EXPECT_THROW(unpack_units(good + "x", 0, false), std::invalid_argument);
    EXPECT_THROW(unpack_units(good, 0.1, false), std::invalid_argument);  // the run asks for grids, the batch has none
    EXPECT_THROW(unpack_units(good, 0.1, true), std::invalid_argument);   // ... per unit: none there either
    EXPECT_EQ(unpack_units(good, 0, false).units.size(), 2u);
    c.grid_voxel_size = 0.01;
    c.grid_path = "unused.vdb";
    const std::string gridded = pack_units(trace_units(s.scene, s.source, c, 0, 2, nullptr));
    EXPECT_THROW(unpack_units(gridded, 0, false), std::invalid_argument);    // grids the run does not keep
    EXPECT_THROW(unpack_units(gridded, 0.01, true), std::invalid_argument);  // per chunk, not per unit
    EXPECT_TRUE(unpack_units(gridded, 0.01, false).grids);
}

TEST(UnitIo, StoreRunWithGridsKeepsOnlyTheMergedUnitsDeposits) {
    // A store run keeps grids per unit (grids_per_unit): the units its threads
    // traced past the stop point are discarded with their deposits, so one
    // thread, two threads and speculative chunks all give the same grid sum,
    // and the grid holds exactly the absorbed weight of the merged packets.
    Slab s;
    RunConfig c = two_threads(5);
    c.store = 500;
    c.max_photons = 200000;
    c.grid_voxel_size = 0.01;
    ASSERT_TRUE(grids_per_unit(c));
    c.grid_path = ::testing::TempDir() + "/unit_io_store2.vdb";
    const RunResult two = run(s.scene, s.source, c, nullptr, nullptr);
    c.threads = 1;
    c.grid_path = ::testing::TempDir() + "/unit_io_store1.vdb";
    const RunResult one = run(s.scene, s.source, c, nullptr, nullptr);
    c.grid_path = ::testing::TempDir() + "/unit_io_store_pieces.vdb";
    UnitReducer reducer(s.scene, s.source, c);
    for (uint64_t first = 0; !reducer.stopped(); first += 3)  // 3 units per chunk: the stop falls inside one
        reducer.add_batch(
            unpack_units(pack_units(trace_units(s.scene, s.source, c, first, 3, nullptr)), c.grid_voxel_size, true));
    const RunResult pieces = reducer.finish(1);
    EXPECT_EQ(two.stop, StopReason::kStore);
    EXPECT_EQ(one.packets, two.packets);
    EXPECT_EQ(pieces.packets, two.packets);
    EXPECT_EQ(one.grid_absorbed_sum, two.grid_absorbed_sum);
    EXPECT_EQ(pieces.grid_absorbed_sum, two.grid_absorbed_sum);
    EXPECT_EQ(one.scalar[kAbsorbed].mean, two.scalar[kAbsorbed].mean);
    EXPECT_NEAR(two.grid_absorbed_sum, two.scalar[kAbsorbed].mean, 1e-12);
    for (const char* f : {"/unit_io_store2.vdb", "/unit_io_store1.vdb", "/unit_io_store_pieces.vdb"})
        std::remove((::testing::TempDir() + f).c_str());
}
