// OpenVDB output of voxel tallies.
//
// The functions that need OpenVDB (write_vdb, vdb_grid_names,
// ensure_openvdb_initialized) are implemented in
// vdb_writer.cpp, the only place that includes OpenVDB, which is built as a
// library of its own with default symbol visibility (openvdb::initialize()
// crashes when OpenVDB headers are compiled with -fvisibility=hidden, as in
// the pybind11 module); the engine loads it on their first call
// (vdb_library.h). The path and memory checks (vdb_files.cpp) need no OpenVDB.
#pragma once

#include <cstdint>
#include <functional>
#include <map>
#include <string>
#include <vector>

#include "voxel_grid.h"

namespace ep {

struct GridOutput {
    std::string name;              // grid name in the file (unique, non-empty)
    std::string meaning;           // stored as per-grid string metadata "meaning"
    const VoxelAccumulator* data;  // not owned; must outlive the write_vdb call
    // Every voxel value, the sum and the dropped value are written multiplied
    // by this (the engine's per-launched-packet normalisation, 1 / packets).
    double scale = 1.0;
    // Further parts of the same grid (not owned): accumulators holding voxel
    // sets disjoint from `data`'s and from each other's, such as the shards of
    // a run's grids (grid_shards.h). The grid is their union, its sum and
    // dropped counters the totals.
    std::vector<const VoxelAccumulator*> more_parts = {};
    // Called (if set) with part i (numbered as parts(): 0 is `data`) once its
    // voxels are in the grid's tree and its sums are taken, on the thread that
    // filled it: the part is not read again, and the caller may free it. A run
    // frees its voxel tables shard by shard, so the tree grows while the
    // tables it is made from shrink (colon at 0.2 mm: peak 298 -> 279 MB,
    // docs/performance.md §15). Any failure may leave parts released.
    std::function<void(size_t part)> release_part = nullptr;

    std::vector<const VoxelAccumulator*> parts() const {
        std::vector<const VoxelAccumulator*> all{data};
        all.insert(all.end(), more_parts.begin(), more_parts.end());
        return all;
    }
};

// Writes one openvdb::FloatGrid per entry of `grids` to `path`.
//  - grid class FOG_VOLUME, background 0, one active voxel per accumulator voxel
//    (values times `scale`, converted to float), linear transform with the accumulator's voxel
//    size, so index (i, j, k) is the world point (i, j, k) * voxel_size;
//  - per-grid metadata: "meaning" (string), "accumulator_sum" (double, the
//    accumulator's exact sum times `scale`, which the float voxels were made
//    from), "dropped_deposits" (int64) and "dropped_value" (double, times
//    `scale`) from the accumulator's counters,
//    creator "EndoPhoton <version>", and a copy of every `metadata` entry;
//  - file-level metadata: every `metadata` entry, as strings.
// The file is written to a temporary file next to `path` and renamed over it,
// so readers never see a half-written file and a failed write leaves any
// previous file untouched.
// The grids are built on up to `threads` threads (their parts in parallel),
// and each is written as soon as it is built and freed once written. Returns each grid's
// "accumulator_sum", in `grids` order.
// Throws std::invalid_argument for a path check_vdb_path refuses (before
// anything is built, and again just before the rename), and for bad input
// (empty list, null data, empty or
// duplicate name, reserved metadata key, voxel sizes that differ, a value
// beyond float range), naming the grid or key; std::logic_error if the parts
// of a grid overlap; std::runtime_error naming the path if the file cannot be
// written.
// The grids' OpenVDB trees may take at most `max_tree_bytes` (0: three
// quarters of the memory available when the write starts, tree_memory_limit).
// A tree node costs far more than a voxel (a leaf 2 kB, an internal node
// 34 kB or 270 kB), so deposits scattered at a tiny voxel size could need
// many gigabytes for a few thousand voxels: before a node is made, the write
// charges it, and once the next would pass the limit it throws
// std::runtime_error naming grids.voxel_size, leaving no file.
std::vector<double> write_vdb(const std::string& path, const std::vector<GridOutput>& grids,
                              const std::map<std::string, std::string>& metadata, int threads = 1,
                              uint64_t max_tree_bytes = 0);

// Three quarters of the memory this process can still take: the smaller of
// the system's available memory (/proc/meminfo MemAvailable, else the free
// physical pages) and what the address-space limit (ulimit -v) leaves.
uint64_t tree_memory_limit();

// Whether OpenVDB can scale its index space to voxels of `voxel_size` (its
// linear transform refuses a scale whose cube is below 3e-15, so voxels
// below ~1.44e-5 scene units cannot be written): OpenVDB's rule, computed
// here without OpenVDB (vdb_files.cpp).
bool vdb_voxel_size_supported(double voxel_size);
// Throws std::invalid_argument naming grids.voxel_size unless it is supported
// (the engine checks it before a run, write_vdb before a write).
void check_vdb_voxel_size(double voxel_size);

// Throws std::invalid_argument naming grids.path and its value unless a grid
// file can be written there: the path must not be empty or longer than
// PATH_MAX, its file name must leave room for the temporary file's suffix
// within NAME_MAX, its directory must exist and be writable, and the path
// itself must be new or an existing regular file. Anything else that exists
// there (a directory, a FIFO, a socket, a device, and any symbolic link,
// wherever it points) is refused: the write replaces the file by a rename,
// which would silently turn a special file into a regular one. The engine
// checks it before a run (validate_config), write_vdb before it writes and
// again just before its rename.
void check_vdb_path(const std::string& path);

// Names of the grids stored in a .vdb file, in file order. Throws
// std::runtime_error naming the path if the file cannot be read.
std::vector<std::string> vdb_grid_names(const std::string& path);

// Thread-safe, idempotent openvdb::initialize().
void ensure_openvdb_initialized();

}  // namespace ep
