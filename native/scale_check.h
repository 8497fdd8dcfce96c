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
// Smallest side of a region's bounding box, scene units. Embree's triangle
// tests multiply two float32 coordinates (the triangle's normal, ~ side^2) and
// take the reciprocal of its dot product with the ray: a 2-unit box scaled by
// 1.7e-20 (sides 3.4e-20) overflows it and every packet is silently missed, one
// scaled by 2e-20 still runs right. 1e-15 keeps side^2 >= 1e-30, eight orders of
// magnitude above float32's smallest normal number (1.2e-38), and is far below
// any physical size in the scene units offered (m, cm, mm). The thinness check
// below is relative (its tolerance scales with the scene), so it cannot catch a
// region that is small everywhere.
constexpr double kMinRegionSide = 1e-15;
// The crossing-grouping tolerance must stay below this fraction of the
// thinnest region (smallest side of a region's bounding box).
constexpr double kResolutionFraction = 0.25;
// Largest number of voxels along one axis of the scene's bounding box for a grid
// (voxel indices are int32).
constexpr double kMaxVoxelsPerAxis = 1 << 30;

// Throws std::invalid_argument naming the region, light or field and its value.
void check_scale(const Scene& scene, const Source& source, const RunConfig& cfg);

// Crossings closer than the grouping tolerance are one crossing, so a packet
// that reaches an edge or a corner of a region within that distance of its
// other face takes the two faces as one: far from the origin, where the
// tolerance grows with |coordinate|, light near edges is biased (a pencil
// beam one mean free path from a box's edge, n 1.5, albedo 0.9: absorbed
// +0.0004 / +0.0013 / +0.0040 / +0.022 with the tolerance at 0.024 / 0.064 /
// 0.20 / 2.0 mean free paths, i.e. 100 / 300 / 1000 / 10^4 cm from the
// origin; 3 x 100,000 packets, stderr 0.0005; docs/numerics.md). Flat
// faces away from edges are not affected.
constexpr double kEdgeResolutionMfp = 0.05;

// Adds a warning naming each scattering region whose crossing tolerance at
// its largest |coordinate| exceeds kEdgeResolutionMfp of its mean free path.
void edge_resolution_warnings(const Scene& scene, std::vector<std::string>& warnings);

// Event cap implied by the media: kPathologicalMaxEvents if a region is more
// than kPathologicalOpticalSize mean free paths across, else 0 (none). Adds a
// warning naming the region to `warnings` when it caps.
uint64_t pathological_event_cap(const Scene& scene, std::vector<std::string>& warnings);

}  // namespace ep
