// Where the .vdb writer comes from. OpenVDB is a large library (loading it
// took 26 MB of a process's memory and most of the dynamic linker's
// relocations when `import endophoton` loaded it), and only a run that writes
// grids uses it. So the writer (vdb_writer.cpp, OpenVDB's one user) is a
// library of its own, libendophoton_vdb.so.1, installed beside the engine's
// module, and the engine loads it the first time it needs it: write_vdb,
// vdb_grid_names and ensure_openvdb_initialized (vdb_writer.h) call through
// vdb_api(). A process that writes no grids never loads OpenVDB, and a run
// that writes them loads it when its tracing is done, to write
// (tests/python/test_vdb_loading.py).
#pragma once

#include <cstdint>
#include <map>
#include <string>
#include <vector>

#include "vdb_writer.h"

namespace ep {

// Changes whenever what crosses into the library changes shape: a library
// built from other sources than the engine is refused, never called.
constexpr uint32_t kVdbAbi = uint32_t(1000000 + 100 * sizeof(GridOutput) + sizeof(VoxelAccumulator));

// The writer's functions, as the library exports them.
struct VdbApi {
    uint32_t abi;  // kVdbAbi of the library's sources
    std::vector<double> (*write)(const std::string& path, const std::vector<GridOutput>& grids,
                                 const std::map<std::string, std::string>& metadata, int threads,
                                 uint64_t max_tree_bytes);
    std::vector<std::string> (*grid_names)(const std::string& path);
    // OpenVDB's own answer to vdb_voxel_size_supported's rule (for tests).
    bool (*voxel_size_supported)(double voxel_size);
    void (*initialize)();
};

// The library's file name, and the name of its entry point.
constexpr const char* kVdbLibrary = "libendophoton_vdb.so.1";
constexpr const char* kVdbEntry = "endophoton_vdb_api";

// The writer, loaded on the first call (thread-safe): from the process when
// it is linked in already (the C++ tests link it), else from kVdbLibrary in
// the folder of the object that holds the engine (the Python module's).
// Throws std::runtime_error naming the library's path if it cannot be loaded
// or was built from other sources; every later call throws the same.
const VdbApi& vdb_api();

}  // namespace ep

extern "C" const ep::VdbApi* endophoton_vdb_api();
