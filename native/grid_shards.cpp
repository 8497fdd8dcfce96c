#include "grid_shards.h"

#include <algorithm>
#include <array>
#include <sstream>
#include <stdexcept>

#ifdef __GLIBC__
#include <malloc.h>
#endif

namespace ep {

namespace {
// Entries a thread's shard bucket keeps between adds: a worker's staging set
// (512 packets, engine.cpp) puts a few hundred voxels in each bucket
// (colon_polyp at 0.2 mm: ~100 per 150 packets), so this keeps every
// staging set's buckets in memory, and at most 64 x 4096 x 32 bytes = 8 MB
// per thread.
constexpr size_t kKeptBucketEntries = 4096;
}  // namespace

SharedGridSet::SharedGridSet(double voxel_size, size_t per_fluorophore, uint64_t max_bytes, size_t emission)
    : voxel_size_(voxel_size), max_bytes_(max_bytes) {
    shards_.reserve(kShards);
    for (size_t s = 0; s < kShards; ++s) {
        shards_.push_back(std::make_unique<Shard>(voxel_size, per_fluorophore, emission));
        shards_.back()->bytes = shards_.back()->grids.memory_bytes();
        bytes_ += shards_.back()->bytes;
    }
}

void throw_voxel_tables_over(double voxel_size, uint64_t took_bytes, uint64_t limit_bytes) {
    std::ostringstream msg;
    msg.precision(6);
    msg << "grids.voxel_size = " << voxel_size << ": the run's voxel tables took " << (took_bytes >> 20)
        << " MiB, more than the " << (limit_bytes >> 20)
        << " MiB its grids may use (the deposits lie scattered, a new voxel for most of them); use a larger "
           "voxel_size, or fewer packets";
    throw std::runtime_error(msg.str());
}

void SharedGridSet::charge(Shard& s) {
    const size_t now = s.grids.memory_bytes();
    const uint64_t total = bytes_.fetch_add(now - s.bytes, std::memory_order_relaxed) + (now - s.bytes);
    s.bytes = now;
    if (max_bytes_ == 0 || total <= max_bytes_) return;
    throw_voxel_tables_over(voxel_size_, total, max_bytes_);
}

void SharedGridSet::add(const GridSet& g) {
    shards_.front()->grids.check_mergeable(g);
    // The voxels of one grid, grouped by shard in one walk of its table, so
    // that each shard's lock is taken once per grid. The buckets are the
    // calling thread's and keep their memory from one unit to the next: a
    // run adds one staging set per unit, and allocating (and zeroing) the
    // buffer every time cost as much as filling it.
    thread_local std::array<std::vector<VoxelAccumulator::Entry>, kShards> buckets;
    for (size_t k = 0; k < g.grid_count(); ++k) {
        const VoxelAccumulator& src = g.grid(k);
        for (auto& b : buckets) b.clear();
        src.for_each([&](const VoxelAccumulator::Coord& c, const Fixed128& v) {
            buckets[shard_of(c)].push_back(VoxelAccumulator::Entry{c, v});
        });
        for (size_t s = 0; s < kShards; ++s) {
            if (buckets[s].empty()) continue;
            std::lock_guard<std::mutex> lock(shards_[s]->mu);
            shards_[s]->grids.grid(k).add_entries(buckets[s].data(), buckets[s].size());
            charge(*shards_[s]);
        }
        if (src.dropped() > 0) {
            std::lock_guard<std::mutex> lock(shards_.front()->mu);
            shards_.front()->grids.grid(k).add_dropped(src.dropped(), src.dropped_value_fixed());
        }
    }
    // A large set (a Dask chunk's grids) must not leave its copy behind in a
    // thread that lives on: buckets beyond a staging set's size are freed.
    for (auto& b : buckets)
        if (b.capacity() > kKeptBucketEntries) std::vector<VoxelAccumulator::Entry>().swap(b);
    std::lock_guard<std::mutex> lock(shards_.front()->mu);
    shards_.front()->grids.packets += g.packets;
}

std::vector<const VoxelAccumulator*> SharedGridSet::parts(size_t k) const {
    std::vector<const VoxelAccumulator*> out;
    for (const auto& s : shards_) out.push_back(&s->grids.grid(k));
    return out;
}

size_t SharedGridSet::voxel_count(size_t k) const {
    size_t n = 0;
    for (const auto& s : shards_) n += s->grids.grid(k).voxel_count();
    return n;
}

void SharedGridSet::release(size_t k, size_t shard) {
    shards_.at(shard)->grids.grid(k).clear();
#ifdef __GLIBC__
    // The tables were allocated by the worker threads, in their malloc
    // arenas, and the writer's tree nodes come from another: the freed tables
    // would stay in the process, unused, while the tree grows. malloc_trim
    // hands their pages back to the system, once per 8 shards (an eighth of a
    // grid's tables), as each call walks every arena's free chunks.
    if (shard % 8 == 7 || shard + 1 == kShards) malloc_trim(0);
#endif
}

}  // namespace ep
