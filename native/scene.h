// The scene: regions bounded by closed triangle meshes in one Embree 3 scene,
// each with a medium, a priority and its fluorophores, inside an ambient
// medium that neither scatters nor absorbs.
#pragma once
#include <embree3/rtcore.h>

#include <atomic>
#include <cstddef>
#include <cstdlib>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include "cell_cache_store.h"
#include "medium.h"
#include "mesh_check.h"
#include "triangle_grid.h"
#include "vecmath.h"

namespace ep {

class EEM;
class TriangleCache;
class TriangleCacheBuilder;

// A fluorophore of a region: the seed's d (probability of interaction) and
// c (concentration), and the scene-wide id of its EEM.
struct FluorophoreRef {
    int id = -1;
    Float d = 0, c = 0;
};

struct Region {
    std::string name;
    Medium medium;
    int priority = 0;
    std::vector<FluorophoreRef> fluorophores;
    unsigned geom_id = 0;
    std::vector<Vec3> normals;  // outward unit normal per triangle
    MeshReport report;
};

// One surface crossing found along a ray.
struct Hit {
    Float t;          // ray parameter, scene units
    uint32_t region;  // region index
    uint32_t prim;    // triangle index within the region
    Float cos_dn;     // dot(ray direction, outward normal): < 0 entering, > 0 leaving
};

// The order of a hit list: by distance, ties (the two triangles of an edge,
// coincident faces) by region and triangle, so that every query that finds
// the same hits (Embree's, the triangle cache's, in any traversal order)
// lists them alike and the transport picks the same face normal.
inline bool hit_before(const Hit& a, const Hit& b) {
    if (a.t != b.t) return a.t < b.t;
    return a.region != b.region ? a.region < b.region : a.prim < b.prim;
}

class Scene {
  public:
    static constexpr int kMaxRegions = 64;  // region sets are 64-bit masks

    Scene(Float unit_cm, Float ambient_n);
    ~Scene();
    Scene(const Scene&) = delete;
    Scene& operator=(const Scene&) = delete;

    // Validates the mesh and the medium (std::invalid_argument naming the region)
    // and adds it. Vertices are float32 (N,3) in scene units, triangles uint32 (M,3).
    int add_region(const std::string& name, const float* vertices, size_t n_vertices, const uint32_t* triangles,
                   size_t n_triangles, const Medium& medium, int priority);
    int add_fluorophore(const std::string& name, std::shared_ptr<const EEM> eem);
    void set_region_fluorophores(int region, const std::vector<FluorophoreRef>& refs);
    void commit();

    Float unit_cm() const { return unit_cm_; }
    Float ambient_n() const { return ambient_n_; }
    Float extent() const { return extent_; }  // largest bounding-box side, scene units
    size_t region_count() const { return regions_.size(); }
    const Region& region(size_t i) const { return regions_[i]; }
    size_t fluorophore_count() const { return eems_.size(); }
    const EEM& eem(int id) const { return *eems_[size_t(id)]; }
    const std::string& fluorophore_name(int id) const { return fluor_names_[size_t(id)]; }
    bool has_fluorophores() const;
    bool has_spectral_media() const;

    // Highest-priority region of a set (ties: the region added later wins); -1 if empty.
    int top(uint64_t set) const {
        int best = -1;
        while (set) {
            const int i = __builtin_ctzll(set);
            set &= set - 1;
            if (best < 0 || rank_[size_t(i)] > rank_[size_t(best)]) best = i;
        }
        return best;
    }

    // Every surface crossing with t in [tnear, tfar], sorted by t; tnear may be
    // negative to include crossings just behind the origin. Embree's
    // filter callback records each candidate and rejects it, so traversal
    // continues to tfar; coincident faces (touching regions) all show up.
    void intersect_all(const Vec3& origin, const Vec3& dir, Float tnear, Float tfar, std::vector<Hit>& out) const;

    // The first crossing in [tnear, tfar] that changes the region set `set`
    // (enters a region not in it or leaves one in it): Embree's closest-hit
    // query, which stops there instead of collecting every crossing to tfar.
    // `hit` is the one intersect_all lists for that triangle (same refined
    // distance). `clearance` bounds from below how far the crossing point is
    // from the triangle's edges and from every other region's surface: when it
    // exceeds the transport's grouping tolerance, the all-hits list holds no
    // other crossing that groups with this one, so the one hit decides alone.
    struct FirstHit {
        bool found = false;
        Float clearance = 0;
    };
    FirstHit intersect_first(const Vec3& origin, const Vec3& dir, Float tnear, Float tfar, uint64_t set,
                             Hit& hit) const;
    // Whether [tnear, tfar] holds a crossing that changes `set`, by Embree's
    // any-hit (occlusion) query: it ends at the first such crossing its
    // traversal meets, which need not be the nearest, and is cheaper than the
    // closest-hit query for a question of yes or no. found = false: there is
    // none (intersect_first finds none either). Else `hit` and `clearance`
    // are intersect_first's for that crossing.
    FirstHit intersect_any(const Vec3& origin, const Vec3& dir, Float tnear, Float tfar, uint64_t set, Hit& hit) const;

    // Distance from p to the nearest triangle of any region (scene units),
    // searched within `radius`; returns `radius` if nothing is closer.
    Float distance_to_surface(const Vec3& p, Float radius) const;

    // Fills `cache` with every triangle that meets the ball (c, radius), for
    // steps that stay inside it (triangle_cache.h). False, and an empty cache
    // that covers nothing, when more than max_count triangles meet the ball.
    // Through the uniform grid (triangle_grid.h): O(local) per gather.
    bool gather_triangles(const Vec3& c, Float radius, size_t max_count, TriangleCacheBuilder& cache) const;
    // The same gather through Embree's BVH (rtcPointQuery): the reference the
    // grid is tested against, and the cost it is measured against.
    bool gather_triangles_bvh(const Vec3& c, Float radius, size_t max_count, TriangleCacheBuilder& cache) const;
    const TriangleGrid& grid() const { return grid_; }
    // The local triangle cache of the cube around p (issue 11): every grid
    // cell is split into kCellSplit^3 cubes, and each cube's cache holds the
    // triangles that meet the ball about its centre of radius one cube side
    // (the cube's half-diagonal is 0.87 side, so a short step from anywhere
    // in the cube stays inside the ball); an empty cube's ball is the widest
    // of kEmptyWiden that no triangle meets. Built on first use and shared by
    // every thread: the content is a function of the cube alone, so which
    // thread builds it never matters. A cache that covers nothing when p is
    // outside the grid or more than kCellMaxTriangles meet the ball (the
    // caller then asks Embree).
    const TriangleCache& cell_cache(const Vec3& p) const;
    // cell_cache's cache also past the store's budget: a cube the full store
    // does not keep is gathered into `scratch` the way cell_cache builds it
    // (the same planes and triangles: a function of the cube alone). For
    // callers whose answers read a cache's content, not only its crossings
    // (the camera tally's depth bound and look-back): which cubes the store
    // kept depends on the threads' timing once it is full, their content
    // never does, so these answers stay the same on any thread count.
    const TriangleCache& cube_cache(const Vec3& p, TriangleCacheBuilder& scratch) const;
    // The cube store's size and budget in bytes (cell slot blocks and cache
    // blocks together). Once the store holds the budget, a cube not built
    // yet gets no cache: its steps take the full query, which gives the same
    // answers more slowly. So a long run in a finely meshed scene, whose
    // light reaches millions of cubes, keeps its memory bounded; the cubes
    // built by then, where the light came first, keep their caches.
    // (The store: cell_cache_store.h.)
    static constexpr size_t kDefaultStoreCapBytes = CellCacheStore::kDefaultCapBytes;
    size_t cache_store_bytes() const { return cells_.bytes(); }
    size_t cache_store_cap_bytes() const { return cells_.cap_bytes(); }
    // For the scene's next builds (also mid-run: a thread reads it per build).
    void set_cache_store_cap_bytes(size_t bytes) { cells_.set_cap_bytes(bytes); }
    // The cache of the cube around p if it is built, else null (also outside
    // the grid): cell_cache's lookup alone, inline and without a call, for
    // the interior steps' loop (transport.cpp), which hops to a built cube
    // without leaving its registers.
    const TriangleCache* built_cell_cache(const Vec3& p) const {
        size_t cell;
        int cube;
        Vec3 centre;
        if (!grid_.cube_of<kCellSplit>(p, &cell, &cube, &centre)) return nullptr;
        return cells_.built(cell, cube);
    }
    // Per scene-wide triangle, for the gathers' ball test (GatherData::offer):
    // its outward normal (Region::normals, copied) and the three planes
    // through its edges perpendicular to it, each facing away from the
    // triangle (unit `side`, offset `off`; off = +inf when the triangle is too
    // thin to trust them). The triangle lies behind all three, so a point
    // s beyond one of them is at least s from the triangle. With its
    // vertices, in three cache lines in the order the test reads them: the
    // plane's line (n, vertex 0) decides most offers alone, and the edge
    // planes and the other vertices follow. (Apart, the edge planes and the
    // vertices cost ~4 lines an offer; callgrind, colon: ~5 last-level misses
    // a gather.) Vertices 1 and 2 are float mesh data, exact as float.
    struct alignas(64) EdgePlanes {
        Vec3 n;
        Vec3 p0;      // vertex 0
        Float scale;  // the largest vertex coordinate's magnitude (rounding room)
        Float off[3];
        Vec3 side[3];
        float p1[3], p2[3];  // vertices 1 and 2
        Vec3 v1() const { return Vec3(p1[0], p1[1], p1[2]); }
        Vec3 v2() const { return Vec3(p2[0], p2[1], p2[2]); }
    };
    // Scene-wide triangle `id` (region_base + primitive): its normal,
    // vertices and edge planes (TriangleCache's triangles name it).
    const EdgePlanes& triangle(size_t id) const { return edge_planes_[id]; }
    static constexpr int kCellSplit = CellCacheStore::kCellSplit;
    // The radii (in cube sides, widest first) an empty cube's ball tries
    // (cell_cache): the widest that no triangle meets is its ball.
    static constexpr Float kEmptyWiden[] = {2};
    static constexpr size_t kCellMaxTriangles = 16;

  private:
    Float unit_cm_, ambient_n_;
    Float extent_ = 0;
    RTCDevice device_ = nullptr;
    RTCScene scene_ = nullptr;
    bool committed_ = false;
    std::vector<Region> regions_;
    std::vector<int> rank_;
    std::vector<std::vector<float>> vertices_;
    std::vector<std::vector<uint32_t>> triangles_;
    std::vector<std::shared_ptr<const EEM>> eems_;
    std::vector<std::string> fluor_names_;
    Float bbox_min_[3] = {0, 0, 0}, bbox_max_[3] = {0, 0, 0};
    TriangleGrid grid_;
    std::vector<uint32_t> region_base_;        // scene-wide index of each region's first triangle
    CellCacheStore cells_;                     // cell_cache's caches
    std::unique_ptr<TriangleCache> no_cache_;  // covers nothing
    // Widens the ball of the empty cache `scratch` (centre c, radius side).
    void widen_empty(const Vec3& c, Float side, TriangleCacheBuilder& scratch) const;
    std::vector<Vec3> corners_;  // vertices 3T..3T+2 of scene-wide triangle T in double
    std::vector<EdgePlanes> edge_planes_;
    void compute_edge_planes();
    std::vector<float> isolation_;  // per triangle: lower bound of its distance to other regions
    void compute_isolation();
    // A lower bound of the distance from q (on a triangle of `region`) to
    // every other region's triangle, at least iso (a bound known already).
    Float near_clearance(const Vec3& q, uint32_t region, Float iso) const;
    // intersect_first (any = false) and intersect_any (any = true).
    FirstHit first_crossing(const Vec3& origin, const Vec3& dir, Float tnear, Float tfar, uint64_t set, bool any,
                            Hit& hit) const;
};

}  // namespace ep
