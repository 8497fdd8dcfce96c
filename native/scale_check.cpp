#include "scale_check.h"

#include <algorithm>
#include <cmath>
#include <sstream>
#include <stdexcept>

namespace ep {

namespace {

double max_abs3(const double* v) { return std::max({std::fabs(v[0]), std::fabs(v[1]), std::fabs(v[2])}); }

// Upper bound of transport.cpp's group_tolerance for a ray from a point of
// magnitude `p_abs` travelling at most `t` (scene units).
double tolerance_bound(double p_abs, double t, double extent) { return 2e-6 * (p_abs + t) + 1e-7 * extent; }

std::string vec_str(const Vec3& v) {
    std::ostringstream os;
    os.precision(6);
    os << "(" << v.x << ", " << v.y << ", " << v.z << ")";
    return os.str();
}

}  // namespace

void check_scale(const Scene& scene, const Source& source, const RunConfig& cfg) {
    const size_t nreg = scene.region_count();
    if (nreg == 0) throw std::invalid_argument("scene.regions is empty: add at least one region");
    double lo[3], hi[3], thin = INFINITY;
    size_t thin_region = 0;
    for (int k = 0; k < 3; ++k) lo[k] = INFINITY, hi[k] = -INFINITY;
    // Cheapest checks first: magnitudes, then the per-region resolution.
    for (size_t i = 0; i < nreg; ++i) {
        const MeshReport& m = scene.region(i).report;
        const double mag = std::max(max_abs3(m.bbox_min), max_abs3(m.bbox_max));
        const std::string owner = "region '" + scene.region(i).name + "'";
        if (!(mag <= kMaxCoordinate)) {
            std::ostringstream os;
            os << owner << ": mesh.vertices reach |coordinate| = " << mag << ", beyond the limit " << kMaxCoordinate
               << " scene units of float32 ray tracing";
            throw std::invalid_argument(os.str());
        }
        double side = INFINITY;
        for (int k = 0; k < 3; ++k) {
            lo[k] = std::min(lo[k], m.bbox_min[k]);
            hi[k] = std::max(hi[k], m.bbox_max[k]);
            side = std::min(side, m.bbox_max[k] - m.bbox_min[k]);
        }
        if (!(side >= kMinRegionSide)) {
            std::ostringstream os;
            os << owner << ": thinnest side " << side << " scene units is below the limit " << kMinRegionSide
               << " scene units of float32 ray tracing (its triangle tests underflow near 1e-19): scale the mesh up "
                  "or give the scene in a smaller unit";
            throw std::invalid_argument(os.str());
        }
        // A packet crossing the region's thinnest side is at most `mag` from the
        // origin and travels about `side` between the two crossings.
        const double tol = tolerance_bound(mag, side, scene.extent());
        if (!(tol <= kResolutionFraction * side)) {
            std::ostringstream os;
            os << owner << ": thinnest side " << side << " scene units at |coordinate| up to " << mag
               << " is below what float32 ray tracing resolves there (crossing tolerance " << tol
               << "): move the region nearer the origin or make it thicker";
            throw std::invalid_argument(os.str());
        }
        if (side < thin) thin = side, thin_region = i;
    }
    const auto& lights = source.lights();
    for (size_t i = 0; i < lights.size(); ++i) {
        const Light& l = lights[i];
        const double reach =
            std::max({std::fabs(l.center.x), std::fabs(l.center.y), std::fabs(l.center.z)}) + double(l.radius);
        std::ostringstream pre;
        pre << "source.lights[" << i << "]: position = " << vec_str(l.center) << ", radius = " << l.radius;
        if (!(reach <= kMaxCoordinate)) {
            std::ostringstream os;
            os << pre.str() << " reaches |coordinate| = " << reach << ", beyond the limit " << kMaxCoordinate
               << " scene units of float32 ray tracing";
            throw std::invalid_argument(os.str());
        }
        // The first ray travels at least the distance to the scene's box before
        // its first crossing, where the tolerance is set.
        double near2 = 0;
        const double c[3] = {l.center.x, l.center.y, l.center.z};
        for (int k = 0; k < 3; ++k) {
            const double d = std::max({lo[k] - c[k], c[k] - hi[k], 0.0});
            near2 += d * d;
        }
        const double tol = tolerance_bound(reach, std::sqrt(near2) + l.radius, scene.extent());
        if (!(tol <= kResolutionFraction * thin)) {
            std::ostringstream os;
            os << pre.str() << " is too far from the scene: the float32 crossing tolerance there, " << tol
               << " scene units, is more than a quarter of the thinnest region '" << scene.region(thin_region).name
               << "' (" << thin << "); move the source nearer the scene";
            throw std::invalid_argument(os.str());
        }
    }
    if (cfg.grid_voxel_size > 0) {
        double span = 0;
        for (int k = 0; k < 3; ++k) span = std::max(span, std::max(std::fabs(lo[k]), std::fabs(hi[k])));
        if (!(span / cfg.grid_voxel_size <= kMaxVoxelsPerAxis)) {
            std::ostringstream os;
            os << "grids.voxel_size = " << cfg.grid_voxel_size << " gives " << span / cfg.grid_voxel_size
               << " voxels from the origin to the scene's edge, beyond the int32 index limit " << kMaxVoxelsPerAxis;
            throw std::invalid_argument(os.str());
        }
    }
}

void edge_resolution_warnings(const Scene& scene, std::vector<std::string>& warnings) {
    for (size_t i = 0; i < scene.region_count(); ++i) {
        const Region& r = scene.region(i);
        const double mut = double(r.medium.mua) + double(r.medium.mus);
        if (!(double(r.medium.mus) > 0)) continue;               // no scattering: no walk that wanders to an edge
        const double mfp = 1 / (mut * double(scene.unit_cm()));  // scene units
        const double mag = std::max(max_abs3(r.report.bbox_min), max_abs3(r.report.bbox_max));
        const double tol = tolerance_bound(mag, mfp, scene.extent());
        if (tol <= kEdgeResolutionMfp * mfp) continue;
        std::ostringstream os;
        os.precision(3);
        os << "region '" << r.name << "': at |coordinate| up to " << mag
           << " scene units, surface crossings closer than " << tol
           << " scene units are one crossing (float32 ray tracing), " << tol / mfp << " of its mean free path (" << mfp
           << " scene units): light that reaches its edges and corners is "
           << "resolved only to that and may be biased there (docs/numerics.md, 'Edges far from the origin'); "
           << "move the scene nearer the origin";
        warnings.push_back(os.str());
    }
}

uint64_t pathological_event_cap(const Scene& scene, std::vector<std::string>& warnings) {
    for (size_t i = 0; i < scene.region_count(); ++i) {
        const Region& r = scene.region(i);
        double largest = 0;
        for (int k = 0; k < 3; ++k) largest = std::max(largest, r.report.bbox_max[k] - r.report.bbox_min[k]);
        const double mfps = double(r.medium.mus) * largest * double(scene.unit_cm());
        if (mfps > kPathologicalOpticalSize) {
            std::ostringstream os;
            os << "region '" << r.name << "': medium.mus = " << r.medium.mus << " cm^-1 makes it " << mfps
               << " mean free paths across, more than transport can follow (" << kPathologicalOpticalSize
               << "): packets are capped at " << kPathologicalMaxEvents
               << " events and the weight they still carry is tallied as cut";
            warnings.push_back(os.str());
            return kPathologicalMaxEvents;
        }
    }
    return 0;
}

}  // namespace ep
