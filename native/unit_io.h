// The byte form of traced work units, so that units traced in another process
// (a Dask worker, python/endophoton/distributed.py) reach the client's
// UnitReducer exactly as the engine's own threads hand them over: every double
// travels as its 8 bytes, every grid voxel as (index, value), so merging the
// unpacked units gives the bits a local run gives.
#pragma once
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "transport.h"
#include "voxel_grid.h"  // UnitOutput owns accumulators

namespace ep {

// Units first_unit, first_unit + 1, ... in order.
struct UnitBatch {
    uint64_t first_unit = 0;
    std::vector<std::unique_ptr<UnitOutput>> units;
};

std::string pack_units(const UnitBatch& batch);

// Throws std::invalid_argument if `bytes` is not a batch of this engine
// version's format, or its grids are not of `voxel_size` (0: no grids).
UnitBatch unpack_units(const std::string& bytes, double voxel_size);

}  // namespace ep
