// The grid file's path rules and the file steps of its atomic write: what
// the .vdb writer does around OpenVDB, which needs no OpenVDB. They are in the
// engine's core library, so a run checks its grid path before it starts
// without loading the writer (vdb_library.h), and the writer library links
// the same code.
#pragma once

#include <stdexcept>
#include <string>

namespace ep {

// std::runtime_error "vdb file '<path>': <what>".
std::runtime_error vdb_path_error(const std::string& path, const std::string& what);

// Creates an empty, uniquely named file next to `path` and returns its name.
std::string create_temp_file(const std::string& path);
// Flushes the temporary file `tmp` (the write of `path`) to disk.
void sync_file(const std::string& tmp, const std::string& path);
// The likely cause of a failed write of `tmp` when the stream left no errno.
std::string likely_cause(const std::string& tmp);
// Throws check_vdb_path's std::invalid_argument if `path` exists and is not a
// regular file (symbolic links included).
void check_target_kind(const std::string& path);
// Throws check_vdb_voxel_size's std::invalid_argument naming grids.voxel_size.
[[noreturn]] void throw_vdb_voxel_size(double voxel_size);

}  // namespace ep
