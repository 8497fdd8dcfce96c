// The face planes of a small scene, to answer without Embree "does this ray
// enter any region?" where the answer is plainly no (issue 11). A packet
// leaving the tissue into the ambient asks exactly that (look_ahead: a
// closest-hit query from the ambient, whose filter keeps entering hits only),
// once per exit; in a convex scene (a slab, a box) the answer is always no, and
// Embree's query costs ~850 instructions (callgrind, the MCML slab: an eighth
// of the packet) even with twelve triangles.
//
// The proof is conservative. Embree's filter (Scene::intersect_first) keeps a
// hit on a triangle with outward normal n only when cos = dot(d, n) < 0. Every
// point x of that triangle has dot(n, x) >= c, c the smallest dot(n, v) over
// its vertices; the ray o + t d (t >= 0, o the backed-up origin) has
// dot(n, o + t d) <= dot(n, o). So when dot(n, o) < c - margin the ray stays a
// margin below every point of the triangle and cannot meet it; the margin
// (1e-5 of the coordinates) is far above Embree's float rounding (~1e-7).
// Grazing triangles (|cos| <= 1e-12, where the filter's sign could be in
// doubt; an unscattered packet parallel to a slab's sides) take the same test:
// the ray can meet a triangle only at t <= sqrt(3) (|o| + scale), over which
// it rises towards the plane by < 2e-12 (|o| + scale), far inside the margin. Any
// entering triangle in front makes the proof fail: then the caller asks
// Embree, so the answer is always the query's.
#pragma once
#include <cstring>
#include <vector>

#include "scene.h"
#include "triangle_cache.h"
#include "vecmath.h"

namespace ep {

class EntryPlanes {
  public:
    // Scenes with more triangles than this ask Embree (the test is linear in
    // planes; a layered slab of five layers has 60 triangles but six normals).
    static constexpr size_t kMaxTriangles = 64;

    // Collects the planes of every triangle of the (committed) scene; disabled
    // when it has more than kMaxTriangles.
    void build(const Scene& scene) {
        planes_.clear();
        enabled_ = false;
        size_t count = 0;
        for (size_t r = 0; r < scene.region_count(); ++r) count += scene.region(r).normals.size();
        TriangleCacheBuilder all;
        // A ball that holds every triangle (the gather only reads its triangles).
        if (count == 0 || count > kMaxTriangles || !scene.gather_triangles_bvh(Vec3(0, 0, 0), 1e30, kMaxTriangles, all))
            return;
        scale_ = 0;
        for (const TriangleCache::Triangle& cached : all.triangles()) {
            const Scene::EdgePlanes& t = scene.triangle(cached.id);
            const Vec3 v0 = t.p0, v1 = t.v1(), v2 = t.v2();
            scale_ = std::max({scale_, max_abs_component(v0), max_abs_component(v1), max_abs_component(v2)});
            const Float c = std::min({dot(t.n, v0), dot(t.n, v1), dot(t.n, v2)});
            // Triangles with bit-identical normals (coplanar or parallel) share
            // one test against the smallest offset, which holds for each of them.
            bool joined = false;
            for (Plane& p : planes_)
                if (std::memcmp(&p.n, &t.n, sizeof(Vec3)) == 0) {
                    p.c = std::min(p.c, c);
                    joined = true;
                    break;
                }
            if (!joined) planes_.push_back(Plane{t.n, c});
        }
        enabled_ = !planes_.empty();
    }

    // True when the ray from o - back d along unit d (Embree's backed-up ray
    // to infinity) provably enters no region; false when it might.
    bool none_ahead(const Vec3& o, const Vec3& d, Float back) const {
        if (!enabled_) return false;
        const Float margin = 1e-5 * (max_abs_component(o) + back + scale_);
        for (const Plane& p : planes_) {
            const Float cos = dot(d, p.n);
            if (cos > 1e-12) continue;  // leaving hits only: the filter rejects them
            // dot(n, o - back d) <= dot(n, o) + back
            if (!(dot(p.n, o) + back < p.c - margin)) return false;
        }
        return true;
    }

  private:
    struct Plane {
        Vec3 n;
        Float c;  // min dot(n, v) over the vertices of its triangles
    };
    bool enabled_ = false;
    Float scale_ = 0;  // largest vertex coordinate
    std::vector<Plane> planes_;
};

}  // namespace ep
