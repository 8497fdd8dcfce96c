// The .vdb writer: the engine's one user of OpenVDB, built as a library of
// its own (libendophoton_vdb.so.1) that the engine loads the first time a run
// writes grids (vdb_library.h), so a process that writes none never loads
// OpenVDB. Default symbol visibility: openvdb::initialize() crashes when
// OpenVDB headers are compiled with -fvisibility=hidden.
#include <openvdb/io/File.h>
#include <openvdb/io/GridDescriptor.h>
#include <openvdb/io/io.h>
#include <openvdb/openvdb.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <cfloat>
#include <cmath>
#include <condition_variable>
#include <cstdio>
#include <cstring>
#include <exception>
#include <fstream>
#include <memory>
#include <mutex>
#include <set>
#include <sstream>
#include <stdexcept>
#include <system_error>
#include <thread>

#include "vdb_files.h"
#include "vdb_library.h"
#include "vdb_writer.h"

namespace ep {

namespace {

void initialize_openvdb() {
    // openvdb::initialize() registers grid and metadata types in global
    // registries; it is not safe to race with itself, so guard it once.
    static std::once_flag flag;
    std::call_once(flag, [] { openvdb::initialize(); });
}

bool openvdb_voxel_size_supported(double voxel_size) {
    if (!(voxel_size > 0) || !std::isfinite(voxel_size)) return false;
    try {
        openvdb::math::Transform::createLinearTransform(voxel_size);
        return true;
    } catch (const openvdb::Exception&) {
        return false;
    }
}

// Metadata names OpenVDB itself writes into grids; a user key with one of these
// names would be silently overwritten or would corrupt how the grid is read.
bool is_reserved_key(const std::string& key) {
    static const std::set<std::string> reserved = {openvdb::GridBase::META_GRID_CLASS,
                                                   openvdb::GridBase::META_GRID_CREATOR,
                                                   openvdb::GridBase::META_GRID_NAME,
                                                   openvdb::GridBase::META_SAVE_HALF_FLOAT,
                                                   openvdb::GridBase::META_IS_LOCAL_SPACE,
                                                   openvdb::GridBase::META_VECTOR_TYPE,
                                                   openvdb::GridBase::META_FILE_BBOX_MIN,
                                                   openvdb::GridBase::META_FILE_BBOX_MAX,
                                                   openvdb::GridBase::META_FILE_COMPRESSION,
                                                   openvdb::GridBase::META_FILE_MEM_BYTES,
                                                   openvdb::GridBase::META_FILE_VOXEL_COUNT,
                                                   openvdb::GridBase::META_FILE_DELAYED_LOAD,
                                                   "meaning",
                                                   "accumulator_sum",
                                                   "dropped_deposits",
                                                   "dropped_value"};
    return reserved.count(key) != 0;
}

void validate(const std::vector<GridOutput>& grids, const std::map<std::string, std::string>& metadata) {
    if (grids.empty()) throw std::invalid_argument("grids: no grid to write (the list is empty)");
    std::set<std::string> names;
    for (size_t i = 0; i < grids.size(); ++i) {
        const GridOutput& g = grids[i];
        if (g.name.empty()) throw std::invalid_argument("grid #" + std::to_string(i) + ": name = '' must not be empty");
        if (!names.insert(g.name).second)
            throw std::invalid_argument("grid '" + g.name + "': name is used by more than one grid");
        for (const VoxelAccumulator* p : g.parts())
            if (p == nullptr)
                throw std::invalid_argument("grid '" + g.name + "': data = null must point to an accumulator");
        if (!(std::isfinite(g.scale) && g.scale > 0)) {
            std::ostringstream msg;
            msg.precision(17);
            msg << "grid '" << g.name << "': scale = " << g.scale << " must be a positive finite number";
            throw std::invalid_argument(msg.str());
        }
        for (const VoxelAccumulator* p : g.parts()) {
            if (p->voxel_size() == grids[0].data->voxel_size()) continue;
            std::ostringstream msg;
            msg.precision(17);
            msg << "grid '" << g.name << "': voxel_size = " << p->voxel_size() << " differs from grid '"
                << grids[0].name << "' voxel_size = " << grids[0].data->voxel_size()
                << "; all grids of a file must share one voxel size";
            throw std::invalid_argument(msg.str());
        }
    }
    for (const auto& kv : metadata) {
        if (kv.first.empty()) throw std::invalid_argument("metadata key '' must not be empty");
        if (is_reserved_key(kv.first))
            throw std::invalid_argument("metadata key '" + kv.first + "' is reserved by the VDB writer or OpenVDB");
    }
}

using FloatTree = openvdb::FloatTree;
using Leaf = FloatTree::LeafNodeType;
using Upper = FloatTree::RootNodeType::ChildNodeType;  // internal node of 32^3 children
using Lower = Upper::ChildNodeType;                    // internal node of 16^3 leaves

// The bytes of tree nodes the write may still make, shared by its threads and
// grids (write_vdb's max_tree_bytes). A voxel whose leaf does not exist yet
// charges the leaf (its object and 512 float values) and any internal node it
// would add, before touchLeaf makes them; a charge past the limit throws.
class TreeBudget {
  public:
    TreeBudget(uint64_t max_bytes, double voxel_size) : max_(max_bytes), voxel_size_(voxel_size) {}
    void charge_new_leaf(const openvdb::tree::ValueAccessor<FloatTree>& acc, const openvdb::Coord& xyz) {
        uint64_t bytes = sizeof(Leaf) + Leaf::SIZE * sizeof(float);
        if (!acc.template probeConstNode<Lower>(xyz)) bytes += sizeof(Lower);
        if (!acc.template probeConstNode<Upper>(xyz)) bytes += sizeof(Upper);
        if (used_.fetch_add(bytes, std::memory_order_relaxed) + bytes <= max_) return;
        std::ostringstream msg;
        msg.precision(6);
        msg << "grids.voxel_size = " << voxel_size_ << ": the deposits lie too scattered at this voxel size: "
            << "their OpenVDB tree nodes would need more than the " << max_ / (1 << 20)
            << " MiB the .vdb writer may use (each leaf of 8^3 voxels takes 2 kB and each internal node 34 kB "
               "or 270 kB, however few voxels it holds); use a larger voxel_size";
        throw std::runtime_error(msg.str());
    }

  private:
    const uint64_t max_;
    const double voxel_size_;
    std::atomic<uint64_t> used_{0};
};

// Sets the voxels of `part` (times `scale`) in `tree`, through an accessor
// that keeps the last leaf and internal nodes, in the accumulator's table
// order (a part is a shard of a run's grids: a few thousand voxels in a few
// hundred leaves, which stay in cache). A value beyond float range is an
// error naming the part's smallest such voxel in (x, y, z) order, so the
// message does not depend on the table order. Throws std::logic_error if a
// voxel is already set (parts overlap).
void fill_part(const GridOutput& g, const VoxelAccumulator& part, FloatTree& tree, TreeBudget& budget) {
    openvdb::tree::ValueAccessor<FloatTree> acc(tree);
    bool bad = false, twice = false;
    VoxelAccumulator::Coord bad_c{};
    double bad_v = 0;
    part.for_each([&](const VoxelAccumulator::Coord& c, const Fixed128& f) {
        const double v = f.to_double() * g.scale;
        if (!(std::fabs(v) <= double(FLT_MAX))) {
            if (!bad || c < bad_c) bad_c = c, bad_v = v;
            bad = true;
            return;
        }
        const openvdb::Coord xyz(c[0], c[1], c[2]);
        if (!acc.probeConstLeaf(xyz)) budget.charge_new_leaf(acc, xyz);
        Leaf* leaf = acc.touchLeaf(xyz);
        const openvdb::Index offset = Leaf::coordToOffset(xyz);
        twice |= leaf->isValueOn(offset);
        leaf->setValueOn(offset, static_cast<float>(v));
    });
    if (bad) {
        std::ostringstream msg;
        msg << "grid '" << g.name << "': voxel (" << bad_c[0] << ", " << bad_c[1] << ", " << bad_c[2]
            << ") value = " << bad_v << " is beyond the float range of a VDB grid";
        throw std::invalid_argument(msg.str());
    }
    if (twice) throw std::logic_error("grid '" + g.name + "': two of its parts hold the same voxel (internal error)");
}

// Moves the leaves of `from` into `into` (two threads' trees of one grid).
// Parts hold disjoint voxel sets, and a run's shards even disjoint leaves, so
// a leaf is usually just handed over; a leaf both hold is joined voxel by
// voxel. Throws std::logic_error if a voxel is set in both (parts overlap).
void move_leaves(FloatTree& from, FloatTree& into, const GridOutput& g) {
    std::vector<Leaf*> leaves;
    leaves.reserve(from.leafCount());
    from.stealNodes(leaves);
    std::vector<std::unique_ptr<Leaf>> owned(leaves.begin(), leaves.end());
    openvdb::tree::ValueAccessor<FloatTree> acc(into);
    for (auto& leaf : owned) {
        Leaf* have = acc.probeLeaf(leaf->origin());
        if (!have) {
            acc.addLeaf(leaf.release());
            continue;
        }
        for (auto it = leaf->cbeginValueOn(); it; ++it) {
            if (have->isValueOn(it.pos()))
                throw std::logic_error("grid '" + g.name + "': two of its parts hold the same voxel (internal error)");
            have->setValueOn(it.pos(), *it);
        }
    }
}

// The exact totals of a part (or, added up, of a grid), taken before the
// part is released: the grid's metadata is written from them.
struct PartTotals {
    uint64_t sum[3] = {0, 0, 0};  // the voxels' sum (Fixed128::add_to_wide)
    uint64_t dropped = 0;
    Fixed128 dropped_value;

    explicit PartTotals(const VoxelAccumulator* part = nullptr) {
        if (!part) return;
        part->add_sum_to(sum);
        dropped = part->dropped();
        dropped_value = part->dropped_value_fixed();
    }
    void add(const PartTotals& o, const GridOutput& g) {
        Fixed128::add_wide(sum, o.sum);
        dropped += o.dropped;
        if (!dropped_value.add(o.dropped_value))
            throw std::overflow_error("grid '" + g.name + "': the dropped deposits of its parts sum to 2^47 or more");
    }
};

// The grid of `g` from its threads' trees (null where a thread filled none
// of its parts) and its parts' totals, with its metadata.
openvdb::FloatGrid::Ptr assemble_grid(const GridOutput& g, std::vector<FloatTree::Ptr> trees, const PartTotals& totals,
                                      const std::map<std::string, std::string>& metadata) {
    auto grid = openvdb::FloatGrid::create(/*background=*/0.0f);
    grid->setName(g.name);
    grid->setGridClass(openvdb::GRID_FOG_VOLUME);
    // The accumulator rounds x / h to the nearest integer, i.e. voxel centres
    // sit at integer multiples of h; a pure linear scale reproduces exactly that.
    grid->setTransform(openvdb::math::Transform::createLinearTransform(g.data->voxel_size()));
    bool first = true;
    for (auto& t : trees) {
        if (!t) continue;
        if (first)
            grid->setTree(t);
        else
            move_leaves(*t, grid->tree(), g);
        first = false;
        t.reset();
    }

    grid->insertMeta("meaning", openvdb::StringMetadata(g.meaning));
    const double sum = Fixed128::words_to_double(totals.sum, 3);
    grid->insertMeta("accumulator_sum", openvdb::DoubleMetadata(sum * g.scale));
    grid->insertMeta("dropped_deposits", openvdb::Int64Metadata(static_cast<int64_t>(totals.dropped)));
    grid->insertMeta("dropped_value", openvdb::DoubleMetadata(totals.dropped_value.to_double() * g.scale));
#ifdef ENDOPHOTON_VERSION
    grid->setCreator("EndoPhoton " ENDOPHOTON_VERSION);
#else
    grid->setCreator("EndoPhoton");
#endif
    for (const auto& kv : metadata) grid->insertMeta(kv.first, openvdb::StringMetadata(kv.second));
    return grid;
}

// Builds the grids on up to `threads` threads while the caller writes them,
// in grid order: the file is written grid by grid, so grid 0 can go out while
// grid 1 is still being filled (OpenVDB's write itself is serial). Every part
// of every grid is a task (so threads share even a single grid's work),
// filled into its thread's tree of that grid; the thread that fills a grid's
// last part joins its threads' trees into the grid. Which thread fills which
// part does not enter the grid: the parts' voxels are disjoint. get(k)
// rethrows grid k's first failure (in part order), so the error does not
// depend on the thread timing.
class GridBuilder {
  public:
    GridBuilder(const std::vector<GridOutput>& grids, const std::map<std::string, std::string>& metadata, int threads,
                uint64_t max_tree_bytes)
        : budget_(max_tree_bytes, grids.front().data->voxel_size()),
          grids_(grids),
          metadata_(metadata),
          remaining_(grids.size()),
          built_(grids.size()),
          grid_errors_(grids.size()) {
        for (size_t k = 0; k < grids.size(); ++k) {
            const auto parts = grids[k].parts();
            for (size_t j = 0; j < parts.size(); ++j) parts_.push_back({k, j, parts[j]});
            remaining_[k].store(parts.size());
        }
        fill_errors_.resize(parts_.size());
        totals_.resize(parts_.size());
        const size_t count = std::max<size_t>(1, std::min(parts_.size(), size_t(std::max(threads, 1))));
        trees_.assign(count, std::vector<FloatTree::Ptr>(grids.size()));
        try {
            for (size_t t = 1; t < count; ++t)
                helpers_.emplace_back([this, t] {
                    while (fill_next(t)) {
                    }
                });
        } catch (const std::system_error&) {
            // No thread to spare: the caller fills the rest in get().
        }
    }
    ~GridBuilder() {
        next_.store(parts_.size());  // an early exit (an error) leaves the parts not started
        for (auto& th : helpers_) th.join();
    }

    // Grid k, once built: the calling thread fills parts (of any grid, in
    // order) until it is.
    openvdb::FloatGrid::ConstPtr get(size_t k) {
        while (!ready(k))
            if (!fill_next(0)) {
                std::unique_lock<std::mutex> lock(mu_);
                cv_.wait(lock, [&] { return built_[k].done; });
            }
        if (grid_errors_[k]) std::rethrow_exception(grid_errors_[k]);
        return built_[k].grid;
    }
    // Gives up grid k (its memory), once written.
    void release(size_t k) { built_[k].grid.reset(); }

  private:
    struct Built {
        openvdb::FloatGrid::Ptr grid;
        bool done = false;  // guarded by mu_
    };
    bool ready(size_t k) {
        std::lock_guard<std::mutex> lock(mu_);
        return built_[k].done;
    }
    // Fills the next part not yet taken, on thread t; false if none is left.
    bool fill_next(size_t t) {
        const size_t i = next_.fetch_add(1);
        if (i >= parts_.size()) return false;
        const Part& part = parts_[i];
        const size_t k = part.grid;
        try {
            FloatTree::Ptr& tree = trees_[t][k];
            if (!tree) tree = std::make_shared<FloatTree>(/*background=*/0.0f);
            fill_part(grids_[k], *part.data, *tree, budget_);
            totals_[i] = PartTotals(part.data);
            if (grids_[k].release_part) grids_[k].release_part(part.index);
        } catch (...) {
            fill_errors_[i] = std::current_exception();
        }
        if (remaining_[k].fetch_sub(1, std::memory_order_acq_rel) == 1) assemble(k);
        return true;
    }
    // Joins grid k's trees and adds its parts' totals, once its last part is
    // filled (each part was handed back, GridOutput::release_part, as it was).
    void assemble(size_t k) {
        openvdb::FloatGrid::Ptr grid;
        std::exception_ptr error;
        for (size_t i = 0; i < parts_.size() && !error; ++i)
            if (parts_[i].grid == k && fill_errors_[i]) error = fill_errors_[i];
        if (!error) {
            try {
                PartTotals totals;
                for (size_t i = 0; i < parts_.size(); ++i)
                    if (parts_[i].grid == k) totals.add(totals_[i], grids_[k]);
                std::vector<FloatTree::Ptr> own;
                for (auto& per_thread : trees_) own.push_back(std::move(per_thread[k]));
                grid = assemble_grid(grids_[k], std::move(own), totals, metadata_);
            } catch (...) {
                error = std::current_exception();
            }
        }
        {
            std::lock_guard<std::mutex> lock(mu_);
            built_[k].grid = std::move(grid);
            grid_errors_[k] = error;
            built_[k].done = true;
        }
        cv_.notify_all();
    }

    TreeBudget budget_;
    const std::vector<GridOutput>& grids_;
    const std::map<std::string, std::string>& metadata_;
    struct Part {
        size_t grid, index;  // grid k's part `index` (GridOutput::parts order)
        const VoxelAccumulator* data;
    };
    std::vector<Part> parts_;                         // grid-major
    std::vector<PartTotals> totals_;                  // per part, once filled
    std::vector<std::atomic<size_t>> remaining_;      // parts of grid k not yet filled
    std::vector<std::vector<FloatTree::Ptr>> trees_;  // [thread][grid]
    std::vector<std::exception_ptr> fill_errors_;     // per part
    std::atomic<size_t> next_{0};
    std::mutex mu_;
    std::condition_variable cv_;
    std::vector<Built> built_;
    std::vector<std::exception_ptr> grid_errors_;  // written with built_[k].done, under mu_
    std::vector<std::thread> helpers_;
};

// openvdb::io::File::write streams into an std::ofstream it never checks, so a
// full disk or a file-size limit would leave a short file reported as written.
// This archive writes the same (seekable) format into a stream we own, and
// every failure of that stream is an error naming the cause.
class CheckedArchive : public openvdb::io::Archive {
  public:
    // Active-mask compression only (inactive values are not stored). Blosc,
    // the default on top of it, finds nothing to squeeze in the float noise of
    // Monte Carlo tallies: at 0.2 mm on colon_polyp it made the file 10%
    // larger (8.2 MB against 7.4 MB) and the write slower, and a reader built
    // without Blosc could not open the file.
    CheckedArchive() { setCompression(openvdb::io::COMPRESS_ACTIVE_MASK); }
    // Writes the grids of `builder`, each as soon as it is built, and frees
    // each once written, keeping its "accumulator_sum" in `sums` (a run's
    // grids then never hold all their trees at once). The sequence
    // is Archive::write's for grids of unique, non-empty names and their own
    // trees: stream flags, header, file metadata, the grid count, then each
    // grid under its own name (the bytes are the same but for the header's
    // random UUID; checked against Archive::write when this was written).
    void write_checked(const std::string& tmp, const std::string& path, GridBuilder& builder, size_t n,
                       const openvdb::MetaMap& meta, std::vector<double>& sums) const {
        std::ofstream os(tmp, std::ios_base::out | std::ios_base::binary | std::ios_base::trunc);
        if (!os) throw vdb_path_error(path, "cannot open the temporary file '" + tmp + "': " + std::strerror(errno));
        errno = 0;
        openvdb::io::StreamMetadata::Ptr stream_meta(new openvdb::io::StreamMetadata);
        openvdb::io::setStreamMetadataPtr(os, stream_meta, /*transfer=*/false);
        openvdb::io::setDataCompression(os, compression());
        openvdb::io::setWriteGridStatsMetadata(os, isGridStatsMetadataEnabled());
        writeHeader(os, /*seekable=*/true);
        meta.writeMeta(os);
        const int32_t count = int32_t(n);
        os.write(reinterpret_cast<const char*>(&count), sizeof count);
        sums.assign(n, 0.0);
        for (size_t k = 0; k < n; ++k) {
            openvdb::FloatGrid::ConstPtr grid = builder.get(k);
            openvdb::io::GridDescriptor gd(grid->getName(), grid->type(), grid->saveFloatAsHalf());
            writeGrid(gd, grid, os, /*seekable=*/true);
            openvdb::io::setDataCompression(os, compression());  // a grid may change it
            sums[k] = grid->metaValue<double>("accumulator_sum");
            grid.reset();
            builder.release(k);
        }
        os.flush();
        const int err = errno;
        if (!os)
            throw vdb_path_error(path, "write failed: " + (err ? std::string(std::strerror(err)) : likely_cause(tmp)));
        os.close();
        if (os.fail()) throw vdb_path_error(path, "write failed on close: " + likely_cause(tmp));
    }
};

std::vector<double> write_file(const std::string& path, const std::vector<GridOutput>& grids,
                               const std::map<std::string, std::string>& metadata, int threads,
                               uint64_t max_tree_bytes) {
    check_vdb_path(path);
    validate(grids, metadata);
    initialize_openvdb();
    const double voxel_size = grids.front().data->voxel_size();
    if (!openvdb_voxel_size_supported(voxel_size)) throw_vdb_voxel_size(voxel_size);

    openvdb::MetaMap file_meta;
    for (const auto& kv : metadata) file_meta.insertMeta(kv.first, openvdb::StringMetadata(kv.second));

    GridBuilder builder(grids, metadata, threads, max_tree_bytes ? max_tree_bytes : tree_memory_limit());
    const std::string tmp = create_temp_file(path);
    std::vector<double> sums;
    try {
        CheckedArchive().write_checked(tmp, path, builder, grids.size(), file_meta, sums);
        sync_file(tmp, path);
    } catch (const openvdb::Exception& e) {
        std::remove(tmp.c_str());
        throw vdb_path_error(path, std::string("write failed: ") + e.what());
    } catch (...) {
        std::remove(tmp.c_str());
        throw;
    }
    try {
        check_target_kind(path);  // a special file or link may have appeared there during the write
    } catch (...) {
        std::remove(tmp.c_str());
        throw;
    }
    if (std::rename(tmp.c_str(), path.c_str()) != 0) {
        const std::string why = std::strerror(errno);
        std::remove(tmp.c_str());
        throw vdb_path_error(path, "cannot rename the temporary file over it: " + why);
    }
    return sums;
}

std::vector<std::string> grid_names(const std::string& path) {
    initialize_openvdb();
    std::vector<std::string> names;
    try {
        openvdb::io::File file(path);
        file.open(/*delayLoad=*/false);
        for (auto it = file.beginName(); it != file.endName(); ++it) names.push_back(it.gridName());
        file.close();
    } catch (const openvdb::Exception& e) {
        throw vdb_path_error(path, std::string("cannot read: ") + e.what());
    }
    return names;
}

}  // namespace

}  // namespace ep

// The library's one entry point (vdb_library.h).
extern "C" const ep::VdbApi* endophoton_vdb_api() {
    static const ep::VdbApi api{ep::kVdbAbi, ep::write_file, ep::grid_names, ep::openvdb_voxel_size_supported,
                                ep::initialize_openvdb};
    return &api;
}
