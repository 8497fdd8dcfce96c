// Unit tests for ep::write_vdb: what is written is read back by OpenVDB itself
// (io::File), not by our own reader, so the file is checked against the format.
#include "vdb_library.h"
#include "vdb_writer.h"

#include <openvdb/io/File.h>
#include <openvdb/openvdb.h>

#include <gtest/gtest.h>

#include <dirent.h>
#include <stdlib.h>
#include <sys/stat.h>
#include <unistd.h>

#include <array>
#include <atomic>
#include <cmath>
#include <fstream>
#include <limits>
#include <map>
#include <random>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

namespace {

using ep::GridOutput;
using ep::VoxelAccumulator;

// A fresh directory per test, removed afterwards, so leftover-file checks see
// only what the test itself produced.
class VdbWriterTest : public ::testing::Test {
  protected:
    void SetUp() override {
        std::string base = ::testing::TempDir();
        if (base.empty() || base.back() != '/') base += '/';
        std::string templ = base + "ep_vdb_test_XXXXXX";
        std::vector<char> buf(templ.begin(), templ.end());
        buf.push_back('\0');
        ASSERT_NE(::mkdtemp(buf.data()), nullptr) << "mkdtemp in " << base;
        dir_ = buf.data();
        ep::ensure_openvdb_initialized();
    }
    void TearDown() override {
        for (const std::string& f : list_dir()) ::unlink((dir_ + "/" + f).c_str());
        ::rmdir(dir_.c_str());
    }
    std::vector<std::string> list_dir() const {
        std::vector<std::string> out;
        if (DIR* d = ::opendir(dir_.c_str())) {
            while (dirent* e = ::readdir(d)) {
                const std::string n = e->d_name;
                if (n != "." && n != "..") out.push_back(n);
            }
            ::closedir(d);
        }
        return out;
    }
    std::string path(const std::string& name) const { return dir_ + "/" + name; }

    std::string dir_;
};

openvdb::FloatGrid::Ptr read_float_grid(const std::string& path, const std::string& name) {
    openvdb::io::File file(path);
    file.open();
    auto base = file.readGrid(name);
    file.close();
    return openvdb::gridPtrCast<openvdb::FloatGrid>(base);
}

TEST_F(VdbWriterTest, WritesGridsThatOpenVdbReadsBack) {
    const double h = 0.1;
    VoxelAccumulator absorbed(h), emitted(h);
    // Known deposit: world (0.3, -0.2, 0.5) -> index (3, -2, 5), two deposits.
    absorbed.add(0.3, -0.2, 0.5, 0.25);
    absorbed.add(0.31, -0.19, 0.52, 0.5);
    std::mt19937_64 rng(3);
    std::uniform_real_distribution<double> pos(-1.0, 1.0), val(1e-5, 1.0);
    for (int n = 0; n < 5000; ++n) absorbed.add(pos(rng), pos(rng), pos(rng), val(rng));
    emitted.add(-0.7, 0.0, 0.1, 3.0);

    const std::map<std::string, std::string> meta = {
        {"packets", "100000"}, {"seed", "7"}, {"unit", "cm"}, {"engine_version", "0.1.0"}};
    const std::string out = path("tally.vdb");
    ep::write_vdb(out,
                  {{"absorbed", "absorbed weight per voxel", &absorbed},
                   {"fluorescence", "emitted fluorescence weight", &emitted}},
                  meta);

    EXPECT_EQ(ep::vdb_grid_names(out), (std::vector<std::string>{"absorbed", "fluorescence"}));

    {
        openvdb::io::File file(out);
        file.open();
        auto fmeta = file.getMetadata();
        for (const auto& kv : meta) {
            ASSERT_TRUE((*fmeta)[kv.first]) << "file metadata " << kv.first;
            EXPECT_EQ(fmeta->metaValue<std::string>(kv.first), kv.second);
        }
        file.close();
    }

    auto grid = read_float_grid(out, "absorbed");
    ASSERT_TRUE(grid);
    EXPECT_EQ(grid->getName(), "absorbed");
    EXPECT_EQ(grid->getGridClass(), openvdb::GRID_FOG_VOLUME);
    EXPECT_EQ(grid->metaValue<std::string>("meaning"), "absorbed weight per voxel");
    for (const auto& kv : meta) EXPECT_EQ(grid->metaValue<std::string>(kv.first), kv.second);
    EXPECT_EQ(grid->metaValue<double>("accumulator_sum"), absorbed.sum());
    EXPECT_EQ(grid->metaValue<int64_t>("dropped_deposits"), 0);
    EXPECT_EQ(grid->metaValue<double>("dropped_value"), 0.0);
    EXPECT_EQ(grid->getCreator().rfind("EndoPhoton", 0), 0u) << grid->getCreator();

    const openvdb::Vec3d vs = grid->voxelSize();
    EXPECT_DOUBLE_EQ(vs.x(), h);
    EXPECT_DOUBLE_EQ(vs.y(), h);
    EXPECT_DOUBLE_EQ(vs.z(), h);

    // The known deposit: its voxel holds the float of the accumulated double,
    // and that voxel's centre is where the deposit was made, to within h/2.
    const openvdb::Coord known(3, -2, 5);
    auto acc = grid->getConstAccessor();
    EXPECT_TRUE(acc.isValueOn(known));
    EXPECT_EQ(acc.getValue(known), static_cast<float>(absorbed.value({3, -2, 5})));
    const openvdb::Vec3d centre = grid->transform().indexToWorld(known);
    EXPECT_NEAR(centre.x(), 0.3, 1e-12);
    EXPECT_NEAR(centre.y(), -0.2, 1e-12);
    EXPECT_NEAR(centre.z(), 0.5, 1e-12);
    // World -> index through OpenVDB's own transform lands on the same voxel.
    EXPECT_EQ(grid->transform().worldToIndexCellCentered(openvdb::Vec3d(0.31, -0.19, 0.52)), known);

    EXPECT_EQ(grid->activeVoxelCount(), absorbed.voxel_count());
    // Every voxel value matches, and the float sum conserves the double sum.
    double total = 0.0;
    size_t visited = 0;
    for (auto it = grid->cbeginValueOn(); it; ++it) {
        ASSERT_TRUE(it.isVoxelValue());
        const openvdb::Coord c = it.getCoord();
        EXPECT_EQ(*it, static_cast<float>(absorbed.value({c.x(), c.y(), c.z()})));
        total += *it;
        ++visited;
    }
    EXPECT_EQ(visited, absorbed.voxel_count());
    EXPECT_NEAR(total, absorbed.sum(), 1e-6 * absorbed.sum());

    auto fl = read_float_grid(out, "fluorescence");
    ASSERT_TRUE(fl);
    EXPECT_EQ(fl->activeVoxelCount(), 1u);
    EXPECT_EQ(fl->getConstAccessor().getValue(openvdb::Coord(-7, 0, 1)), 3.0f);
    EXPECT_EQ(fl->metaValue<std::string>("meaning"), "emitted fluorescence weight");

    // The atomic write leaves exactly the target behind, no temporary file.
    EXPECT_EQ(list_dir(), (std::vector<std::string>{"tally.vdb"}));
}

TEST_F(VdbWriterTest, EmptyAccumulatorGivesValidEmptyGrid) {
    VoxelAccumulator none(0.5);
    none.add(std::nan(""), 0.0, 0.0, 0.75);  // dropped: the grid stays empty
    const std::string out = path("empty.vdb");
    ep::write_vdb(out, {{"absorbed", "nothing deposited", &none}}, {});
    auto grid = read_float_grid(out, "absorbed");
    ASSERT_TRUE(grid);
    EXPECT_EQ(grid->activeVoxelCount(), 0u);
    EXPECT_EQ(grid->getGridClass(), openvdb::GRID_FOG_VOLUME);
    EXPECT_DOUBLE_EQ(grid->voxelSize().x(), 0.5);
    EXPECT_EQ(grid->metaValue<double>("accumulator_sum"), 0.0);
    EXPECT_EQ(grid->metaValue<int64_t>("dropped_deposits"), 1);
    EXPECT_EQ(grid->metaValue<double>("dropped_value"), 0.75);
}

TEST_F(VdbWriterTest, OverwritesExistingFileAtomically) {
    const std::string out = path("t.vdb");
    {
        std::ofstream old(out);
        old << "not a vdb file";
    }
    VoxelAccumulator a(1.0);
    a.add(2, 0, 0, 1.0);
    ep::write_vdb(out, {{"first", "", &a}}, {});
    EXPECT_EQ(ep::vdb_grid_names(out), std::vector<std::string>{"first"});
    ep::write_vdb(out, {{"second", "", &a}}, {});
    EXPECT_EQ(ep::vdb_grid_names(out), std::vector<std::string>{"second"});
    EXPECT_EQ(list_dir(), std::vector<std::string>{"t.vdb"});
}

TEST_F(VdbWriterTest, UnwritablePathErrorNamesPath) {
    VoxelAccumulator a(1.0);
    a.add(0, 0, 0, 1.0);
    const std::string bad = path("no_such_dir/out.vdb");
    try {
        ep::write_vdb(bad, {{"absorbed", "", &a}}, {});
        FAIL() << "write to " << bad << " succeeded";
    } catch (const std::invalid_argument& e) {  // refused before anything is built
        EXPECT_NE(std::string(e.what()).find("grids.path = '" + bad + "'"), std::string::npos) << e.what();
    }
    EXPECT_TRUE(list_dir().empty());
}

// A FIFO, a symbolic link (even to a regular file) or a directory at the path
// is refused, by name, and left as it was; no temporary file is left behind.
TEST_F(VdbWriterTest, RefusesToReplaceWhatIsNotARegularFile) {
    VoxelAccumulator a(1.0);
    a.add(0, 0, 0, 1.0);
    ASSERT_EQ(::mkfifo(path("fifo").c_str(), 0600), 0);
    std::ofstream(path("target.vdb")) << "kept";
    ASSERT_EQ(::symlink("target.vdb", path("link.vdb").c_str()), 0);
    ASSERT_EQ(::mkdir(path("sub").c_str(), 0700), 0);
    for (const auto& [name, kind] : std::vector<std::pair<std::string, std::string>>{
             {"fifo", "a FIFO"}, {"link.vdb", "a symbolic link"}, {"sub", "a directory"}}) {
        try {
            ep::write_vdb(path(name), {{"absorbed", "", &a}}, {});
            ADD_FAILURE() << "replaced " << name;
        } catch (const std::invalid_argument& e) {
            const std::string msg = e.what();
            EXPECT_NE(msg.find("grids.path = '" + path(name) + "' exists and is " + kind), std::string::npos) << msg;
        }
    }
    struct stat st;
    ASSERT_EQ(::lstat(path("fifo").c_str(), &st), 0);
    EXPECT_TRUE(S_ISFIFO(st.st_mode));
    ASSERT_EQ(::lstat(path("link.vdb").c_str(), &st), 0);
    EXPECT_TRUE(S_ISLNK(st.st_mode));
    std::string kept;
    std::ifstream(path("target.vdb")) >> kept;
    EXPECT_EQ(kept, "kept");
    ::rmdir(path("sub").c_str());
    EXPECT_EQ(list_dir().size(), 3u);  // fifo, link.vdb, target.vdb: no temporary file
}

TEST_F(VdbWriterTest, UnreadableFileErrorNamesPath) {
    const std::string missing = path("missing.vdb");
    try {
        ep::vdb_grid_names(missing);
        FAIL() << "reading " << missing << " succeeded";
    } catch (const std::runtime_error& e) {
        EXPECT_NE(std::string(e.what()).find(missing), std::string::npos) << e.what();
    }
}

// Runs write_vdb expecting std::invalid_argument whose message contains `needle`.
void expect_rejected(const std::string& out, const std::vector<GridOutput>& grids,
                     const std::map<std::string, std::string>& meta, const std::string& needle) {
    try {
        ep::write_vdb(out, grids, meta);
        ADD_FAILURE() << "accepted; expected an error mentioning " << needle;
    } catch (const std::invalid_argument& e) {
        EXPECT_NE(std::string(e.what()).find(needle), std::string::npos) << e.what();
    }
}

TEST_F(VdbWriterTest, ScaleMultipliesValuesSumAndDroppedValue) {
    VoxelAccumulator a(0.5);
    a.add(0, 0, 0, 3.0);
    a.add(1, 0, 0, 5.0);
    a.add(std::nan(""), 0, 0, 2.0);  // dropped: counted, its value kept
    const std::string out = path("scaled.vdb");
    ep::write_vdb(out, {{"absorbed", "", &a, 0.25}}, {});
    auto grid = read_float_grid(out, "absorbed");
    ASSERT_TRUE(grid);
    auto acc = grid->getConstAccessor();
    EXPECT_EQ(acc.getValue(openvdb::Coord(0, 0, 0)), 0.75f);
    EXPECT_EQ(acc.getValue(openvdb::Coord(2, 0, 0)), 1.25f);
    EXPECT_EQ(grid->metaValue<double>("accumulator_sum"), 2.0);
    EXPECT_EQ(grid->metaValue<int64_t>("dropped_deposits"), 1);
    EXPECT_EQ(grid->metaValue<double>("dropped_value"), 0.5);
}

TEST_F(VdbWriterTest, RejectsInconsistentInput) {
    VoxelAccumulator a(0.1), b(0.2);
    a.add(0, 0, 0, 1.0);
    b.add(0, 0, 0, 1.0);
    const std::string out = path("bad.vdb");

    expect_rejected(out, {{"absorbed", "", &a}, {"coarse", "", &b}}, {}, "grid 'coarse'");
    expect_rejected(out, {{"absorbed", "", &a}, {"absorbed", "", &a}}, {}, "grid 'absorbed'");
    expect_rejected(out, {{"absorbed", "", nullptr}}, {}, "grid 'absorbed': data");
    expect_rejected(out, {{"", "", &a}}, {}, "name = ''");
    expect_rejected(out, {}, {}, "grids");
    expect_rejected(out, {{"absorbed", "", &a}}, {{"class", "x"}}, "metadata key 'class'");
    expect_rejected(out, {{"absorbed", "", &a}}, {{"meaning", "x"}}, "metadata key 'meaning'");
    expect_rejected(out, {{"big", "", &a, 1e39}}, {}, "grid 'big'");  // finite double, not a finite float
    expect_rejected(out, {{"scaled", "", &a, 0.0}}, {}, "grid 'scaled': scale = 0");
    expect_rejected(out, {{"scaled", "", &a, std::nan("")}}, {}, "grid 'scaled': scale = nan");
    // Nothing, not even a temporary file, is left by a rejected write.
    EXPECT_TRUE(list_dir().empty());
}

}  // namespace

namespace {

// Every active voxel of a grid with its value.
std::map<std::array<int, 3>, float> voxels_of(const openvdb::FloatGrid& grid) {
    std::map<std::array<int, 3>, float> out;
    for (auto it = grid.cbeginValueOn(); it; ++it) {
        const openvdb::Coord c = it.getCoord();
        out[{c.x(), c.y(), c.z()}] = *it;
    }
    return out;
}

}  // namespace

TEST_F(VdbWriterTest, GridFromDisjointPartsHoldsTheirUnionOnAnyThreadCount) {
    // Deposits of whole multiples of 2^-16 split over three parts by voxel
    // (neighbouring voxels, so leaves are shared between parts): the written
    // voxels and the sum must be those of an integer reference.
    const double h = 0.5, quantum = 0x1p-16, scale = 0.125;
    std::vector<VoxelAccumulator> parts(3, VoxelAccumulator(h)), other(3, VoxelAccumulator(h));
    std::map<std::array<int, 3>, int64_t> ref;
    std::mt19937_64 rng(21);
    std::uniform_int_distribution<int> axis(-40, 40);
    std::uniform_int_distribution<int64_t> quanta(1, 1 << 20);
    for (int n = 0; n < 20000; ++n) {
        const std::array<int, 3> c{axis(rng), axis(rng), axis(rng)};
        const int64_t q = quanta(rng);
        const size_t p = size_t((c[0] + c[1] + c[2] + 300) % 3);
        parts[p].add_index({c[0], c[1], c[2]}, double(q) * quantum);
        other[(p + 1) % 3].add_index({c[2], c[1], c[0]}, 1.0);
        ref[c] += q;
    }
    parts[2].add(std::nan(""), 0, 0, 4.0);  // dropped, in the last part
    int64_t total = 0;
    for (const auto& kv : ref) total += kv.second;

    for (int threads : {1, 2, 3}) {
        const std::string out = path("parts" + std::to_string(threads) + ".vdb");
        ep::write_vdb(out,
                      {{"absorbed", "", &parts[0], scale, {&parts[1], &parts[2]}},
                       {"other", "", &other[0], 1.0, {&other[1], &other[2]}}},
                      {}, threads);
        auto grid = read_float_grid(out, "absorbed");
        ASSERT_TRUE(grid);
        const auto got = voxels_of(*grid);
        ASSERT_EQ(got.size(), ref.size()) << threads << " threads";
        for (const auto& [c, q] : ref)
            ASSERT_EQ(got.at(c), static_cast<float>(double(q) * quantum * scale)) << threads << " threads";
        EXPECT_EQ(grid->metaValue<double>("accumulator_sum"), double(total) * quantum * scale);
        EXPECT_EQ(grid->metaValue<int64_t>("dropped_deposits"), 1);
        EXPECT_EQ(grid->metaValue<double>("dropped_value"), 4.0 * scale);
        auto second = read_float_grid(out, "other");
        ASSERT_TRUE(second);
        EXPECT_EQ(second->activeVoxelCount(), ref.size());
    }
}

// Each part is handed back (release_part) once its voxels are in the tree,
// exactly once, on any thread count: a caller that frees it there (the engine
// frees its voxel tables shard by shard) still gets every voxel and the exact
// sums and dropped counters.
TEST_F(VdbWriterTest, EachPartIsReleasedOnceItIsRead) {
    const double h = 0.5;
    for (int threads : {1, 2, 3}) {
        std::vector<VoxelAccumulator> a(2, VoxelAccumulator(h)), b(2, VoxelAccumulator(h));
        for (int i = 0; i < 300; ++i) {
            a[size_t(i % 2)].add_index({i, 0, 0}, 0.25);
            b[size_t(i % 2)].add_index({0, i, 1}, 0.5);
        }
        a[1].add_index({VoxelAccumulator::kMaxIndex + 1, 0, 0}, 3.0);  // dropped, in the part released second
        std::atomic<int> released_a[2] = {{0}, {0}}, released_b[2] = {{0}, {0}};
        const auto free_parts = [](std::vector<VoxelAccumulator>& parts, std::atomic<int>* count) {
            return [&parts, count](size_t i) {
                parts.at(i).clear();
                ++count[i];
            };
        };
        const std::string out = path("released" + std::to_string(threads) + ".vdb");
        const std::vector<double> sums = ep::write_vdb(out,
                                                       {{"a", "", &a[0], 1.0, {&a[1]}, free_parts(a, released_a)},
                                                        {"b", "", &b[0], 2.0, {&b[1]}, free_parts(b, released_b)}},
                                                       {}, threads);
        for (int i : {0, 1}) {
            EXPECT_EQ(released_a[i].load(), 1) << threads << " threads, part " << i;
            EXPECT_EQ(released_b[i].load(), 1) << threads << " threads, part " << i;
        }
        EXPECT_EQ(a[0].voxel_count() + a[1].voxel_count() + b[0].voxel_count() + b[1].voxel_count(), 0u);
        EXPECT_EQ(sums, (std::vector<double>{75.0, 300.0}));
        EXPECT_EQ(read_float_grid(out, "a")->activeVoxelCount(), 300u);
        EXPECT_EQ(read_float_grid(out, "a")->metaValue<int64_t>("dropped_deposits"), 1);
        EXPECT_EQ(read_float_grid(out, "a")->metaValue<double>("dropped_value"), 3.0);
        EXPECT_EQ(read_float_grid(out, "b")->activeVoxelCount(), 300u);
    }
}

TEST_F(VdbWriterTest, OverlappingPartsAreAnInternalError) {
    VoxelAccumulator a(0.5), b(0.5), c(0.5);
    a.add_index({1, 2, 3}, 1.0);
    b.add_index({9, 9, 9}, 1.0);
    b.add_index({1, 2, 3}, 2.0);
    c.add_index({0, 2, 3}, 1.0);  // a's leaf, another voxel: joined, not an overlap
    const std::string out = path("overlap.vdb");
    // One thread fills every part into one tree; more threads fill parts into
    // their own trees and join them: both must see the shared voxel.
    for (int threads : {1, 2, 3}) {
        EXPECT_THROW(ep::write_vdb(out, {{"absorbed", "", &a, 1.0, {&c, &b}}}, {}, threads), std::logic_error)
            << threads << " threads";
        EXPECT_TRUE(list_dir().empty());  // nothing written
    }
}

TEST_F(VdbWriterTest, ValueBeyondFloatRangeNamesTheSameVoxelOnAnyThreadCount) {
    // Voxels of 1 (1e30 once scaled) fill every part; a few of 1e9 overflow a
    // float once scaled. The error names the smallest of them, in (x, y, z)
    // order, in the first part that holds one: the same voxel whatever the
    // thread count and the accumulators' table order.
    std::vector<VoxelAccumulator> parts(4, VoxelAccumulator(1.0));
    for (int i = 0; i < 400; ++i) parts[size_t(i) % 4].add_index({i / 7 - 20, i % 13, i % 5}, 1.0);
    parts[1].add_index({5, 0, 0}, 1e9);
    parts[1].add_index({-3, 7, 1}, 1e9);
    parts[1].add_index({-3, 9, -2}, 1e9);
    parts[2].add_index({-3, 7, 0}, 1e9);  // smaller, but in a later part
    parts[3].add_index({-90, 0, 0}, 1e9);
    for (int threads : {1, 2, 3}) {
        const std::string out = path("huge.vdb");
        try {
            ep::write_vdb(out, {{"huge", "", &parts[0], 1e30, {&parts[1], &parts[2], &parts[3]}}}, {}, threads);
            ADD_FAILURE() << "no error at " << threads << " threads";
        } catch (const std::invalid_argument& e) {
            EXPECT_NE(std::string(e.what()).find("grid 'huge': voxel (-3, 7, 1) value = 1e+39"), std::string::npos)
                << e.what();
        }
        EXPECT_TRUE(list_dir().empty());
    }
}

// Deposits scattered one to a node: 40 voxels, each 4096 voxels from the
// next, need 40 leaves and 40 internal nodes of each level, about 12 MB of
// tree for 40 voxels. Under a 1 MiB limit the write stops before making them,
// naming grids.voxel_size, and leaves no file; under an ample one it writes
// every voxel. The limit counts the nodes exactly as OpenVDB sizes them.
TEST_F(VdbWriterTest, ScatteredVoxelsStopAtTheTreeMemoryLimit) {
    VoxelAccumulator a(0.25);
    for (int i = 0; i < 40; ++i) a.add_index({4096 * i, -4096 * i, 0}, 1.0 + i);
    const std::string out = path("scattered.vdb");
    try {
        ep::write_vdb(out, {{"absorbed", "", &a}}, {}, 2, uint64_t(1) << 20);
        FAIL() << "a 1 MiB limit let 40 scattered voxels through";
    } catch (const std::runtime_error& e) {
        const std::string what = e.what();
        EXPECT_NE(what.find("grids.voxel_size = 0.25"), std::string::npos) << what;
        EXPECT_NE(what.find("1 MiB"), std::string::npos) << what;
    }
    EXPECT_TRUE(list_dir().empty());
    ep::write_vdb(out, {{"absorbed", "", &a}}, {}, 2, uint64_t(64) << 20);
    auto grid = read_float_grid(out, "absorbed");
    ASSERT_TRUE(grid);
    EXPECT_EQ(grid->activeVoxelCount(), 40u);
    EXPECT_EQ(grid->tree().getValue(openvdb::Coord(4096 * 39, -4096 * 39, 0)), 40.0f);
}

// Voxels too small for OpenVDB's linear transform are refused by name
// before anything is written; the smallest accepted one writes.
TEST_F(VdbWriterTest, VoxelBelowOpenVdbScaleIsRefusedByName) {
    EXPECT_FALSE(ep::vdb_voxel_size_supported(1e-5));
    EXPECT_FALSE(ep::vdb_voxel_size_supported(0.0));
    EXPECT_TRUE(ep::vdb_voxel_size_supported(2e-5));
    VoxelAccumulator tiny(1e-5);
    tiny.add_index({1, 2, 3}, 1.0);
    expect_rejected(path("tiny.vdb"), {{"absorbed", "", &tiny}}, {}, "grids.voxel_size = 1e-05");
    EXPECT_TRUE(list_dir().empty());
    EXPECT_GT(ep::tree_memory_limit(), uint64_t(0));
}

// The engine checks a run's voxel size with OpenVDB's rule computed without
// OpenVDB (vdb_files.cpp), so that a run loads the writer library only to
// write: the rule gives OpenVDB's own answer (the library's, vdb_api) at every
// size about its threshold (the cube root of 3e-15, ~1.442e-5), at the
// doubles next to it, and far from it.
TEST(VdbVoxelSize, RuleAgreesWithOpenVdbAboutTheThreshold) {
    const ep::VdbApi& api = ep::vdb_api();
    std::vector<double> sizes = {1e-300, 1e-20, 1e-6, 1e-5, 1.4e-5, 1.44e-5, 1.45e-5, 2e-5, 1.0, 1e100, 1e300};
    double at = std::cbrt(3e-15);
    for (int k = 0; k < 64; ++k) at = std::nextafter(at, 0.0);
    for (int k = 0; k < 128; ++k, at = std::nextafter(at, 1.0)) sizes.push_back(at);
    for (int k = -200; k <= 200; ++k) sizes.push_back(std::cbrt(3e-15) * (1 + k * 1e-4));
    int refused = 0, accepted = 0;
    for (double s : sizes) {
        const bool openvdb = api.voxel_size_supported(s);
        EXPECT_EQ(ep::vdb_voxel_size_supported(s), openvdb) << "voxel size " << s;
        (openvdb ? accepted : refused) += 1;
    }
    // Both answers occur among the doubles next to the threshold.
    EXPECT_GT(refused, 64);
    EXPECT_GT(accepted, 64);
    EXPECT_FALSE(ep::vdb_voxel_size_supported(-1.0));
    EXPECT_FALSE(ep::vdb_voxel_size_supported(std::numeric_limits<double>::infinity()));
    EXPECT_FALSE(ep::vdb_voxel_size_supported(std::nan("")));
}
