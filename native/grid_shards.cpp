#include "grid_shards.h"

#include <algorithm>
#include <array>

namespace ep {

SharedGridSet::SharedGridSet(double voxel_size, size_t per_fluorophore) {
    shards_.reserve(kShards);
    for (size_t s = 0; s < kShards; ++s) shards_.push_back(std::make_unique<Shard>(voxel_size, per_fluorophore));
}

void SharedGridSet::add(const GridSet& g) {
    shards_.front()->grids.check_mergeable(g);
    // The voxels of one grid, grouped by shard (a counting sort), so that each
    // shard's lock is taken once per grid.
    size_t most = 0;
    for (size_t k = 0; k < g.grid_count(); ++k) most = std::max(most, g.grid(k).voxel_count());
    std::vector<VoxelAccumulator::Entry> bucketed(most);
    std::array<size_t, kShards + 1> start;
    for (size_t k = 0; k < g.grid_count(); ++k) {
        const VoxelAccumulator& src = g.grid(k);
        start.fill(0);
        src.for_each([&](const VoxelAccumulator::Coord& c, const Fixed192&) { ++start[shard_of(c) + 1]; });
        for (size_t s = 0; s < kShards; ++s) start[s + 1] += start[s];
        std::array<size_t, kShards> next;
        std::copy(start.begin(), start.end() - 1, next.begin());
        src.for_each([&](const VoxelAccumulator::Coord& c, const Fixed192& v) {
            bucketed[next[shard_of(c)]++] = VoxelAccumulator::Entry{c, v};
        });
        for (size_t s = 0; s < kShards; ++s) {
            if (start[s + 1] == start[s]) continue;
            std::lock_guard<std::mutex> lock(shards_[s]->mu);
            shards_[s]->grids.grid(k).add_entries(bucketed.data() + start[s], start[s + 1] - start[s]);
        }
        if (src.dropped() > 0) {
            std::lock_guard<std::mutex> lock(shards_.front()->mu);
            shards_.front()->grids.grid(k).add_dropped(src.dropped(), src.dropped_value_fixed());
        }
    }
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

}  // namespace ep
