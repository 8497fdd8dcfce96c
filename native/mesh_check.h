// Validation of region meshes before they reach Embree. A region must be a
// closed (watertight), consistently and outward oriented triangle mesh with
// finite coordinates and no degenerate triangles, otherwise "inside" is not
// defined and packets would leak.
#pragma once
#include <cstdint>
#include <string>
#include <vector>

namespace ep {

struct MeshReport {
    double signed_volume = 0;  // scene units^3, > 0 for outward orientation
    double bbox_min[3] = {0, 0, 0}, bbox_max[3] = {0, 0, 0};
    size_t welded_vertices = 0;  // distinct positions after exact welding
};

// Throws std::invalid_argument naming `owner`, the field and the offending value.
// Vertices that share an exact position are welded before the topology checks,
// so meshes exported with split vertices (OBJ/STL style) are accepted.
// A mesh whose triangles cross each other (say two overlapping cubes in one
// mesh) is rejected: "inside" would count both. Triangles that share a vertex
// and contacts that only touch are not tested (docs/numerics.md).
MeshReport check_mesh(const std::string& owner, const float* vertices, size_t n_vertices, const uint32_t* triangles,
                      size_t n_triangles);

}  // namespace ep
