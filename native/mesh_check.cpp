#include "mesh_check.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <mutex>
#include <numeric>
#include <sstream>
#include <stdexcept>
#include <utility>

#include <embree3/rtcore.h>

#include "embree_device.h"

namespace ep {

namespace {

[[noreturn]] void fail(const std::string& owner, const std::string& what) {
    throw std::invalid_argument(owner + ": " + what);
}

using P3 = std::array<double, 3>;

double orient3d(const P3& a, const P3& b, const P3& c, const P3& d) {
    const double ab[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]};
    const double ac[3] = {c[0] - a[0], c[1] - a[1], c[2] - a[2]};
    const double ad[3] = {d[0] - a[0], d[1] - a[1], d[2] - a[2]};
    return ab[0] * (ac[1] * ad[2] - ac[2] * ad[1]) - ab[1] * (ac[0] * ad[2] - ac[2] * ad[0]) +
           ab[2] * (ac[0] * ad[1] - ac[1] * ad[0]);
}

// True if segment pq crosses triangle abc: p and q strictly on opposite sides
// of its plane and the line through the closed triangle (on an edge counts).
// Touching (a vertex on a face, coplanar contact) does not count, so meshes
// that only touch themselves are not rejected.
bool segment_pierces(const P3& p, const P3& q, const P3& a, const P3& b, const P3& c) {
    const double sp = orient3d(a, b, c, p), sq = orient3d(a, b, c, q);
    if (!((sp > 0 && sq < 0) || (sp < 0 && sq > 0))) return false;
    const double s1 = orient3d(p, q, a, b), s2 = orient3d(p, q, b, c), s3 = orient3d(p, q, c, a);
    if (s1 == 0 && s2 == 0 && s3 == 0) return false;
    return (s1 >= 0 && s2 >= 0 && s3 >= 0) || (s1 <= 0 && s2 <= 0 && s3 <= 0);
}

// Two triangles without a shared (welded) vertex intersect if an edge of one
// pierces the other. Broad phase: Embree's BVH collision query (rtcCollide)
// over one user primitive per triangle, whose box is the triangle's widened
// outward by one float step: every pair whose closed boxes meet is offered
// (a superset; the exact test decides). (A sweep along the longest axis was
// quadratic in the triangles a slab across that axis holds: a tube of 1.64M
// triangles in rings of 2,048 spent ~12 s here.) Of the pairs that cross,
// the one with the lowest indices is named, whatever order Embree offers
// them in.
struct CollideMesh {
    const float* v;
    std::vector<std::array<uint32_t, 3>> idx;  // welded vertex indices per triangle
    std::mutex mutex;                          // guards `first` (callbacks may run in parallel)
    std::pair<size_t, size_t> first{SIZE_MAX, SIZE_MAX};

    P3 point(uint32_t i) const { return P3{v[3 * size_t(i)], v[3 * size_t(i) + 1], v[3 * size_t(i) + 2]}; }
    // An edge of triangle e pierces triangle f.
    bool pierces(size_t e, size_t f) const {
        const P3 a = point(idx[f][0]), b = point(idx[f][1]), c = point(idx[f][2]);
        for (int k = 0; k < 3; ++k)
            if (segment_pierces(point(idx[e][k]), point(idx[e][(k + 1) % 3]), a, b, c)) return true;
        return false;
    }
    void offer(size_t s, size_t t) {
        if (s == t) return;
        for (uint32_t x : idx[s])
            for (uint32_t y : idx[t])
                if (x == y) return;  // welded neighbours meet at the shared vertex
        if (!pierces(s, t) && !pierces(t, s)) return;
        const std::pair<size_t, size_t> p{std::min(s, t), std::max(s, t)};
        std::lock_guard<std::mutex> lock(mutex);
        first = std::min(first, p);
    }
};

void collide_bounds(const RTCBoundsFunctionArguments* args) {
    const auto* m = static_cast<const CollideMesh*>(args->geometryUserPtr);
    const auto& t = m->idx[args->primID];
    float lo[3], hi[3];
    for (int a = 0; a < 3; ++a) {
        lo[a] = hi[a] = m->v[3 * size_t(t[0]) + a];
        for (int k = 1; k < 3; ++k) {
            lo[a] = std::min(lo[a], m->v[3 * size_t(t[k]) + a]);
            hi[a] = std::max(hi[a], m->v[3 * size_t(t[k]) + a]);
        }
        lo[a] = std::nextafter(lo[a], -INFINITY);
        hi[a] = std::nextafter(hi[a], INFINITY);
    }
    RTCBounds* b = args->bounds_o;
    b->lower_x = lo[0], b->lower_y = lo[1], b->lower_z = lo[2];
    b->upper_x = hi[0], b->upper_y = hi[1], b->upper_z = hi[2];
}

void collide_pairs(void* user, RTCCollision* pairs, unsigned int n) {
    auto* m = static_cast<CollideMesh*>(user);
    for (unsigned i = 0; i < n; ++i) m->offer(pairs[i].primID0, pairs[i].primID1);
}

void check_self_intersection(const std::string& owner, const float* v, const uint32_t* tri, size_t nt,
                             const std::vector<uint32_t>& canon) {
    CollideMesh mesh;
    mesh.v = v;
    mesh.idx.resize(nt);
    for (size_t t = 0; t < nt; ++t)
        for (int k = 0; k < 3; ++k) mesh.idx[t][k] = canon[tri[3 * t + k]];
    struct Embree {                                                  // released on every path out, a throw included
        RTCDevice device = rtcNewDevice(embree_config("").c_str());  // every core: offer() is thread-safe
        RTCScene scene = device ? rtcNewScene(device) : nullptr;
        ~Embree() {
            if (scene) rtcReleaseScene(scene);
            if (device) rtcReleaseDevice(device);
        }
    } e;
    if (!e.scene) throw std::runtime_error(owner + ": Embree could not start for the self-intersection check");
    RTCGeometry g = rtcNewGeometry(e.device, RTC_GEOMETRY_TYPE_USER);
    rtcSetGeometryUserPrimitiveCount(g, unsigned(nt));
    rtcSetGeometryUserData(g, &mesh);
    rtcSetGeometryBoundsFunction(g, collide_bounds, nullptr);
    rtcCommitGeometry(g);
    rtcAttachGeometry(e.scene, g);
    rtcReleaseGeometry(g);
    rtcCommitScene(e.scene);
    rtcCollide(e.scene, e.scene, collide_pairs, &mesh);
    if (rtcGetDeviceError(e.device) != RTC_ERROR_NONE)
        throw std::runtime_error(owner + ": Embree failed in the self-intersection check");
    if (mesh.first.first != SIZE_MAX)
        fail(owner, "mesh intersects itself: mesh.triangles[" + std::to_string(mesh.first.first) +
                        "] and mesh.triangles[" + std::to_string(mesh.first.second) +
                        "] cross (split overlapping parts into separate regions)");
}

// Every coordinate finite; the bounding box into rep. Returns the largest
// side of the box (> 0).
double check_vertices(const std::string& owner, const float* v, size_t nv, MeshReport& rep) {
    for (size_t i = 0; i < nv; ++i) {
        for (int k = 0; k < 3; ++k) {
            const float x = v[3 * i + k];
            if (!std::isfinite(x)) {
                std::ostringstream os;
                os << "mesh.vertices[" << i << "][" << k << "] = " << x << " is not finite";
                fail(owner, os.str());
            }
        }
    }
    for (int k = 0; k < 3; ++k) {
        rep.bbox_min[k] = rep.bbox_max[k] = v[k];
    }
    for (size_t i = 0; i < nv; ++i)
        for (int k = 0; k < 3; ++k) {
            rep.bbox_min[k] = std::min(rep.bbox_min[k], double(v[3 * i + k]));
            rep.bbox_max[k] = std::max(rep.bbox_max[k], double(v[3 * i + k]));
        }
    const double extent = std::max(
        {rep.bbox_max[0] - rep.bbox_min[0], rep.bbox_max[1] - rep.bbox_min[1], rep.bbox_max[2] - rep.bbox_min[2]});
    if (!(extent > 0)) fail(owner, "mesh has zero extent");
    return extent;
}

// Exact welding: canonical index per distinct position (bit for bit), the
// lowest index that has it; the number of distinct positions into rep. By
// sorting, not hashing: a hash node per vertex and per directed edge below
// cost seconds on million-triangle meshes.
std::vector<uint32_t> weld_exact(const float* v, size_t nv, MeshReport& rep) {
    std::vector<uint32_t> canon(nv);
    auto bits = [v](size_t i) {
        std::array<uint32_t, 3> b;
        std::memcpy(b.data(), v + 3 * i, sizeof b);
        return b;
    };
    std::vector<uint32_t> order(nv);
    std::iota(order.begin(), order.end(), 0u);
    std::sort(order.begin(), order.end(), [&](uint32_t a, uint32_t b) {
        const auto ka = bits(a), kb = bits(b);
        return ka != kb ? ka < kb : a < b;
    });
    size_t groups = 0;
    for (size_t i = 0; i < nv; ++i) {
        const bool first = i == 0 || bits(order[i]) != bits(order[i - 1]);
        groups += first;
        canon[order[i]] = first ? order[i] : canon[order[i - 1]];
    }
    rep.welded_vertices = groups;
    return canon;
}

// Degenerate triangles: out-of-range or repeated indices, or an area that is
// zero at the precision of the mesh (|cross| below 1e-12 extent^2). Appends
// each triangle's directed edges a->b, as (a << 32) | b of welded indices, to
// `directed`; returns six times the signed volume.
double check_triangles(const std::string& owner, const float* v, size_t nv, const uint32_t* tri, size_t nt,
                       const std::vector<uint32_t>& canon, double extent, std::vector<uint64_t>& directed) {
    double volume6 = 0;
    const double area_floor = 1e-12 * extent * extent;
    directed.reserve(3 * nt);
    for (size_t t = 0; t < nt; ++t) {
        uint32_t idx[3];
        for (int k = 0; k < 3; ++k) {
            idx[k] = tri[3 * t + k];
            if (idx[k] >= nv) {
                std::ostringstream os;
                os << "mesh.triangles[" << t << "][" << k << "] = " << idx[k] << " is out of range (vertices: " << nv
                   << ")";
                fail(owner, os.str());
            }
            idx[k] = canon[idx[k]];
        }
        const float* a = v + 3 * size_t(idx[0]);
        const float* b = v + 3 * size_t(idx[1]);
        const float* c = v + 3 * size_t(idx[2]);
        const double e1[3] = {double(b[0]) - a[0], double(b[1]) - a[1], double(b[2]) - a[2]};
        const double e2[3] = {double(c[0]) - a[0], double(c[1]) - a[1], double(c[2]) - a[2]};
        const double cr[3] = {e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2],
                              e1[0] * e2[1] - e1[1] * e2[0]};
        const double area2 = std::sqrt(cr[0] * cr[0] + cr[1] * cr[1] + cr[2] * cr[2]);
        if (idx[0] == idx[1] || idx[1] == idx[2] || idx[0] == idx[2] || !(area2 > area_floor)) {
            std::ostringstream os;
            os << "mesh.triangles[" << t << "] = (" << tri[3 * t] << ", " << tri[3 * t + 1] << ", " << tri[3 * t + 2]
               << ") is degenerate (area " << 0.5 * area2 << ")";
            fail(owner, os.str());
        }
        volume6 += double(a[0]) * cr[0] + double(a[1]) * cr[1] + double(a[2]) * cr[2];
        for (int k = 0; k < 3; ++k) {
            const uint64_t from = idx[k], to = idx[(k + 1) % 3];
            directed.push_back((from << 32) | to);
        }
    }
    return volume6;
}

// Watertight and consistently oriented <=> every directed edge a->b occurs
// exactly once and its twin b->a occurs exactly once. The first edge that
// fails, in sorted order, is named.
void check_edges(const std::string& owner, std::vector<uint64_t>& directed) {
    std::sort(directed.begin(), directed.end());
    for (size_t i = 0; i < directed.size();) {
        const uint64_t key = directed[i];
        size_t j = i;
        while (j < directed.size() && directed[j] == key) ++j;
        const uint64_t a = key >> 32, b = key & 0xFFFFFFFFULL;
        if (j - i > 1) {
            std::ostringstream os;
            os << "mesh orientation is inconsistent: edge (" << a << ", " << b << ") is traversed " << j - i
               << " times in the same direction";
            fail(owner, os.str());
        }
        if (!std::binary_search(directed.begin(), directed.end(), (b << 32) | a)) {
            std::ostringstream os;
            os << "mesh is open (not watertight): edge (" << a << ", " << b << ") has only one triangle";
            fail(owner, os.str());
        }
        i = j;
    }
}

}  // namespace

MeshReport check_mesh(const std::string& owner, const float* v, size_t nv, const uint32_t* tri, size_t nt) {
    MeshReport rep;
    if (nv < 4) fail(owner, "mesh.vertices has " + std::to_string(nv) + " rows; a closed mesh needs at least 4");
    if (nt < 4) fail(owner, "mesh.triangles has " + std::to_string(nt) + " rows; a closed mesh needs at least 4");
    const double extent = check_vertices(owner, v, nv, rep);
    const std::vector<uint32_t> canon = weld_exact(v, nv, rep);
    std::vector<uint64_t> directed;
    const double volume6 = check_triangles(owner, v, nv, tri, nt, canon, extent, directed);
    check_edges(owner, directed);
    rep.signed_volume = volume6 / 6.0;
    if (!(rep.signed_volume > 0)) {
        std::ostringstream os;
        os << "mesh orientation is inward: signed volume = " << rep.signed_volume
           << " must be > 0 (flip the triangle winding / recalculate normals outside)";
        fail(owner, os.str());
    }
    check_self_intersection(owner, v, tri, nt, canon);
    return rep;
}

}  // namespace ep
