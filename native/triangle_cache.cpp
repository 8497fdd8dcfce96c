#include "triangle_cache.h"

#include <algorithm>
#include <cmath>
#include <memory>
#include <new>

#include "scene.h"

namespace ep {

TriangleCacheBuilder& TriangleCacheBuilder::operator=(const TriangleCacheBuilder& o) {
    if (this == &o) return *this;
    center_ = o.center_;
    radius_ = o.radius_;
    eps_ = o.eps_;
    tris_ = o.tris_;
    planes_ = o.planes_;
    sync();
    return *this;
}

namespace {

// Byte offsets of a frozen copy's planes and triangles in its block.
size_t planes_offset() {
    static_assert(alignof(TriangleCache::Plane) <= alignof(TriangleCache), "plane alignment");
    static_assert(sizeof(TriangleCache) == TriangleCache::kFrozenAlign, "a frozen cache's members are one line");
    return sizeof(TriangleCache);
}
size_t triangles_offset(size_t n_planes) {
    static_assert(alignof(TriangleCache::Triangle) <= alignof(TriangleCache::Plane), "triangle alignment");
    static_assert(sizeof(TriangleCache::Plane) % alignof(TriangleCache::Triangle) == 0, "triangle alignment");
    return planes_offset() + n_planes * sizeof(TriangleCache::Plane);
}

}  // namespace

static_assert(sizeof(TriangleCache::Triangle) == 16, "a cached triangle: four 32-bit numbers");

size_t TriangleCache::frozen_size(const TriangleCache& src) {
    return triangles_offset(src.n_planes_) + src.n_tris_ * sizeof(Triangle);
}

TriangleCache* TriangleCache::freeze(const TriangleCache& src, void* bytes) {
    auto* c = new (bytes) TriangleCache();
    c->center_ = src.center_;
    c->radius_ = src.radius_;
    c->eps_ = src.eps_;
    auto* base = static_cast<char*>(bytes);
    auto* planes = reinterpret_cast<Plane*>(base + planes_offset());
    auto* tris = reinterpret_cast<Triangle*>(base + triangles_offset(src.n_planes_));
    std::uninitialized_copy(src.planes_view_, src.planes_view_ + src.n_planes_, planes);
    std::uninitialized_copy(src.tris_view_, src.tris_view_ + src.n_tris_, tris);
    c->planes_view_ = planes;
    c->n_planes_ = src.n_planes_;
    c->tris_view_ = tris;
    c->n_tris_ = src.n_tris_;
    return c;
}

void TriangleCacheBuilder::reset(const Vec3& center, Float radius) {
    tris_.clear();
    planes_.clear();
    sync();
    center_ = center;
    radius_ = radius;
    // Rounding allowance of the plane distances in intersect(): a few ulps of
    // the magnitudes involved, bounded over the ball (|x| <= |c| + r there).
    eps_ = 1e-13 * (2 * (max_abs_component(center) + radius) + radius);
    if (++stamp_ == 0) {  // the stamps wrapped: forget every old one
        std::fill(seen_.begin(), seen_.end(), 0u);
        stamp_ = 1;
    }
}

void TriangleCacheBuilder::add(uint32_t id, const Vec3& v0, const Vec3& v1, const Vec3& v2, const Vec3& n,
                               uint32_t region, uint32_t prim) {
    // Join the plane of an earlier triangle when this one lies in it (the two
    // triangles of a quad, a flat face): vertices within a relative 1e-9 of
    // the plane. The margin records how far they really are, so the plane
    // test stays conservative for every member. (The tolerance is worked out
    // only for a plane of the same normal: most triangles of a cube's cache
    // have none; callgrind, colon_polyp.)
    std::vector<Plane>& planes = planes_;
    uint32_t plane = uint32_t(planes.size());
    for (uint32_t k = 0; k < planes.size(); ++k) {
        Plane& p = planes[k];
        if (dot(p.n, n) < 1 - 1e-12) continue;
        const Float scale = max_abs_component(v0) + max_abs_component(v1) + max_abs_component(v2);
        const Float tol = 1e-9 * (scale + radius_);
        const Float e = std::max(
            {std::fabs(dot(p.n, v0) - p.off), std::fabs(dot(p.n, v1) - p.off), std::fabs(dot(p.n, v2) - p.off)});
        if (e <= tol) {
            p.margin = std::max(p.margin, e);
            p.reach = p.margin + eps_;
            plane = k;
            break;
        }
    }
    if (plane == planes.size()) {
        const Float off = dot(n, v0);
        const Float e = std::max(std::fabs(dot(n, v1) - off), std::fabs(dot(n, v2) - off));
        planes.push_back(Plane{n, off, e, e + eps_});
    }
    tris_.push_back(Triangle{id, region, prim, plane});
    sync();
}

void TriangleCache::intersect_open(const Scene& scene, const Vec3& org, const Vec3& d, Float back, Float t_end,
                                   uint64_t open, std::vector<Hit>& out) const {
    out.clear();
    for (const Triangle& tri : triangles()) {
        if (!((open >> std::min<uint32_t>(tri.plane, 63)) & 1)) continue;
        // Watertight test in double (signed volumes of the ray and each edge):
        // an edge shared by two triangles gives exactly opposite values in
        // both (cross(b, c) = -cross(c, b) bit for bit), so a ray through the
        // edge is inside at least one of them, never neither.
        const Scene::EdgePlanes& e = scene.triangle(tri.id);
        const Vec3 a = e.p0 - org, b = e.v1() - org, c = e.v2() - org;
        const Float e0 = dot(d, cross(b, c)), e1 = dot(d, cross(c, a)), e2 = dot(d, cross(a, b));
        const bool inside = (e0 >= 0 && e1 >= 0 && e2 >= 0) || (e0 <= 0 && e1 <= 0 && e2 <= 0);
        if (!inside || (e0 == 0 && e1 == 0 && e2 == 0)) continue;
        const Float cos_dn = dot(d, e.n);
        if (cos_dn == 0) continue;
        // Distance along the ray to the triangle's plane, as collect_filter refines it.
        const Float t = dot(a, e.n) / cos_dn;
        if (!(t >= 0 && t <= t_end)) continue;
        out.push_back(Hit{t - back, tri.region, tri.prim, cos_dn});
    }
    if (out.size() > 1) std::sort(out.begin(), out.end(), [](const Hit& a, const Hit& b) { return hit_before(a, b); });
}

}  // namespace ep
