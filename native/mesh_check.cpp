#include "mesh_check.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <sstream>
#include <stdexcept>
#include <unordered_map>

namespace ep {

namespace {

struct PosKey {
    float p[3];
    bool operator==(const PosKey& o) const { return std::memcmp(p, o.p, sizeof p) == 0; }
};
struct PosHash {
    size_t operator()(const PosKey& k) const {
        uint32_t b[3];
        std::memcpy(b, k.p, sizeof b);
        uint64_t h = 1469598103934665603ULL;
        for (uint32_t v : b) h = (h ^ v) * 1099511628211ULL;
        return size_t(h);
    }
};

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
// pierces the other. Broad phase: sweep over the triangles' intervals along
// the longest axis.
void check_self_intersection(const std::string& owner, const float* v, const uint32_t* tri, size_t nt,
                             const std::vector<uint32_t>& canon) {
    struct Box {
        double lo[3], hi[3];
        uint32_t idx[3];
        size_t t;
    };
    std::vector<Box> boxes(nt);
    for (size_t t = 0; t < nt; ++t) {
        Box& b = boxes[t];
        b.t = t;
        for (int k = 0; k < 3; ++k) b.idx[k] = canon[tri[3 * t + k]];
        for (int a = 0; a < 3; ++a) {
            b.lo[a] = b.hi[a] = v[3 * size_t(b.idx[0]) + a];
            for (int k = 1; k < 3; ++k) {
                b.lo[a] = std::min(b.lo[a], double(v[3 * size_t(b.idx[k]) + a]));
                b.hi[a] = std::max(b.hi[a], double(v[3 * size_t(b.idx[k]) + a]));
            }
        }
    }
    // Sweep along the mesh's longest axis: a long tube (a colon) then meets
    // only its neighbouring rings in the sweep window.
    double ext[3] = {0, 0, 0};
    for (int a = 0; a < 3; ++a) {
        double lo = INFINITY, hi = -INFINITY;
        for (const Box& b : boxes) lo = std::min(lo, b.lo[a]), hi = std::max(hi, b.hi[a]);
        ext[a] = hi - lo;
    }
    const int ax = ext[0] >= ext[1] && ext[0] >= ext[2] ? 0 : (ext[1] >= ext[2] ? 1 : 2);
    const int o1 = (ax + 1) % 3, o2 = (ax + 2) % 3;
    std::sort(boxes.begin(), boxes.end(), [ax](const Box& a, const Box& b) { return a.lo[ax] < b.lo[ax]; });
    auto point = [&](uint32_t i) { return P3{v[3 * size_t(i)], v[3 * size_t(i) + 1], v[3 * size_t(i) + 2]}; };
    auto pierces = [&](const Box& e, const Box& f) {
        const P3 a = point(f.idx[0]), b = point(f.idx[1]), c = point(f.idx[2]);
        for (int k = 0; k < 3; ++k)
            if (segment_pierces(point(e.idx[k]), point(e.idx[(k + 1) % 3]), a, b, c)) return true;
        return false;
    };
    for (size_t i = 0; i < nt; ++i) {
        const Box& A = boxes[i];
        for (size_t j = i + 1; j < nt && boxes[j].lo[ax] <= A.hi[ax]; ++j) {
            const Box& B = boxes[j];
            if (B.lo[o1] > A.hi[o1] || A.lo[o1] > B.hi[o1] || B.lo[o2] > A.hi[o2] || A.lo[o2] > B.hi[o2]) continue;
            bool shared = false;
            for (uint32_t x : A.idx)
                for (uint32_t y : B.idx) shared = shared || x == y;
            if (shared) continue;
            if (pierces(A, B) || pierces(B, A)) {
                const size_t t1 = std::min(A.t, B.t), t2 = std::max(A.t, B.t);
                fail(owner, "mesh intersects itself: mesh.triangles[" + std::to_string(t1) + "] and mesh.triangles[" +
                                std::to_string(t2) + "] cross (split overlapping parts into separate regions)");
            }
        }
    }
}

}  // namespace

MeshReport check_mesh(const std::string& owner, const float* v, size_t nv, const uint32_t* tri, size_t nt) {
    MeshReport rep;
    if (nv < 4) fail(owner, "mesh.vertices has " + std::to_string(nv) + " rows; a closed mesh needs at least 4");
    if (nt < 4) fail(owner, "mesh.triangles has " + std::to_string(nt) + " rows; a closed mesh needs at least 4");
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

    // Exact welding: canonical index per distinct position.
    std::vector<uint32_t> canon(nv);
    std::unordered_map<PosKey, uint32_t, PosHash> seen;
    seen.reserve(nv * 2);
    for (size_t i = 0; i < nv; ++i) {
        PosKey key{{v[3 * i], v[3 * i + 1], v[3 * i + 2]}};
        auto it = seen.emplace(key, uint32_t(i));
        canon[i] = it.first->second;
    }
    rep.welded_vertices = seen.size();

    // Degenerate triangles: out-of-range or repeated indices, or an area that is
    // zero at the precision of the mesh (|cross| below 1e-12 extent^2).
    double volume6 = 0;
    const double area_floor = 1e-12 * extent * extent;
    std::unordered_map<uint64_t, int> directed;  // (a,b) -> count of directed edge a->b
    directed.reserve(nt * 4);
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
            directed[(from << 32) | to] += 1;
        }
    }
    // Watertight and consistently oriented <=> every directed edge a->b occurs
    // exactly once and its twin b->a occurs exactly once.
    for (const auto& [key, count] : directed) {
        const uint64_t a = key >> 32, b = key & 0xFFFFFFFFULL;
        auto twin = directed.find((b << 32) | a);
        const int twin_count = twin == directed.end() ? 0 : twin->second;
        if (count > 1) {
            std::ostringstream os;
            os << "mesh orientation is inconsistent: edge (" << a << ", " << b << ") is traversed " << count
               << " times in the same direction";
            fail(owner, os.str());
        }
        if (twin_count == 0) {
            std::ostringstream os;
            os << "mesh is open (not watertight): edge (" << a << ", " << b << ") has only one triangle";
            fail(owner, os.str());
        }
    }
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
