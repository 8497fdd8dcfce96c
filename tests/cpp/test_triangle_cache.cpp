// The local triangle cache (native/triangle_cache.h) must give the same
// crossings as the full Embree all-hits query for every segment inside its
// ball: random segments aimed at faces, edges and vertices of a box pair with
// coincident faces and of a curved mesh (a UV sphere), at miss distances from
// 1e-7 to 1e-1 of the feature size.
#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <vector>

#include "scene.h"
#include "test_meshes.h"
#include "triangle_cache.h"

using namespace ep;

namespace {

// UV sphere, CCW seen from outside (outward normals).
void sphere(float r, float cx, float cy, float cz, int n_phi, int n_theta, std::vector<float>& v,
            std::vector<uint32_t>& t) {
    v.clear();
    t.clear();
    v.insert(v.end(), {cx, cy, cz + r});
    for (int i = 1; i < n_theta; ++i) {
        const double th = kPi * i / n_theta;
        for (int j = 0; j < n_phi; ++j) {
            const double ph = 2 * kPi * j / n_phi;
            v.insert(v.end(), {float(cx + r * std::sin(th) * std::cos(ph)), float(cy + r * std::sin(th) * std::sin(ph)),
                               float(cz + r * std::cos(th))});
        }
    }
    v.insert(v.end(), {cx, cy, cz - r});
    const uint32_t south = uint32_t(v.size() / 3 - 1);
    auto ring = [&](int i, int j) { return uint32_t(1 + (i - 1) * n_phi + (j % n_phi)); };
    for (int j = 0; j < n_phi; ++j) t.insert(t.end(), {0u, ring(1, j), ring(1, j + 1)});
    for (int i = 1; i + 1 < n_theta; ++i)
        for (int j = 0; j < n_phi; ++j) {
            t.insert(t.end(), {ring(i, j), ring(i + 1, j), ring(i + 1, j + 1)});
            t.insert(t.end(), {ring(i, j), ring(i + 1, j + 1), ring(i, j + 1)});
        }
    for (int j = 0; j < n_phi; ++j) t.insert(t.end(), {south, ring(n_theta - 1, j + 1), ring(n_theta - 1, j)});
}

// A crossing as the transport sees it: hits within a tolerance are one group;
// per region, entered and left (a region both entered and left was touched).
struct Event {
    double t;
    uint64_t enter, leave;
};

std::vector<Event> events(const std::vector<Hit>& hits) {
    std::vector<Event> out;
    size_t i = 0;
    while (i < hits.size()) {
        const double t0 = hits[i].t, tol = 1e-6 * (1 + std::fabs(t0));
        uint64_t enter = 0, leave = 0;
        size_t j = i;
        for (; j < hits.size() && hits[j].t <= t0 + tol; ++j) {
            if (hits[j].cos_dn < 0) enter |= uint64_t(1) << hits[j].region;
            if (hits[j].cos_dn > 0) leave |= uint64_t(1) << hits[j].region;
        }
        const uint64_t both = enter & leave;
        if ((enter | leave) & ~both) out.push_back(Event{t0, enter & ~both, leave & ~both});
        i = j;
    }
    return out;
}

bool ambiguous(const std::vector<Hit>& hits, double t0, double t1) {
    for (size_t i = 0; i < hits.size(); ++i) {
        if (std::fabs(hits[i].t - t0) < 1e-6 || std::fabs(hits[i].t - t1) < 1e-6) return true;
        if (std::fabs(hits[i].cos_dn) < 1e-2) return true;
        if (i > 0 && hits[i].t - hits[i - 1].t > 1e-9 && hits[i].t - hits[i - 1].t < 1e-4) return true;
    }
    return false;
}

struct Mesh {
    std::vector<float> v;
    std::vector<uint32_t> t;
};

// Compares cached and full queries on n segments aimed at random features of
// the meshes; returns the number of segments that crossed something.
int compare(const Scene& s, const std::vector<Mesh>& meshes, int n, uint64_t seed) {
    std::mt19937_64 rng(seed);
    std::uniform_real_distribution<double> U(0, 1);
    auto unit = [&] {
        const double z = 2 * U(rng) - 1, ph = 2 * kPi * U(rng), r = std::sqrt(1 - z * z);
        return Vec3(r * std::cos(ph), r * std::sin(ph), z);
    };
    TriangleCache cache;
    std::vector<Hit> full, cached;
    int crossed = 0, covered = 0, compared = 0;
    for (int k = 0; k < n; ++k) {
        const Mesh& m = meshes[rng() % meshes.size()];
        const size_t tri = rng() % (m.t.size() / 3);
        Vec3 P[3];
        for (int c = 0; c < 3; ++c) {
            const float* p = &m.v[3 * size_t(m.t[3 * tri + size_t(c)])];
            P[c] = Vec3(p[0], p[1], p[2]);
        }
        // A vertex, a point on an edge, or a point inside the face.
        const int kind = int(rng() % 3);
        double a = U(rng), b = U(rng);
        if (kind == 0)
            a = 1, b = 0;
        else if (kind == 1)
            b = 0;
        else if (a + b > 1)
            a = 1 - a, b = 1 - b;
        const Vec3 q = P[0] + (P[1] - P[0]) * a + (P[2] - P[0]) * b * (kind == 1 ? 0 : 1);
        const double miss = std::pow(10.0, -7 + 6 * U(rng));
        const Vec3 d = unit();
        const double L = 0.05 + 0.2 * U(rng);
        const Vec3 o = q - d * (L * U(rng)) + unit() * miss;
        const double back = 4e-7 * (max_abs_component(o) + 1e-3 * s.extent());
        EXPECT_TRUE(s.gather_triangles(o, 0.3, 4096, cache));
        if (!cache.covers(o - d * back, o + d * L)) continue;
        ++covered;
        s.intersect_all(o, d, -back, L, full);
        cache.intersect(o, d, -back, L, cached);
        // Float-precision ambiguities of Embree itself are left out: a grazing
        // hit (|cos| < 1e-2), or two crossings closer than 1e-4 but not one
        // crossing (a near-tangent touch, where float rounding decides whether
        // the ray dips in at all).
        // So is a hit within 1e-6 of either end of the segment (Embree's
        // float tnear / tfar against the double plane distance).
        if (ambiguous(full, -back, L) || ambiguous(cached, -back, L)) continue;
        ++compared;
        const auto ef = events(full), ec = events(cached);
        if (!ef.empty()) ++crossed;
        EXPECT_EQ(ef.size(), ec.size()) << "segment " << k << " kind " << kind << " miss " << miss;
        if (ef.size() != ec.size()) continue;
        for (size_t i = 0; i < ef.size(); ++i) {
            EXPECT_EQ(ef[i].enter, ec[i].enter) << "segment " << k << " kind " << kind << " miss " << miss;
            EXPECT_EQ(ef[i].leave, ec[i].leave) << "segment " << k << " kind " << kind << " miss " << miss;
            // The group's first hit may be the other triangle of an edge:
            // equal within the transport's grouping tolerance.
            EXPECT_NEAR(ef[i].t, ec[i].t, 4e-6)
                << "segment " << k << " kind " << kind << " miss " << miss << " n " << ef.size();
        }
    }
    EXPECT_GT(covered, n * 9 / 10);
    EXPECT_GT(compared, covered * 9 / 10);
    return crossed;
}

}  // namespace

Medium tissue() {
    Medium m;
    m.mua = 1;
    m.mus = 10;
    return m;
}

TEST(TriangleCache, SameCrossingsAsFullQueryOnBoxesWithCoincidentFaces) {
    Scene s(1.0, 1.0);
    const Medium m = tissue();
    std::vector<Mesh> meshes(2);
    box(-1, -1, -1, 1, 1, 0, meshes[0].v, meshes[0].t);
    s.add_region("top", meshes[0].v.data(), 8, meshes[0].t.data(), 12, m, 0);
    box(-1, -1, -2, 1, 1, -1, meshes[1].v, meshes[1].t);
    s.add_region("bottom", meshes[1].v.data(), 8, meshes[1].t.data(), 12, m, 1);
    s.commit();
    const int crossed = compare(s, meshes, 20000, 11);
    EXPECT_GT(crossed, 20000 / 3);  // most segments cross a surface
}

TEST(TriangleCache, SameCrossingsAsFullQueryOnCurvedMesh) {
    Scene s(1.0, 1.0);
    const Medium m = tissue();
    std::vector<Mesh> meshes(2);
    sphere(1.0f, 0, 0, 0, 48, 24, meshes[0].v, meshes[0].t);
    s.add_region("sphere", meshes[0].v.data(), meshes[0].v.size() / 3, meshes[0].t.data(), meshes[0].t.size() / 3, m,
                 0);
    sphere(0.3f, 0.5f, 0, 0, 24, 12, meshes[1].v, meshes[1].t);  // a polyp-like inclusion
    s.add_region("inclusion", meshes[1].v.data(), meshes[1].v.size() / 3, meshes[1].t.data(), meshes[1].t.size() / 3, m,
                 1);
    s.commit();
    const int crossed = compare(s, meshes, 20000, 12);
    EXPECT_GT(crossed, 20000 / 3);
}

TEST(TriangleCache, CoplanarTrianglesShareOnePlaneAndFarBallIsEmpty) {
    Scene s(1.0, 1.0);
    Medium m;
    m.mua = 1;
    std::vector<float> v;
    std::vector<uint32_t> t;
    box(-5, -5, -10, 5, 5, 0, v, t);
    s.add_region("tissue", v.data(), 8, t.data(), 12, m, 0);
    s.commit();
    TriangleCache cache;
    // Near the top face only, by its diagonal: its two triangles, one plane.
    ASSERT_TRUE(s.gather_triangles(Vec3(0.01, 0.0, -0.01), 0.05, 48, cache));
    EXPECT_EQ(cache.size(), 2u);
    EXPECT_EQ(cache.plane_count(), 1u);
    std::vector<Hit> hits;
    cache.intersect(Vec3(0.01, 0.0, -0.01), Vec3(0, 0, 1), -1e-9, 0.02, hits);
    ASSERT_EQ(hits.size(), 1u);  // the ray meets the top face at one of its two triangles
    EXPECT_NEAR(hits[0].t, 0.01, 1e-15);
    EXPECT_GT(hits[0].cos_dn, 0);  // leaving
    // Deep inside: no triangle meets the ball.
    ASSERT_TRUE(s.gather_triangles(Vec3(0, 0, -5), 1.0, 48, cache));
    EXPECT_EQ(cache.size(), 0u);
    // Too many triangles: the gather gives up and the cache covers nothing.
    EXPECT_FALSE(s.gather_triangles(Vec3(0, 0, -5), 100.0, 4, cache));
    EXPECT_FALSE(cache.covers(Vec3(0, 0, -5), Vec3(0, 0, -5)));
}
