// The grids of a whole run, filled by all of its worker threads at once.
//
// Each thread deposits one unit at a time into a small staging GridSet (it
// stays in cache) and then adds that set here. Keeping one grid set per
// thread instead doubled the memory the deposits touch at two threads and
// left a serial merge of the threads' sets at the end of the run (colon_polyp
// at 0.2 mm: half a second). Here the voxels are split into kShards shards by
// their 8^3 block (an OpenVDB leaf node), each shard a GridSet behind its own
// mutex, so two threads adding at the same time rarely wait for each other,
// and the run's grids exist once. The sums are exact (fixed_point.h), so the
// order in which threads add their sets does not enter a result.
#pragma once

#include <atomic>
#include <cstdint>
#include <memory>
#include <mutex>
#include <vector>

#include "voxel_grid.h"

namespace ep {

// Throws the std::runtime_error of voxel tables that took `took_bytes`,
// past the `limit_bytes` a run's grids may use (grids.voxel_size named):
// the run's shared grids and a Dask chunk's grids (engine.cpp) stop alike.
[[noreturn]] void throw_voxel_tables_over(double voxel_size, uint64_t took_bytes, uint64_t limit_bytes);

class SharedGridSet {
  public:
    static constexpr int kShardBits = 6;
    static constexpr size_t kShards = size_t(1) << kShardBits;

    // The shape of GridSet(voxel_size, per_fluorophore, emission). Its voxel tables may
    // take at most `max_bytes` (0: no limit): add() that grows them past it
    // throws std::runtime_error naming grids.voxel_size, so that deposits
    // scattered at a tiny voxel size stop the run instead of filling memory.
    SharedGridSet(double voxel_size, size_t per_fluorophore, uint64_t max_bytes = 0, size_t emission = 0);

    // Adds every voxel, dropped counter and the packet count of `g`, exactly.
    // Thread-safe. Throws std::invalid_argument if `g` differs in shape or
    // voxel size, and std::runtime_error past the memory limit.
    void add(const GridSet& g);

    // The shard of voxel c (from its 8^3 block): a multiplicative hash of the
    // block coordinates (>> 3 floors, as OpenVDB's leaf origin does), whose
    // top bits depend on every bit of all three.
    static size_t shard_of(const VoxelAccumulator::Coord& c) {
        const uint64_t h = mix_coord(c[0] >> 3, c[1] >> 3, c[2] >> 3);
        return size_t((h * 0xBF58476D1CE4E5B9ull) >> (64 - kShardBits));
    }

    // The following are not safe while another thread adds.
    size_t grid_count() const { return shards_.front()->grids.grid_count(); }
    // Grid k (numbered as GridSet::grid) as its shards' accumulators: disjoint
    // voxel sets whose union is the grid. The dropped counters are in the first.
    std::vector<const VoxelAccumulator*> parts(size_t k) const;
    uint64_t packets() const { return shards_.front()->grids.packets; }
    size_t voxel_count(size_t k) const;
    // Frees grid k's voxel table in shard `shard` (parts(k)[shard]: its
    // voxels, dropped counters and memory): once they are in the file, the
    // run needs them no more. Not safe while another thread adds, or reads
    // that part.
    void release(size_t k, size_t shard);

  private:
    struct Shard {
        Shard(double voxel_size, size_t per_fluorophore, size_t emission)
            : grids(voxel_size, per_fluorophore, emission) {}
        std::mutex mu;
        GridSet grids;
        size_t bytes = 0;  // grids.memory_bytes() after the last add (guarded by mu)
    };
    // Counts shard s's table growth (under its lock) and throws past the limit.
    void charge(Shard& s);
    std::vector<std::unique_ptr<Shard>> shards_;
    const double voxel_size_;
    const uint64_t max_bytes_;
    std::atomic<uint64_t> bytes_{0};
};

}  // namespace ep
