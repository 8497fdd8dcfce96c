// A local copy of the triangles that meet a ball around a packet (issue 11).
// In tissue a packet lives within a few mean free paths of a surface, where a
// closest-point "safe ball" rarely covers a step; but a segment that stays
// inside a ball can only cross the triangles that meet that ball. Those are
// few (one or two for a flat wall, a handful on a curved wall), so a step
// tests them directly -- first against their plane, which rejects almost every
// step with two dot products -- instead of a full Embree all-hits traversal.
// The answer is the same list of crossings Scene::intersect_all gives: the
// triangle test is watertight (shared edges use bit-identical edge functions)
// and the distance is the same double-precision plane refinement.
#pragma once
#include <cstdint>
#include <vector>

#include "scene.h"
#include "vecmath.h"

namespace ep {

// A read-only view of n elements (the cache's triangles and planes, which
// live in its own vectors or, frozen, in one block of the scene's store).
template <class T>
struct ConstSpan {
    const T* first = nullptr;
    size_t n = 0;
    const T* begin() const { return first; }
    const T* end() const { return first + n; }
    size_t size() const { return n; }
    bool empty() const { return n == 0; }
    const T& operator[](size_t i) const { return first[i]; }
};

class TriangleCache {
  public:
    // A cached triangle names the scene-wide triangle `id`, whose vertices
    // (float mesh data, exactly as Embree sees them) and outward unit normal
    // (Region::normals) the scene holds once (Scene::triangle): 16 bytes a
    // triangle in each cube that meets it, instead of 112 for a copy of its
    // vertices and normal (the colon's store held about one triangle a built
    // cube; issue 39, docs/performance.md §23).
    struct Triangle {
        uint32_t id;  // the scene-wide triangle (Scene::triangle)
        // Derivable from id, but kept: every hit needs them, and the id's
        // region is a search (TriangleGrid::region_of).
        uint32_t region, prim;
        uint32_t plane;  // index into planes()
    };
    // Coplanar triangles share one plane test: n.x = off within +-margin holds
    // every vertex of every member triangle.
    struct Plane {
        Vec3 n;
        Float off, margin;
        Float reach;  // margin + the rounding allowance of the plane test
    };

    // Empty and covering nothing (the scene's answer where no cache is).
    TriangleCache() = default;
    ~TriangleCache() = default;

    // True when the segment from a to b lies inside the ball (a ball is convex:
    // both ends inside suffices).
    __attribute__((always_inline)) bool covers(const Vec3& a, const Vec3& b) const {
        const Vec3 da = a - center_, db = b - center_;
        const Float r2 = radius_ * radius_;
        return (dot(da, da) < r2) & (dot(db, db) < r2);  // & of bools: no branch on the first
    }
    // Scene::intersect_all restricted to the cached triangles: valid only for
    // a segment that covers() accepts ([o + tnear d, o + tfar d], tnear <= 0).
    // Inline (always: with more callers GCC kept it out of line): the plane
    // test, which answers almost every step by itself.
    // `scene` is the one whose triangles the cache was gathered from.
    __attribute__((always_inline)) void intersect(const Scene& scene, const Vec3& o, const Vec3& d, Float tnear,
                                                  Float tfar, std::vector<Hit>& out) const {
        // The same ray as Scene::intersect_all: a negative tnear backs the
        // origin up, and distances are measured from there and shifted back at
        // the end, so the refined distances are bit-identical to the full query's.
        const Float back = tnear < 0 ? -tnear : Float(0);
        const Vec3 org = back > 0 ? o - d * back : o;
        const Float t_end = tfar + back;
        const Vec3 end = org + d * t_end;
        // A segment whose two ends lie strictly on one side of a plane's slab
        // crosses none of its triangles. The comparisons are joined by & and |
        // on bools and the bit is set by a shift of the verdict: the same
        // verdicts without a branch on each, which mispredicted often
        // (callgrind branch simulation, colon_polyp: 349k -> ~220k mispredicts
        // per 10,000 packets here; interleaved A/B +7% and +18% packets/s).
        uint64_t open = 0;  // planes the segment may cross (bit k; planes beyond 63 share bit 63)
        for (size_t k = 0; k < n_planes_; ++k) {
            const Plane& p = planes_view_[k];
            const Float da = dot(p.n, org) - p.off, db = dot(p.n, end) - p.off;
            const bool apart = ((da > p.reach) & (db > p.reach)) | ((da < -p.reach) & (db < -p.reach));
            open |= uint64_t(!apart | (k >= 63)) << std::min<size_t>(k, 63);
        }
        if (open)
            intersect_open(scene, org, d, back, t_end, open, out);
        else
            out.clear();
    }

    const Vec3& center() const { return center_; }
    Float radius() const { return radius_; }
    size_t size() const { return n_tris_; }
    ConstSpan<Triangle> triangles() const { return {tris_view_, n_tris_}; }
    size_t plane_count() const { return n_planes_; }
    ConstSpan<Plane> planes() const { return {planes_view_, n_planes_}; }
    // A frozen copy for the scene's per-cube store (Scene::cell_cache): the
    // object, its planes and its triangles in one block of frozen_size(src)
    // bytes at `bytes` (aligned for TriangleCache), so a cube costs one bump
    // of the store's arena instead of three allocations. The block is the
    // caller's (the object is trivially destructible). It starts a cache
    // line (kFrozenAlign), which the object fills exactly: a hop to the cube
    // reads that line and those of its planes. (The builder's vectors live in
    // TriangleCacheBuilder, not here: with their pointer the object took 72
    // bytes, so an empty cube -- 61% of the cubes the colon builds -- took two
    // lines of the store instead of one; issue 39, docs/performance.md §23.)
    static constexpr size_t kFrozenAlign = 64;
    static size_t frozen_size(const TriangleCache& src);
    static TriangleCache* freeze(const TriangleCache& src, void* bytes);
    // The rounding allowance of intersect()'s plane distances over the ball
    // (reset()): a second one of these on top of a plane's reach covers the
    // few-ulp differences of a test computed by other expressions
    // (transport.cpp's interior steps).
    Float rounding() const { return eps_; }

  protected:
    // A view copies the views, not the content: only the builder and
    // freeze() copy (a copied builder would point into the other's vectors).
    TriangleCache(const TriangleCache&) = default;
    TriangleCache& operator=(const TriangleCache&) = default;

    // The members a hop reads (one line of a frozen copy).
    Vec3 center_;
    Float radius_ = 0, eps_ = 0;
    // What every reader uses: a builder's vectors, or a frozen copy's block.
    const Triangle* tris_view_ = nullptr;
    const Plane* planes_view_ = nullptr;
    uint32_t n_tris_ = 0, n_planes_ = 0;

  private:
    // The triangle tests of the planes in `open` (bit k = plane k).
    void intersect_open(const Scene& scene, const Vec3& org, const Vec3& d, Float back, Float t_end, uint64_t open,
                        std::vector<Hit>& out) const;
};

// A TriangleCache that is gathered into (Scene::gather_triangles): its
// triangles and planes in its own vectors, which keep their capacity from
// gather to gather, and the gathers' mailbox. Scene::cell_cache freezes a
// gathered one into the store.
class TriangleCacheBuilder : public TriangleCache {
  public:
    TriangleCacheBuilder() = default;
    // A copy holds the content in its own vectors (not the mailbox).
    TriangleCacheBuilder(const TriangleCacheBuilder& o) : TriangleCache() { *this = o; }
    TriangleCacheBuilder& operator=(const TriangleCacheBuilder& o);

    // Empty and covering nothing.
    void clear() {
        tris_.clear();
        planes_.clear();
        radius_ = 0;
        sync();
    }
    // Starts a gather around `center`: every triangle meeting the ball of
    // `radius` must then be added (Scene::gather_triangles does this).
    void reset(const Vec3& center, Float radius);
    // Adds the scene-wide triangle `id` (vertices v0..v2, normal n).
    void add(uint32_t id, const Vec3& v0, const Vec3& v1, const Vec3& v2, const Vec3& n, uint32_t region,
             uint32_t prim);
    // Mailbox of a gather through the triangle grid, where a triangle spanning
    // several cells is offered once per cell, for scene-wide triangle ids below
    // n_ids: first_offer(id) is true the first time `id` is offered since
    // reset() (valid until the next reset()).
    struct Mailbox {
        uint32_t* seen;
        uint32_t stamp;
        bool first_offer(uint32_t id) {
            if (seen[id] == stamp) return false;
            seen[id] = stamp;
            return true;
        }
    };
    Mailbox mailbox(size_t n_ids) {
        if (seen_.size() < n_ids) seen_.resize(n_ids, 0);
        return Mailbox{seen_.data(), stamp_};
    }

  private:
    // Points the views at the vectors (after every change).
    void sync() {
        tris_view_ = tris_.data();
        n_tris_ = uint32_t(tris_.size());
        planes_view_ = planes_.data();
        n_planes_ = uint32_t(planes_.size());
    }
    std::vector<Triangle> tris_;
    std::vector<Plane> planes_;
    std::vector<uint32_t> seen_;  // the mailbox's stamps, one per scene triangle
    uint32_t stamp_ = 0;
};

// Conservative forms of TriangleCache::covers() and of intersect()'s plane
// test for a chain of steps in which each step starts where the last one
// ended (transport.cpp's interior steps), intersect()'s look-behind being at
// most `max_back`. A point is clear when it lies inside the ball shrunk by
// the look-behind and beyond every plane's reach widened by the look-behind
// and a second rounding allowance, on the chain's side: then the step to it
// passes both tests, and so does the look-behind of the next step, which
// needs no test of its start. Clear points are found without a test per
// step: a clear point carries a budget, its distance to the nearest of those
// limits, and the steps after it spend the budget (|b - p| <= s for a unit
// direction), so a step is tested only when the budget runs out. Every
// allowance exceeds the rounding it covers ~50-fold: clear() is true only
// where covers() and the plane test would both pass.
class ClearSteps {
  public:
    // As many as a cube's cache holds triangles (Scene::kCellMaxTriangles), so
    // the interior steps run in every cube that has a cache: on colon_polyp
    // a limit of 8 turned ~8 loop entries a packet away, near the polyp's
    // fine tessellation (callgrind).
    static constexpr size_t kMaxPlanes = 16;
    // Takes the cache's ball and planes; false when p itself is not clear (or
    // the cache has more than kMaxPlanes planes): no step can start there.
    bool start(const TriangleCache& cache, const Vec3& p, Float max_back) {
        const auto& planes = cache.planes();
        c_ = cache.center();
        const Float scale = max_abs_component(c_) + cache.radius();
        scale_ = scale;
        // Per step: the rounding of b = p + d s (a few ulps of |b| and of
        // s <= 2 r) and of the distances a budget is made of.
        slack_ = 1e-13 * scale;
        inner_ = cache.radius() - max_back - 1e-14 * scale;
        inner_r2_ = inner_ > 0 ? inner_ * inner_ * (1 - 1e-12) : 0;
        if (planes.size() > kMaxPlanes) return false;
        // renew(p) with the planes' orientation found in the same pass: the
        // ball first, then each plane's margin as soon as it is oriented (a
        // start that fails stops at the first plane too near p).
        const Vec3 dp = p - c_;
        const Float q2 = dot(dp, dp);
        if (!(q2 < inner_r2_)) return false;
        Float budget = inner_ - std::sqrt(q2);
        n_planes_ = planes.size();
        const Float rounding = cache.rounding();
        for (size_t k = 0; k < n_planes_; ++k) {
            const TriangleCache::Plane& q = planes[k];
            // Oriented so that p's side is positive (negation is exact, so
            // the distances are exactly +-intersect()'s).
            const Float da = dot(q.n, p) - q.off;
            const Float side = da > 0 ? 1 : -1;
            n_[k][0] = q.n.x * side;
            n_[k][1] = q.n.y * side;
            n_[k][2] = q.n.z * side;
            off_[k] = q.off * side;
            lo_[k] = q.reach + rounding + max_back;
            const Float margin = da * side - lo_[k];  // renew()'s margin at p, bit for bit
            if (!(margin > 0)) return false;
            budget = std::min(budget, margin);
        }
        budget_ = budget - slack_;
        return true;
    }
    // The step from the last clear point to b, s long: true only when b is
    // clear (the step is in the ball and crosses no cached plane). b in lanes
    // (vecmath.h's Lanes4), as the interior steps hold it: its components are
    // taken out only when the budget runs out, so the steps the budget clears
    // (87 % on seed tissue) do not unpack it (callgrind, seed tissue: 206.4 ->
    // 204.1 instructions per interaction, the same bits).
    bool clear(const Vec3& b, Float s) { return clear(to_lanes(b), s); }
    bool clear(const Lanes4& b, Float s) {
        const Float left = budget_ - (s + slack_);
        if (left > 0) {
            budget_ = left;
            return true;
        }
        return renew(to_vec3(b));
    }

    // True when x lies outside the ball start() took (less the look-behind):
    // a step to x needs another cube's cache, where a step that fails clear()
    // inside it comes near a plane.
    bool beyond_ball(const Vec3& x) const {
        const Vec3 dx = x - c_;
        return !(dot(dx, dx) < inner_r2_);
    }

    // The zone as the float32 lanes take it (lane_block.h): its centre, the
    // scale of its coordinates, the inner radius, and plane k, clear where
    // plane_normal(k) . x - plane_offset(k) > 0.
    const Vec3& center() const { return c_; }
    Float scale() const { return scale_; }
    Float inner() const { return inner_; }
    size_t plane_count() const { return n_planes_; }
    Vec3 plane_normal(size_t k) const { return Vec3(n_[k][0], n_[k][1], n_[k][2]); }
    Float plane_offset(size_t k) const { return off_[k] + lo_[k]; }

  private:
    // Tests x and gives it its budget; false when x is not clear.
    bool renew(const Vec3& x) {
        const Vec3 dx = x - c_;
        const Float q = dot(dx, dx);
        if (!(q < inner_r2_)) return false;
        Float budget = inner_ - std::sqrt(q);
        for (size_t k = 0; k < n_planes_; ++k) {
            const Float margin = n_[k][0] * x.x + n_[k][1] * x.y + n_[k][2] * x.z - off_[k] - lo_[k];
            if (!(margin > 0)) return false;
            budget = std::min(budget, margin);
        }
        budget_ = budget - slack_;
        return true;
    }

    Vec3 c_;
    Float scale_ = 0, inner_ = 0, inner_r2_ = 0, slack_ = 0, budget_ = 0;
    size_t n_planes_ = 0;
    // Plain arrays, not Vec3 (whose members start at 0): a zone is made at
    // every loop entry, and only the first n_planes_ entries are ever set.
    Float n_[kMaxPlanes][3];
    Float off_[kMaxPlanes], lo_[kMaxPlanes];
};

}  // namespace ep
