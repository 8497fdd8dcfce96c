#include "scene.h"

#include <algorithm>
#include <cstdlib>
#include <memory>
#include <numeric>
#include <sstream>
#include <stdexcept>

#include "eem.h"
#include "embree_device.h"
#include "triangle_cache.h"

namespace ep {

namespace {

// Intersection context extended with the hit list the filter fills.
struct CollectContext {
    RTCIntersectContext base;  // must be first: Embree hands back a pointer to it
    const std::vector<Region>* regions;
    const std::vector<std::vector<float>>* vertices;
    const std::vector<std::vector<uint32_t>>* triangles;
    Vec3 org, dir;         // the ray in double; distances are measured from org
    Float t_begin, t_end;  // the window: hits with refined distance in [t_begin, t_end] count
    std::vector<Hit>* hits;
};

// Distance along the ray (org, dir) to the plane of triangle `prim` of
// `region`, in double: t = (v0 - org).n / (dir.n), cos_dn = dir.n != 0. The
// triangle cache computes the same expression (TriangleCache::intersect_open).
Float plane_distance(const std::vector<std::vector<float>>& vertices,
                     const std::vector<std::vector<uint32_t>>& triangles, const Vec3& n, unsigned region, unsigned prim,
                     const Vec3& org, Float cos_dn) {
    const float* v = &vertices[region][3 * size_t(triangles[region][3 * size_t(prim)])];
    return dot(Vec3(v[0], v[1], v[2]) - org, n) / cos_dn;
}

void collect_filter(const RTCFilterFunctionNArguments* args) {
    if (args->N != 1 || !args->valid[0]) return;
    auto* ctx = reinterpret_cast<CollectContext*>(args->context);
    const unsigned geom = RTCHitN_geomID(args->hit, args->N, 0);
    const unsigned prim = RTCHitN_primID(args->hit, args->N, 0);
    const unsigned region = geom;  // geometry ids equal region indices (checked in add_region)
    const Vec3& n = (*ctx->regions)[region].normals[prim];
    // A BVH may reference a triangle from two leaves; keep each triangle once.
    for (const Hit& h : *ctx->hits)
        if (h.region == region && h.prim == prim) {
            args->valid[0] = 0;
            return;
        }
    // Embree's distance is float precision (~1e-7 relative). Refine it in double
    // against the triangle's plane, t = (v0 - o).n / (d.n), so that straight
    // paths (Beer-Lambert, thin layers) are exact to double rounding. The
    // plane distance is the double ray's own (also for grazing rays, where
    // Embree's float distance is the less accurate one), and it is the value
    // the local triangle cache computes; the window is applied to it, not to
    // Embree's float distance (embree_window), and a hit in the triangle's
    // plane (cos 0, which the transport ignores) is dropped, as the cache
    // drops both: the two give identical hit lists.
    args->valid[0] = 0;  // reject: traversal goes on and collects every crossing
    const Float cos_dn = dot(ctx->dir, n);
    if (cos_dn == 0) return;
    const Float t_hit = plane_distance(*ctx->vertices, *ctx->triangles, n, region, prim, ctx->org, cos_dn);
    if (!(t_hit >= ctx->t_begin && t_hit <= ctx->t_end)) return;
    ctx->hits->push_back(Hit{t_hit, region, prim, cos_dn});
}

// The ray handed to Embree (float) for the window [t_begin, t_end] of the
// double ray from org (t_end may be infinite), its end widened by `margin`:
// Embree's float distances err by ~1e-7 of the coordinates and of t, so a
// crossing that a step ends just past could fall beyond Embree's float tfar
// while its refined distance lies inside the window. The filters apply the
// window to the refined distance; the margin only makes Embree offer every
// candidate. (Without it, a colon_polyp packet whose step ended 2.7e-10 past
// the wall stayed inside under the full query and crossed under the cache,
// and safe_distance on and off parted after ~40,000 packets.) The ray's
// origin, direction and tnear are unchanged: Embree's float tests of the
// triangles, edges and vertices stay as they were. (The start needs no
// margin: the transport's queries look behind the packet, and what lies at
// the very start of that look-behind is the surface just crossed.)
RTCRayHit embree_window(const Vec3& org, const Vec3& d, Float t_begin, Float t_end) {
    const Float margin = 4e-7 * (max_abs_component(org) + (std::isfinite(t_end) ? t_end : Float(0)));
    RTCRayHit rh;
    rh.ray.org_x = float(org.x);
    rh.ray.org_y = float(org.y);
    rh.ray.org_z = float(org.z);
    rh.ray.dir_x = float(d.x);
    rh.ray.dir_y = float(d.y);
    rh.ray.dir_z = float(d.z);
    rh.ray.tnear = float(t_begin);
    rh.ray.tfar = std::isfinite(t_end) ? float(t_end + margin) : std::numeric_limits<float>::infinity();
    rh.ray.time = 0;
    rh.ray.mask = 0xFFFFFFFFu;
    rh.ray.id = 0;
    rh.ray.flags = 0;
    rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
    rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
    return rh;
}

// Context of the single-hit query: the region set the ray starts in.
struct FirstContext {
    RTCIntersectContext base;  // must be first
    const std::vector<Region>* regions;
    const std::vector<std::vector<float>>* vertices;
    const std::vector<std::vector<uint32_t>>* triangles;
    Vec3 org, dir;  // as CollectContext's
    Float t_begin, t_end;
    uint64_t set;
    unsigned region = RTC_INVALID_GEOMETRY_ID, prim = 0;  // the last crossing accepted
};

// Accepts only crossings that change the region set (entering a region not in
// it, leaving one in it); Embree's closest-hit traversal goes on past the
// others -- re-hits of the surface just crossed, grazing hits -- which the
// transport would skip in an all-hits list too. The same filter serves the
// any-hit (occlusion) query, which ends at the first crossing it accepts:
// that one is noted in the context, since an occlusion query reports no hit.
void first_filter(const RTCFilterFunctionNArguments* args) {
    if (args->N != 1 || !args->valid[0]) return;
    auto* ctx = reinterpret_cast<FirstContext*>(args->context);
    const unsigned region = RTCHitN_geomID(args->hit, args->N, 0);
    const unsigned prim = RTCHitN_primID(args->hit, args->N, 0);
    const Vec3& n = (*ctx->regions)[region].normals[prim];
    const Float cos_dn = dot(ctx->dir, n);
    const bool inside = (ctx->set >> region) & 1;
    if (!((cos_dn < 0 && !inside) || (cos_dn > 0 && inside))) {
        args->valid[0] = 0;
        return;
    }
    // The window on the refined distance, as collect_filter applies it.
    const Float t = plane_distance(*ctx->vertices, *ctx->triangles, n, region, prim, ctx->org, cos_dn);
    if (!(t >= ctx->t_begin && t <= ctx->t_end)) {
        args->valid[0] = 0;
        return;
    }
    ctx->region = region;
    ctx->prim = prim;
}

// Closest point on triangle abc to p (Ericson, Real-Time Collision Detection §5.1.5),
// returned as squared distance.
Float closest_distance2(const Vec3& p, const Vec3& a, const Vec3& b, const Vec3& c) {
    const Vec3 ab = b - a, ac = c - a, ap = p - a;
    const Float d1 = dot(ab, ap), d2 = dot(ac, ap);
    if (d1 <= 0 && d2 <= 0) return dot(ap, ap);
    const Vec3 bp = p - b;
    const Float d3 = dot(ab, bp), d4 = dot(ac, bp);
    if (d3 >= 0 && d4 <= d3) return dot(bp, bp);
    const Float vc = d1 * d4 - d3 * d2;
    if (vc <= 0 && d1 >= 0 && d3 <= 0) {
        const Vec3 q = a + ab * (d1 / (d1 - d3));
        return dot(p - q, p - q);
    }
    const Vec3 cp = p - c;
    const Float d5 = dot(ab, cp), d6 = dot(ac, cp);
    if (d6 >= 0 && d5 <= d6) return dot(cp, cp);
    const Float vb = d5 * d2 - d1 * d6;
    if (vb <= 0 && d2 >= 0 && d6 <= 0) {
        const Vec3 q = a + ac * (d2 / (d2 - d6));
        return dot(p - q, p - q);
    }
    const Float va = d3 * d6 - d5 * d4;
    if (va <= 0 && (d4 - d3) >= 0 && (d5 - d6) >= 0) {
        const Vec3 q = b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)));
        return dot(p - q, p - q);
    }
    const Float denom = 1 / (va + vb + vc);
    const Vec3 q = a + ab * (vb * denom) + ac * (vc * denom);
    return dot(p - q, p - q);
}

struct PointQueryData {
    const std::vector<std::vector<float>>* vertices;
    const std::vector<std::vector<uint32_t>>* triangles;
    Vec3 p;
    Float best2;
};

bool closest_callback(RTCPointQueryFunctionArguments* args) {
    auto* q = static_cast<PointQueryData*>(args->userPtr);
    const unsigned region = args->geomID;
    const auto& v = (*q->vertices)[region];
    const auto& t = (*q->triangles)[region];
    const uint32_t* tri = &t[3 * size_t(args->primID)];
    auto vert = [&](uint32_t i) { return Vec3(v[3 * i], v[3 * i + 1], v[3 * i + 2]); };
    const Float d2 = closest_distance2(q->p, vert(tri[0]), vert(tri[1]), vert(tri[2]));
    if (d2 < q->best2) {
        q->best2 = d2;
        args->query->radius = float(std::sqrt(d2));
        return true;
    }
    return false;
}

struct GatherData {
    const Scene::EdgePlanes* edge_planes;  // Scene::edge_planes_
    const uint32_t* base;                  // Scene::region_base_
    Vec3 c;
    Float r, r2;
    Float c_max;  // max_abs_component(c), for the rounding room below
    TriangleCacheBuilder* cache;
    size_t max_count;
    bool overflow = false;

    GatherData(const Scene::EdgePlanes* edge_planes_, const uint32_t* base_, const Vec3& c_, Float r_,
               TriangleCacheBuilder* cache_, size_t max_count_)
        : edge_planes(edge_planes_),
          base(base_),
          c(c_),
          r(r_),
          r2(r_ * r_),
          c_max(max_abs_component(c_)),
          cache(cache_),
          max_count(max_count_) {}

    // Keeps triangle (region, prim), scene-wide triangle `id`, if it meets
    // the ball (exact double distance); both gathers (grid and BVH) apply
    // this one test.
    void offer(uint32_t id, unsigned region, unsigned prim) {
        if (overflow) return;
        // Two lower bounds of the distance to the triangle reject most
        // neighbours before the exact test: the distance to its plane, and
        // how far the centre lies beyond one of its edge planes (on
        // colon_polyp ~60% of the exact tests failed, nearly all of them
        // beside an edge). The second rejects only with room for the
        // rounding of both it and closest_distance2 (1e-9 of the coordinates,
        // ~1e6 ulps), so that every triangle it rejects closest_distance2
        // rejects as well: the cache is the same as with the exact test alone.
        const Scene::EdgePlanes& e = edge_planes[id];
        const Float dp = dot(e.n, c - e.p0);
        if (dp * dp > r2) return;
        const Float s =
            std::max({dot(e.side[0], c) - e.off[0], dot(e.side[1], c) - e.off[1], dot(e.side[2], c) - e.off[2]});
        const Float room = 1e-9 * (c_max + e.scale + r);
        if (s > r + room) return;
        // Behind all three edge planes by more than that room, the centre's
        // foot on the plane lies inside the triangle, so the plane distance
        // (within r, tested above) is the distance: kept without the exact
        // test, which would keep it too (on colon_polyp most kept triangles
        // are met so, the cubes being small next to them). A sliver has no
        // edge planes (s = -inf) and takes the exact test.
        const Vec3 p1 = e.v1(), p2 = e.v2();
        if (!(s < -room && s > -kInf) && closest_distance2(c, e.p0, p1, p2) > r2) return;
        if (cache->size() >= max_count) {
            overflow = true;
            return;
        }
        cache->add(id, e.p0, p1, p2, e.n, region, prim);
    }
};

// The query radius never shrinks, so Embree visits every candidate.
bool gather_callback(RTCPointQueryFunctionArguments* args) {
    auto* data = static_cast<GatherData*>(args->userPtr);
    data->offer(data->base[args->geomID] + args->primID, args->geomID, args->primID);
    return false;
}

// The ball's radius for the exact test: a little larger than the cache's, so
// that rounding can never drop a triangle that meets the cache's ball. The
// grid's bounds tests are in double (its own margin covers them); Embree's
// are in float, ~1e-7 of the coordinates, so its ball needs 1e-6 of them.
Float padded_radius(const Vec3& c, Float radius, Float rel) {
    return radius * (1 + 10 * rel) + rel * (max_abs_component(c) + radius);
}

}  // namespace

Scene::Scene(Float unit_cm, Float ambient_n) : unit_cm_(unit_cm), ambient_n_(ambient_n) {
    if (!std::isfinite(unit_cm) || unit_cm <= 0) {
        std::ostringstream os;
        os << "scene.unit_cm = " << unit_cm << " must be a positive number";
        throw std::invalid_argument(os.str());
    }
    if (!std::isfinite(ambient_n) || ambient_n < 1) {
        std::ostringstream os;
        os << "scene.ambient_n = " << ambient_n << " must be a finite number >= 1";
        throw std::invalid_argument(os.str());
    }
    device_ = new_embree_device("threads=1");
    scene_ = rtcNewScene(device_);
    rtcSetSceneFlags(scene_, RTCSceneFlags(RTC_SCENE_FLAG_ROBUST | RTC_SCENE_FLAG_CONTEXT_FILTER_FUNCTION));
    rtcSetSceneBuildQuality(scene_, RTC_BUILD_QUALITY_MEDIUM);
}

Scene::~Scene() {
    if (scene_) rtcReleaseScene(scene_);
    if (device_) rtcReleaseDevice(device_);
}

int Scene::add_region(const std::string& name, const float* vertices, size_t nv, const uint32_t* triangles, size_t nt,
                      const Medium& medium, int priority) {
    if (committed_) throw std::logic_error("Scene::add_region after commit");
    const std::string owner = "region '" + name + "'";
    if (regions_.size() >= size_t(kMaxRegions)) {
        throw std::invalid_argument(owner + ": a scene holds at most " + std::to_string(kMaxRegions) + " regions");
    }
    for (const Region& r : regions_)
        if (r.name == name) throw std::invalid_argument(owner + ": name is used by another region");
    medium.validate(owner);
    Region region;
    region.name = name;
    region.medium = medium;
    region.priority = priority;
    region.report = check_mesh(owner, vertices, nv, triangles, nt);

    vertices_.emplace_back(vertices, vertices + 3 * nv);
    triangles_.emplace_back(triangles, triangles + 3 * nt);
    const auto& v = vertices_.back();
    const auto& t = triangles_.back();
    region.normals.resize(nt);
    for (size_t i = 0; i < nt; ++i) {
        auto P = [&](uint32_t k) { return Vec3(v[3 * k], v[3 * k + 1], v[3 * k + 2]); };
        const Vec3 a = P(t[3 * i]), b = P(t[3 * i + 1]), c = P(t[3 * i + 2]);
        region.normals[i] = normalize(cross(b - a, c - a));  // CCW winding -> outward
    }

    RTCGeometry geom = rtcNewGeometry(device_, RTC_GEOMETRY_TYPE_TRIANGLE);
    rtcSetSharedGeometryBuffer(geom, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, v.data(), 0, 3 * sizeof(float), nv);
    rtcSetSharedGeometryBuffer(geom, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, t.data(), 0, 3 * sizeof(uint32_t), nt);
    rtcCommitGeometry(geom);
    region.geom_id = rtcAttachGeometry(scene_, geom);
    rtcReleaseGeometry(geom);
    if (region.geom_id != regions_.size()) throw std::logic_error("Embree geometry ids are not sequential");

    for (int k = 0; k < 3; ++k) {
        if (regions_.empty()) {
            bbox_min_[k] = region.report.bbox_min[k];
            bbox_max_[k] = region.report.bbox_max[k];
        } else {
            bbox_min_[k] = std::min(bbox_min_[k], region.report.bbox_min[k]);
            bbox_max_[k] = std::max(bbox_max_[k], region.report.bbox_max[k]);
        }
    }
    extent_ = std::max({bbox_max_[0] - bbox_min_[0], bbox_max_[1] - bbox_min_[1], bbox_max_[2] - bbox_min_[2]});
    regions_.push_back(std::move(region));
    return int(regions_.size() - 1);
}

int Scene::add_fluorophore(const std::string& name, std::shared_ptr<const EEM> eem) {
    if (!eem) throw std::invalid_argument("fluorophore '" + name + "': eem is missing");
    for (size_t i = 0; i < fluor_names_.size(); ++i)
        if (fluor_names_[i] == name) {
            return int(i);
        }
    fluor_names_.push_back(name);
    eems_.push_back(std::move(eem));
    return int(eems_.size() - 1);
}

void Scene::set_region_fluorophores(int region, const std::vector<FluorophoreRef>& refs) {
    Region& r = regions_.at(size_t(region));
    for (const FluorophoreRef& f : refs) {
        const std::string owner = "region '" + r.name + "': fluorophore";
        if (f.id < 0 || size_t(f.id) >= eems_.size())
            throw std::invalid_argument(owner + " id " + std::to_string(f.id) + " names no EEM");
        const std::string fname = owner + " '" + fluor_names_[size_t(f.id)] + "'";
        if (!std::isfinite(f.d) || f.d < 0 || f.d > 1) {
            std::ostringstream os;
            os << fname << ": d = " << f.d << " must be in [0, 1]";
            throw std::invalid_argument(os.str());
        }
        if (!std::isfinite(f.c) || f.c < 0 || f.c > 1) {
            std::ostringstream os;
            os << fname << ": c = " << f.c << " must be in [0, 1]";
            throw std::invalid_argument(os.str());
        }
    }
    r.fluorophores = refs;
}

bool Scene::has_fluorophores() const {
    for (const Region& r : regions_)
        if (!r.fluorophores.empty()) return true;
    return false;
}

bool Scene::has_spectral_media() const {
    for (const Region& r : regions_)
        if (r.medium.spectral()) return true;
    return false;
}

void Scene::commit() {
    if (regions_.empty()) throw std::invalid_argument("scene.regions is empty: add at least one region");
    // Rank regions by (priority, index): the highest rank is the medium in overlaps.
    std::vector<int> order(regions_.size());
    std::iota(order.begin(), order.end(), 0);
    std::stable_sort(order.begin(), order.end(),
                     [&](int a, int b) { return regions_[size_t(a)].priority < regions_[size_t(b)].priority; });
    rank_.assign(regions_.size(), 0);
    for (size_t k = 0; k < order.size(); ++k) rank_[size_t(order[k])] = int(k);
    rtcCommitScene(scene_);
    grid_.build(vertices_, triangles_);
    region_base_.assign(regions_.size(), 0);
    for (size_t r = 1; r < regions_.size(); ++r)
        region_base_[r] = region_base_[r - 1] + uint32_t(regions_[r - 1].normals.size());
    corners_.clear();
    corners_.reserve(3 * grid_.triangle_count());
    for (size_t r = 0; r < regions_.size(); ++r)
        for (uint32_t k : triangles_[r]) {
            const float* v = &vertices_[r][3 * size_t(k)];
            corners_.emplace_back(v[0], v[1], v[2]);
        }
    compute_edge_planes();
    compute_isolation();
    no_cache_ = std::make_unique<TriangleCache>();
    cells_.reset(grid_.cell_count());
    committed_ = true;
}

void Scene::compute_edge_planes() {
    edge_planes_.resize(grid_.triangle_count());
    for (size_t r = 0; r < regions_.size(); ++r)
        for (size_t i = 0; i < regions_[r].normals.size(); ++i) {
            const size_t id = region_base_[r] + i;
            const Vec3* P = &corners_[3 * id];
            EdgePlanes& e = edge_planes_[id];
            e.n = regions_[r].normals[i];
            e.p0 = P[0];
            for (int k = 0; k < 3; ++k) {  // float mesh data: exact
                e.p1[k] = float(P[1][k]);
                e.p2[k] = float(P[2][k]);
            }
            e.scale = std::max({max_abs_component(P[0]), max_abs_component(P[1]), max_abs_component(P[2])});
            // The plane through edge (P[k], P[k+1]) containing the triangle's
            // geometric normal g; its unit normal cross(edge, g) points away
            // from the third vertex when oriented so. A sliver (area below
            // 1e-4 of its longest edge squared) keeps no edge planes: its
            // closest points are ill-conditioned.
            const Vec3 g = cross(P[1] - P[0], P[2] - P[0]);
            const Float longest2 =
                std::max({dot(P[1] - P[0], P[1] - P[0]), dot(P[2] - P[1], P[2] - P[1]), dot(P[0] - P[2], P[0] - P[2])});
            const bool thin = !(length(g) > 1e-4 * longest2);
            for (int k = 0; k < 3; ++k) {
                const Vec3 &a = P[k], &b = P[(k + 1) % 3], &o = P[(k + 2) % 3];
                Vec3 u = thin ? Vec3(0, 0, 0) : normalize(cross(b - a, g));
                if (dot(u, o - a) > 0) u = -u;
                e.side[k] = u;
                e.off[k] = thin ? kInf : dot(u, a);
            }
        }
}

// isolation_[T]: a lower bound of the distance from triangle T to every
// triangle of another region (coincident faces of layered slabs, a polyp that
// meets the wall, nearby surfaces), capped at `cap`. Each candidate gives the
// larger of two lower bounds: the gap between the bounding boxes, and how far
// one triangle's vertices all lie on one side of the other's plane; touching
// or coincident triangles get 0. T's own region is left out: its neighbours
// meet T at T's edges, which the query's edge distance covers, and a closed,
// non-self-crossing mesh (mesh_check) has no other part of itself within the
// grouping tolerance of T's interior. The cap, 1e-4 of the coordinates'
// magnitude plus the extent, is far above that tolerance (~1e-6 of it), the
// only distance the bound is compared with.
void Scene::compute_isolation() {
    const Float scale = std::max({std::fabs(bbox_min_[0]), std::fabs(bbox_min_[1]), std::fabs(bbox_min_[2]),
                                  std::fabs(bbox_max_[0]), std::fabs(bbox_max_[1]), std::fabs(bbox_max_[2])});
    const Float cap = 1e-4 * (scale + extent_);
    isolation_.assign(grid_.triangle_count(), float(cap));
    if (regions_.size() < 2) return;
    auto corners = [&](uint32_t region, uint32_t prim, Vec3 p[3], Vec3& lo, Vec3& hi) {
        const auto& v = vertices_[region];
        const uint32_t* t = &triangles_[region][3 * size_t(prim)];
        for (int k = 0; k < 3; ++k) p[k] = Vec3(v[3 * t[k]], v[3 * t[k] + 1], v[3 * t[k] + 2]);
        lo = Vec3(std::min({p[0].x, p[1].x, p[2].x}), std::min({p[0].y, p[1].y, p[2].y}),
                  std::min({p[0].z, p[1].z, p[2].z}));
        hi = Vec3(std::max({p[0].x, p[1].x, p[2].x}), std::max({p[0].y, p[1].y, p[2].y}),
                  std::max({p[0].z, p[1].z, p[2].z}));
    };
    // How far all of q lie on one side of the plane (n, through p0); 0 if they straddle it.
    auto plane_gap = [](const Vec3& n, const Vec3& p0, const Vec3 q[3]) {
        const Float a = dot(n, q[0] - p0), b = dot(n, q[1] - p0), c = dot(n, q[2] - p0);
        return std::max({Float(0), std::min({a, b, c}), -std::max({a, b, c})});
    };
    for (uint32_t r = 0; r < regions_.size(); ++r)
        for (uint32_t i = 0; i < regions_[r].normals.size(); ++i) {
            Vec3 P[3], lo, hi;
            corners(r, i, P, lo, hi);
            Float iso = cap;
            grid_.visit(lo - Vec3(cap, cap, cap), hi + Vec3(cap, cap, cap), [&](const TriangleGrid::Ref& o) {
                if (grid_.in_region(o.id, r)) return true;
                const uint32_t o_region = grid_.region_of(o.id), o_prim = grid_.prim_of(o.id, o_region);
                Vec3 Q[3], qlo, qhi;
                corners(o_region, o_prim, Q, qlo, qhi);
                const Vec3 gap(std::max({Float(0), qlo.x - hi.x, lo.x - qhi.x}),
                               std::max({Float(0), qlo.y - hi.y, lo.y - qhi.y}),
                               std::max({Float(0), qlo.z - hi.z, lo.z - qhi.z}));
                const Float bound = std::max({length(gap), plane_gap(regions_[r].normals[i], P[0], Q),
                                              plane_gap(regions_[o_region].normals[o_prim], Q[0], P)});
                iso = std::min(iso, bound);
                return true;
            });
            // Room for the rounding of the bound and of its float copy.
            isolation_[region_base_[r] + i] = float(iso * (1 - 1e-5));
        }
}

void Scene::intersect_all(const Vec3& o, const Vec3& d, Float tnear, Float tfar, std::vector<Hit>& out) const {
    out.clear();
    static_assert(offsetof(CollectContext, base) == 0, "context must start with RTCIntersectContext");
    CollectContext ctx;
    rtcInitIntersectContext(&ctx.base);
    ctx.base.filter = collect_filter;
    ctx.regions = &regions_;
    ctx.vertices = &vertices_;
    ctx.triangles = &triangles_;
    ctx.dir = d;
    ctx.hits = &out;
    // Embree needs tnear >= 0. A negative tnear means "also report crossings up
    // to |tnear| behind o": the origin is backed up along the ray and the
    // distances shifted back afterwards. The transport relies on this to never
    // lose a crossing that rounding put just behind the packet.
    const Float back = tnear < 0 ? -tnear : Float(0);
    ctx.org = back > 0 ? o - d * back : o;
    ctx.t_begin = std::max(tnear, Float(0));
    ctx.t_end = tfar + back;
    RTCRayHit rh = embree_window(ctx.org, d, ctx.t_begin, ctx.t_end);
    rtcIntersect1(scene_, &ctx.base, &rh);
    if (back > 0)
        for (Hit& h : out) h.t -= back;
    if (out.size() > 1) std::sort(out.begin(), out.end(), [](const Hit& a, const Hit& b) { return hit_before(a, b); });
}

Scene::FirstHit Scene::intersect_first(const Vec3& o, const Vec3& d, Float tnear, Float tfar, uint64_t set,
                                       Hit& hit) const {
    return first_crossing(o, d, tnear, tfar, set, false, hit);
}

Scene::FirstHit Scene::intersect_any(const Vec3& o, const Vec3& d, Float tnear, Float tfar, uint64_t set,
                                     Hit& hit) const {
    return first_crossing(o, d, tnear, tfar, set, true, hit);
}

Scene::FirstHit Scene::first_crossing(const Vec3& o, const Vec3& d, Float tnear, Float tfar, uint64_t set, bool any,
                                      Hit& hit) const {
    static_assert(offsetof(FirstContext, base) == 0, "context must start with RTCIntersectContext");
    FirstContext ctx;
    rtcInitIntersectContext(&ctx.base);
    ctx.base.filter = first_filter;
    ctx.regions = &regions_;
    ctx.vertices = &vertices_;
    ctx.triangles = &triangles_;
    ctx.dir = d;
    ctx.set = set;
    // The same backed-up ray and window as intersect_all, so the refined
    // distance below is bit-identical to the one collect_filter gives for
    // this triangle.
    const Float back = tnear < 0 ? -tnear : Float(0);
    const Vec3 org = back > 0 ? o - d * back : o;
    ctx.org = org;
    ctx.t_begin = std::max(tnear, Float(0));
    ctx.t_end = tfar + back;
    RTCRayHit rh = embree_window(org, d, ctx.t_begin, ctx.t_end);
    if (any) {
        // The occlusion query sets tfar to -inf when a crossing passed the
        // filter, which noted it in the context.
        rtcOccluded1(scene_, &ctx.base, &rh.ray);
        if (rh.ray.tfar >= 0) ctx.region = RTC_INVALID_GEOMETRY_ID;
    } else {
        rtcIntersect1(scene_, &ctx.base, &rh);
        ctx.region = rh.hit.geomID;
        ctx.prim = rh.hit.primID;
    }
    FirstHit r;
    if (ctx.region == RTC_INVALID_GEOMETRY_ID) return r;
    const uint32_t region = ctx.region, prim = ctx.prim;
    const uint32_t* tri = &triangles_[region][3 * size_t(prim)];
    const auto& v = vertices_[region];
    auto vert = [&](uint32_t i) { return Vec3(v[3 * i], v[3 * i + 1], v[3 * i + 2]); };
    const Vec3 a = vert(tri[0]), b = vert(tri[1]), c = vert(tri[2]);
    const Vec3& n = regions_[region].normals[prim];
    const Float cos_dn = dot(d, n);  // != 0: first_filter rejects grazing hits
    const Float t = plane_distance(vertices_, triangles_, n, region, prim, org, cos_dn);
    hit = Hit{t - back, region, prim, cos_dn};
    // Clearance: how far the crossing point is from T's edges (where the
    // neighbour triangle would be hit too) and from every other region's
    // triangle (isolation_, a lower bound found at commit, or near_clearance
    // where that bound is the smaller one).
    const Vec3 q = org + d * t;
    auto edge = [&](const Vec3& e0, const Vec3& e1) { return length(cross(e1 - e0, q - e0)) / length(e1 - e0); };
    const Float edges = std::min({edge(a, b), edge(b, c), edge(c, a)});
    Float others = isolation_[region_base_[region] + prim];
    if (others < edges) others = near_clearance(q, region, others);
    r.clearance = std::min(edges, others);
    r.found = true;
    return r;
}

// isolation_ is one bound for the whole triangle: a wall triangle that a
// polyp passes through gets 0 even where it is millimetres from the polyp
// (on colon_polyp ~19% of the launch rays hit such triangles, and each cost
// an all-hits query besides the single-hit one; callgrind at 10,000
// packets: 0.26 -> 0.01 all-hits queries and 44.8k -> 44.2k instructions a
// packet). The distance from the crossing point itself to the other
// regions' triangles within a small radius rho of it (through the triangle
// grid, which lists every triangle in every cell it meets) bounds it
// better: every other triangle is either within rho, at its exact distance,
// or farther. rho, 1e-5 of the coordinates' magnitude plus the extent, is
// several times twice the transport's grouping tolerance at the crossing,
// the distance the bound is compared with (~5 times for a ray across
// colon_polyp's lumen); the factor below leaves room for the rounding, as in
// isolation_.
Float Scene::near_clearance(const Vec3& q, uint32_t region, Float iso) const {
    const Float rho = 1e-5 * (max_abs_component(q) + extent_);
    if (iso >= rho) return iso;
    Float best2 = rho * rho;
    grid_.visit(q - Vec3(rho, rho, rho), q + Vec3(rho, rho, rho), [&](const TriangleGrid::Ref& o) {
        if (grid_.in_region(o.id, region)) return true;
        const Vec3 e = o.centre() - q;
        const Float reach = o.reach + rho;
        if (dot(e, e) > reach * reach) return true;  // its bounding sphere lies beyond rho
        const Vec3* c = &corners_[3 * size_t(o.id)];
        best2 = std::min(best2, closest_distance2(q, c[0], c[1], c[2]));
        return best2 > 0;
    });
    return std::max(iso, std::sqrt(best2) * (1 - 1e-5));
}

Float Scene::distance_to_surface(const Vec3& p, Float radius) const {
    RTCPointQuery q;
    q.x = float(p.x);
    q.y = float(p.y);
    q.z = float(p.z);
    q.time = 0;
    q.radius = float(radius);
    RTCPointQueryContext qc;
    rtcInitPointQueryContext(&qc);
    PointQueryData data{&vertices_, &triangles_, p, radius * radius};
    rtcPointQuery(scene_, &q, &qc, closest_callback, &data);
    return std::min(radius, std::sqrt(data.best2));
}

bool Scene::gather_triangles(const Vec3& c, Float radius, size_t max_count, TriangleCacheBuilder& cache) const {
    cache.reset(c, radius);
    // A triangle spanning several cells is listed in each: the mailbox passes
    // its first listing only.
    TriangleCacheBuilder::Mailbox box = cache.mailbox(grid_.triangle_count());
    const Float r = padded_radius(c, radius, 1e-9);
    GatherData data(edge_planes_.data(), region_base_.data(), c, r, &cache, max_count);
    grid_.visit(c - Vec3(r, r, r), c + Vec3(r, r, r), [&](const TriangleGrid::Ref& t) {
        // A triangle met in an earlier cell is skipped first: triangles are
        // large next to a cube (on colon_polyp ~37 listings a gather name ~6
        // triangles), and the sphere test is the same for every listing, so
        // only its first needs it. The bounding sphere then rejects most
        // candidates before the exact test.
        if (!box.first_offer(t.id)) return true;
        const Vec3 e = t.centre() - c;
        const Float reach = r + t.reach;
        if (dot(e, e) > reach * reach) return true;
        const uint32_t region = grid_.region_of(t.id);
        data.offer(t.id, region, grid_.prim_of(t.id, region));
        return !data.overflow;
    });
    if (data.overflow) cache.clear();
    return !data.overflow;
}

const TriangleCache& Scene::cell_cache(const Vec3& p) const {
    size_t cell;
    int cube;
    Vec3 c;  // the cube's centre
    if (!grid_.cube_of<kCellSplit>(p, &cell, &cube, &c)) return *no_cache_;
    // Gathered into a per-thread cache (its vectors keep their capacity from
    // cube to cube, and its mailbox drops the triangles met again in another
    // grid cell for a stamp compare each), then frozen into the store. (A
    // short list of the candidates offered, searched for every candidate,
    // cost ~400 of a build's ~2.8k instructions on colon_polyp; callgrind.)
    struct Builder {
        TriangleCacheBuilder scratch;
        CellCacheStore::Cursor cursor;
    };
    thread_local Builder builder;
    std::atomic<TriangleCache*>* slot_ptr = cells_.slot(cell, cube, builder.cursor);
    if (!slot_ptr) return *no_cache_;  // the store is full
    std::atomic<TriangleCache*>& slot = *slot_ptr;
    if (const TriangleCache* built = slot.load(std::memory_order_acquire)) return *built;
    if (cells_.full()) return *no_cache_;  // the same answers through the full query
    const Float side = grid_.cell_size() / kCellSplit;
    TriangleCacheBuilder& scratch = builder.scratch;
    if (gather_triangles(c, side, kCellMaxTriangles, scratch) && scratch.size() == 0) widen_empty(c, side, scratch);
    void* bytes = cells_.allocate(TriangleCache::frozen_size(scratch), builder.cursor);
    TriangleCache* built = TriangleCache::freeze(scratch, bytes);
    TriangleCache* expected = nullptr;
    if (slot.compare_exchange_strong(expected, built, std::memory_order_acq_rel)) return *built;
    // Another thread was first (the same content): the block stays unused.
    return *expected;
}

const TriangleCache& Scene::cube_cache(const Vec3& p, TriangleCacheBuilder& scratch) const {
    if (const TriangleCache* built = built_cell_cache(p)) return *built;
    const TriangleCache& cache = cell_cache(p);
    if (&cache != no_cache_.get()) return cache;
    size_t cell;
    int cube;
    Vec3 c;
    if (!grid_.cube_of<kCellSplit>(p, &cell, &cube, &c)) return *no_cache_;
    // The store is full: cell_cache's build, kept in the caller's scratch.
    const Float side = grid_.cell_size() / kCellSplit;
    if (gather_triangles(c, side, kCellMaxTriangles, scratch) && scratch.size() == 0) widen_empty(c, side, scratch);
    return scratch;
}

void Scene::widen_empty(const Vec3& c, Float side, TriangleCacheBuilder& scratch) const {
    // No triangle meets the ball of one side: the first wider ball that
    // none meets either (the same gather, stopped at its first triangle by a
    // limit of none) is the cube's. Any step inside a ball no triangle
    // meets crosses nothing, so the wider ball answers as the narrow one
    // did; the steps then go farther before the next hop. (Callgrind,
    // colon_polyp, instructions a packet for 20,000 packets on a new scene /
    // 20,000 more on the same scene / 150,000 on a new one: one side 41.6k /
    // 36.7k / 39.3k; {2} 41.8k / 35.9k / 39.0k; {3, 2} 42.6k / 35.8k; {2.5}
    // 42.4k / 36.0k; {1.5} 42.2k / 35.9k: a wider ball's failed gathers cost
    // more than its longer stays save. Wall clock, {4, 2} against {2}, the
    // same bits: median 0.97 of the packets per CPU-second, 8 interleaved
    // pairs at 300,000 packets.)
    for (const Float k : kEmptyWiden)
        if (gather_triangles(c, k * side, 0, scratch)) return;
    scratch.reset(c, side);  // known empty at one side
}

bool Scene::gather_triangles_bvh(const Vec3& c, Float radius, size_t max_count, TriangleCacheBuilder& cache) const {
    cache.reset(c, radius);
    const Float r = padded_radius(c, radius, 1e-6);
    RTCPointQuery q;
    q.x = float(c.x);
    q.y = float(c.y);
    q.z = float(c.z);
    q.time = 0;
    q.radius = float(r * (1 + 1e-5));
    RTCPointQueryContext qc;
    rtcInitPointQueryContext(&qc);
    GatherData data(edge_planes_.data(), region_base_.data(), c, r, &cache, max_count);
    rtcPointQuery(scene_, &q, &qc, gather_callback, &data);
    if (data.overflow) cache.clear();
    return !data.overflow;
}

}  // namespace ep
