// The byte form of traced work units, so that units traced in another process
// (a Dask worker, python/endophoton/distributed.py) reach the client's
// UnitReducer exactly as the engine's own threads hand them over: every double
// travels as its 8 bytes, every grid voxel as (index, exact fixed-point
// value), so merging the unpacked units gives the bits a local run gives. A
// batch carries one grid set for all its units (or, for runs that keep grids
// per unit, one per unit).
#pragma once
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "transport.h"
#include "voxel_grid.h"  // UnitBatch owns grids

namespace ep {

// Units first_unit, first_unit + 1, ... in order, and the grids of them all
// (null when the run has no grids or each unit keeps its own).
struct UnitBatch {
    uint64_t first_unit = 0;
    std::vector<std::unique_ptr<UnitOutput>> units;
    std::unique_ptr<GridSet> grids;
};

std::string pack_units(const UnitBatch& batch);

// Throws std::invalid_argument if `bytes` is not a batch of this engine
// version's format, or its grids are not those of a run with `voxel_size`
// (0: no grids) and grids_per_unit = `per_unit`.
UnitBatch unpack_units(const std::string& bytes, double voxel_size, bool per_unit);

}  // namespace ep
