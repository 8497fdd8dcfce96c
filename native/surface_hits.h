// The surface a ray sees: the first point where a ray that starts in the
// ambient medium enters tissue (a region). Used by the camera (primary rays,
// one per pixel) and by the aperture camera's occlusion test. No physics.
#pragma once
#include <cstddef>
#include <cstdint>

#include "scene.h"

namespace ep {

// Region code for rays whose first crossing leaves a region: the ray started
// inside tissue, so "the surface it sees" is undefined.
constexpr int32_t kStartsInside = -2;
// Region code for rays that meet no surface in [tnear, tfar].
constexpr int32_t kNoSurface = -1;

struct SurfaceHit {
    Float t = kInf;               // ray parameter of the entry point, scene units (direction normalised)
    int32_t region = kNoSurface;  // region the ray enters there (the top-priority one if several coincide)
    int32_t prim = -1;            // triangle of that region's mesh
    Vec3 normal;                  // outward unit normal of that triangle
};

// First entry into tissue along o + t d, t in [tnear, tfar]. Crossings closer
// than a tolerance scaled to the coordinates are treated as one (touching or
// coincident faces); the region is then the top-priority region of the set
// entered. d need not be normalised; t is returned for the normalised ray.
SurfaceHit first_surface(const Scene& scene, const Vec3& o, const Vec3& d, Float tnear, Float tfar);

// Batch version over n rays (origins, directions as (n,3) double rows; tfar per
// ray, may be +inf), split over `threads` threads (0 = all cores). Outputs:
// t (n), region (n), prim (n), normal (n,3). Deterministic: each ray is
// independent of the split.
void first_surfaces(const Scene& scene, const double* origins, const double* directions, const double* tfar, size_t n,
                    Float tnear, int threads, double* t_out, int32_t* region_out, int32_t* prim_out,
                    double* normal_out);

}  // namespace ep
