// What float32 ray tracing can represent, relative to the scene's scale.
//
// Embree stores vertices and rays in float32 and (in Debian's build) asserts
// |ray origin| < 1.8e18; the transport groups surface crossings closer than
// 2e-6 (|p| + t) + 1e-7 extent (transport.cpp, group_tolerance). A source far
// from a thin region, or a thin region far from the origin, would therefore
// crash the tracer or merge the region's two faces into one crossing and give
// a silently wrong answer. check_scale() rejects such inputs, by name, before
// any ray is cast. docs/numerics.md lists the limits.
#pragma once
#include <string>
#include <vector>

#include "run_config.h"
#include "scene.h"
#include "source.h"

namespace ep {

// Largest |coordinate| of a vertex or of a light's emission disk, scene units.
constexpr double kMaxCoordinate = 1e12;
// The crossing-grouping tolerance must stay below this fraction of the
// thinnest region (smallest side of a region's bounding box).
constexpr double kResolutionFraction = 0.25;
// Largest number of voxels along one axis of the scene's bounding box for a grid
// (voxel indices are int32).
constexpr double kMaxVoxelsPerAxis = 1 << 30;

// Throws std::invalid_argument naming the region, light or field and its value.
void check_scale(const Scene& scene, const Source& source, const RunConfig& cfg);

// Event cap implied by the media: kPathologicalMaxEvents if a region is more
// than kPathologicalOpticalSize mean free paths across, else 0 (none). Adds a
// warning naming the region to `warnings` when it caps.
uint64_t pathological_event_cap(const Scene& scene, std::vector<std::string>& warnings);

}  // namespace ep
