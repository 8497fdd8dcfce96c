// The local triangle cache (native/triangle_cache.h) must give the same
// crossings as the full Embree all-hits query for every segment inside its
// ball: random segments aimed at faces, edges and vertices of a box pair with
// coincident faces and of a curved mesh (a UV sphere), at miss distances from
// 1e-7 to 1e-1 of the feature size.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <iostream>
#include <random>
#include <set>
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

// Closed thick-walled tube along +x (the colon bench scene's, C++): inner
// radius r(x) = radius - fold (1 + cos(2 pi x / period)) / 2, wall `wall`,
// outward winding (the inner skin faces the lumen), annulus rings at the ends.
void tube(double length, double radius, double fold, double period, double wall, int n_x, int n_theta,
          std::vector<float>& v, std::vector<uint32_t>& t) {
    v.clear();
    t.clear();
    for (int skin = 0; skin < 2; ++skin)
        for (int i = 0; i < n_x; ++i) {
            const double x = length * i / (n_x - 1);
            const double r = radius - fold * 0.5 * (1 + std::cos(2 * kPi * x / period)) + (skin == 0 ? wall : 0);
            for (int j = 0; j < n_theta; ++j) {
                const double th = 2 * kPi * j / n_theta;
                v.insert(v.end(), {float(x), float(r * std::cos(th)), float(r * std::sin(th))});
            }
        }
    const uint32_t n = uint32_t(n_x * n_theta);
    auto id = [&](int i, int j) { return uint32_t(i * n_theta + (j % n_theta)); };
    for (int i = 0; i + 1 < n_x; ++i)
        for (int j = 0; j < n_theta; ++j) {
            t.insert(t.end(), {id(i, j), id(i + 1, j + 1), id(i + 1, j)});  // outer skin
            t.insert(t.end(), {id(i, j), id(i, j + 1), id(i + 1, j + 1)});
            t.insert(t.end(), {id(i, j) + n, id(i + 1, j) + n, id(i + 1, j + 1) + n});  // inner skin
            t.insert(t.end(), {id(i, j) + n, id(i + 1, j + 1) + n, id(i, j + 1) + n});
        }
    for (int j = 0; j < n_theta; ++j) {
        const int e = n_x - 1;
        t.insert(t.end(), {id(0, j), id(0, j) + n, id(0, j + 1) + n});  // x = 0 faces -x
        t.insert(t.end(), {id(0, j), id(0, j + 1) + n, id(0, j + 1)});
        t.insert(t.end(), {id(e, j), id(e, j + 1), id(e, j + 1) + n});  // x = length faces +x
        t.insert(t.end(), {id(e, j), id(e, j + 1) + n, id(e, j) + n});
    }
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

// A random point near a random feature (vertex, edge, face) of the meshes.
Vec3 near_feature(const std::vector<Mesh>& meshes, std::mt19937_64& rng, int* kind) {
    std::uniform_real_distribution<double> U(0, 1);
    const Mesh& m = meshes[rng() % meshes.size()];
    const size_t tri = rng() % (m.t.size() / 3);
    Vec3 P[3];
    for (int c = 0; c < 3; ++c) {
        const float* p = &m.v[3 * size_t(m.t[3 * tri + size_t(c)])];
        P[c] = Vec3(p[0], p[1], p[2]);
    }
    *kind = int(rng() % 3);
    double a = U(rng), b = U(rng);
    if (*kind == 0)
        a = 1, b = 0;
    else if (*kind == 1)
        b = 0;
    else if (a + b > 1)
        a = 1 - a, b = 1 - b;
    return P[0] + (P[1] - P[0]) * a + (P[2] - P[0]) * b;
}

Vec3 random_unit(std::mt19937_64& rng) {
    std::uniform_real_distribution<double> U(0, 1);
    const double z = 2 * U(rng) - 1, ph = 2 * kPi * U(rng), r = std::sqrt(1 - z * z);
    return Vec3(r * std::cos(ph), r * std::sin(ph), z);
}

// Compares cached and full queries on n segments aimed at random features of
// the meshes; returns the number of segments that crossed something.
int compare(const Scene& s, const std::vector<Mesh>& meshes, int n, uint64_t seed) {
    std::mt19937_64 rng(seed);
    std::uniform_real_distribution<double> U(0, 1);
    TriangleCacheBuilder cache;
    std::vector<Hit> full, cached;
    int crossed = 0, covered = 0, compared = 0;
    for (int k = 0; k < n; ++k) {
        int kind;
        const Vec3 q = near_feature(meshes, rng, &kind);
        const double miss = std::pow(10.0, -7 + 6 * U(rng));
        const Vec3 d = random_unit(rng);
        const double L = 0.05 + 0.2 * U(rng);
        const Vec3 o = q - d * (L * U(rng)) + random_unit(rng) * miss;
        const double back = 4e-7 * (max_abs_component(o) + 1e-3 * s.extent());
        EXPECT_TRUE(s.gather_triangles(o, 0.3, 4096, cache));
        if (!cache.covers(o - d * back, o + d * L)) continue;
        ++covered;
        s.intersect_all(o, d, -back, L, full);
        cache.intersect(s, o, d, -back, L, cached);
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
            // (Embree's float rounding grows with the coordinates' magnitude.)
            EXPECT_NEAR(ef[i].t, ec[i].t, 4e-6 * std::max(1.0, max_abs_component(o)))
                << "segment " << k << " kind " << kind << " miss " << miss << " n " << ef.size();
        }
    }
    EXPECT_GT(covered, n * 9 / 10);
    EXPECT_GT(compared, covered * 9 / 10);
    return crossed;
}

}  // namespace

// Two unit-thick boxes sharing the face z = -1 (coincident faces), committed.
void box_pair(Scene& s, std::vector<Mesh>& meshes) {
    const Medium m = plain_medium();
    box(-1, -1, -1, 1, 1, 0, meshes[0].v, meshes[0].t);
    s.add_region("top", meshes[0].v.data(), 8, meshes[0].t.data(), 12, m, 0);
    box(-1, -1, -2, 1, 1, -1, meshes[1].v, meshes[1].t);
    s.add_region("bottom", meshes[1].v.data(), 8, meshes[1].t.data(), 12, m, 1);
    s.commit();
}

TEST(TriangleCache, SameCrossingsAsFullQueryOnBoxesWithCoincidentFaces) {
    Scene s(1.0, 1.0);
    std::vector<Mesh> meshes(2);
    box_pair(s, meshes);
    const int crossed = compare(s, meshes, 20000, 11);
    EXPECT_GT(crossed, 20000 / 3);  // most segments cross a surface
}

TEST(TriangleCache, SameCrossingsAsFullQueryOnCurvedMesh) {
    Scene s(1.0, 1.0);
    const Medium m = plain_medium();
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
    TriangleCacheBuilder cache;
    // Near the top face only, by its diagonal: its two triangles, one plane.
    ASSERT_TRUE(s.gather_triangles(Vec3(0.01, 0.0, -0.01), 0.05, 48, cache));
    EXPECT_EQ(cache.size(), 2u);
    EXPECT_EQ(cache.plane_count(), 1u);
    std::vector<Hit> hits;
    cache.intersect(s, Vec3(0.01, 0.0, -0.01), Vec3(0, 0, 1), -1e-9, 0.02, hits);
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

namespace {

// The colon bench scene in C++ (cm): the folded tube (100 x 64 quads, 12,928
// triangles with the end rings) and a polyp (UV sphere of radius 0.3, higher
// priority) half inside the wall at the bottom of a valley.
void colon_like(Scene& s, std::vector<Mesh>& meshes) {
    meshes.resize(2);
    tube(8.0, 2.5, 0.5, 2.0, 0.3, 100, 64, meshes[0].v, meshes[0].t);
    s.add_region("colon", meshes[0].v.data(), meshes[0].v.size() / 3, meshes[0].t.data(), meshes[0].t.size() / 3,
                 plain_medium(), 0);
    sphere(0.3f, 5.0f, 0, -2.5f, 48, 24, meshes[1].v, meshes[1].t);
    s.add_region("polyp", meshes[1].v.data(), meshes[1].v.size() / 3, meshes[1].t.data(), meshes[1].t.size() / 3,
                 plain_medium(), 1);
    s.commit();
}

void box_pair(Scene& s, std::vector<Mesh>& meshes, float off) {
    meshes.resize(2);
    box(off - 1, off - 1, off - 1, off + 1, off + 1, off, meshes[0].v, meshes[0].t);
    s.add_region("top", meshes[0].v.data(), 8, meshes[0].t.data(), 12, plain_medium(), 0);
    box(off - 1, off - 1, off - 2, off + 1, off + 1, off - 1, meshes[1].v, meshes[1].t);
    s.add_region("bottom", meshes[1].v.data(), 8, meshes[1].t.data(), 12, plain_medium(), 1);
    s.commit();
}

// Distance from p to triangle abc, by another route than the engine's
// (Ericson's Voronoi regions): the projection onto the plane when it falls
// inside, else the nearest of the three edges.
double point_triangle_distance(const Vec3& p, const Vec3& a, const Vec3& b, const Vec3& c) {
    const Vec3 n = normalize(cross(b - a, c - a));
    const Vec3 q = p - n * dot(p - a, n);
    const double e0 = dot(cross(b - a, q - a), n), e1 = dot(cross(c - b, q - b), n), e2 = dot(cross(a - c, q - c), n);
    if (e0 >= 0 && e1 >= 0 && e2 >= 0) return std::fabs(dot(p - a, n));
    auto seg = [&](const Vec3& u, const Vec3& v) {
        const double s = std::clamp(dot(p - u, v - u) / dot(v - u, v - u), 0.0, 1.0);
        return length(p - (u + (v - u) * s));
    };
    return std::min({seg(a, b), seg(b, c), seg(c, a)});
}

// Distance from p to triangle i of a mesh.
double mesh_triangle_distance(const Vec3& p, const Mesh& mesh, size_t i) {
    Vec3 P[3];
    for (int j = 0; j < 3; ++j) {
        const float* v = &mesh.v[3 * size_t(mesh.t[3 * i + size_t(j)])];
        P[j] = Vec3(v[0], v[1], v[2]);
    }
    return point_triangle_distance(p, P[0], P[1], P[2]);
}

// The grid gather keeps every triangle within r of the centre (brute force
// over the whole scene) and none beyond r plus 1e-8 of the coordinates: balls of every size
// around faces, edges and vertices. Returns how many balls Embree's point
// query (the BVH gather this grid replaced) left short of the brute force.
int same_gathers(const Scene& s, const std::vector<Mesh>& meshes, Float size, int n, uint64_t seed) {
    std::mt19937_64 rng(seed);
    std::uniform_real_distribution<double> U(0, 1);
    TriangleCacheBuilder grid_cache, bvh_cache;
    int nonempty = 0, bvh_short = 0;
    for (int k = 0; k < n; ++k) {
        int kind;
        const Float r = size * std::pow(10.0, -4 + 4 * U(rng));
        const Vec3 c = near_feature(meshes, rng, &kind) + random_unit(rng) * (r * 1.5 * U(rng));
        EXPECT_TRUE(s.gather_triangles(c, r, 1 << 20, grid_cache));
        EXPECT_TRUE(s.gather_triangles_bvh(c, r, 1 << 20, bvh_cache));
        std::set<std::pair<uint32_t, uint32_t>> got, bvh;
        for (const auto& t : grid_cache.triangles()) got.emplace(t.region, t.prim);
        for (const auto& t : bvh_cache.triangles()) bvh.emplace(t.region, t.prim);
        EXPECT_EQ(got.size(), grid_cache.size()) << "ball " << k << ": a triangle gathered twice";
        bool short_of = false;
        for (size_t m = 0; m < meshes.size(); ++m)
            for (size_t i = 0; i < meshes[m].t.size() / 3; ++i) {
                const double dist = mesh_triangle_distance(c, meshes[m], i);
                const auto id = std::make_pair(uint32_t(m), uint32_t(i));
                if (dist <= r) {
                    EXPECT_TRUE(got.count(id)) << "ball " << k << " r " << r << " misses " << m << "/" << i;
                    short_of |= !bvh.count(id);
                }
                if (dist > r * (1 + 1e-6) + 1e-8 * (max_abs_component(c) + r))
                    EXPECT_FALSE(got.count(id)) << "ball " << k << " keeps " << m << "/" << i;
            }
        bvh_short += short_of;
        if (grid_cache.size() > 0) ++nonempty;
    }
    EXPECT_GT(nonempty, n / 2);
    return bvh_short;
}

}  // namespace

// Steps that end within Embree's float rounding of a face, just past it or
// just short of it (1e-13 to 1e-8 of the distance; Embree's float distance
// errs by ~1e-7): every query applies its window to the refined double
// distance, so the full query, the single-hit query and the cache all cross
// the face exactly when its refined distance is within the step. (The full
// queries once took Embree's float tfar as the window and missed ~1 in 10^5
// of the crossings a colon_polyp step ended just past; the cache found them.)
TEST(TriangleCache, StepsEndingAtAFaceCrossItInEveryQuery) {
    for (const double off : {0.0, 1000.0}) {  // also far from the origin
        Scene s(1.0, 1.0);
        std::vector<Mesh> meshes(2);
        box_pair(s, meshes, float(off));
        std::mt19937_64 rng(21);
        std::uniform_real_distribution<double> U(0, 1);
        TriangleCacheBuilder cache;
        std::vector<Hit> full, cached;
        int past = 0;
        for (int k = 0; k < 4000; ++k) {
            // A point of the top box's top face (z = off), away from its edges and diagonal.
            const Vec3 q(off - 0.9 + 1.8 * U(rng), off - 0.9 + 0.8 * U(rng), off);
            Vec3 d = random_unit(rng);
            if (std::fabs(d.z) < 0.2) continue;
            if (d.z < 0) d = d * -1.0;  // leaving the top box upward
            const Vec3 o = q - d * (0.01 + 0.1 * U(rng));
            const double t_face = (off - o.z) / d.z;  // the refined distance's value up to rounding
            const double rel = std::pow(10.0, -13 + 5 * U(rng)), sign = (k % 2) ? 1.0 : -1.0;
            const double s_end = t_face * (1 + sign * rel);
            const double back = 4e-7 * (max_abs_component(o) + 1e-3 * s.extent());
            ASSERT_TRUE(s.gather_triangles(o, 0.3, 4096, cache));
            ASSERT_TRUE(cache.covers(o - d * back, o + d * s_end));
            s.intersect_all(o, d, -back, s_end, full);
            cache.intersect(s, o, d, -back, s_end, cached);
            ASSERT_EQ(full.size(), cached.size()) << "k " << k << " rel " << rel * sign;
            for (size_t i = 0; i < full.size(); ++i) {
                EXPECT_EQ(full[i].t, cached[i].t);
                EXPECT_EQ(full[i].region, cached[i].region);
            }
            // The refined distance decides: crossed exactly when it is within the step.
            const bool crossed = !full.empty() && full.back().t > 0;
            if (crossed) EXPECT_LE(full.back().t, s_end);
            past += crossed;
            Hit h;
            const Scene::FirstHit f = s.intersect_first(o, d, -back, s_end, uint64_t(1), h);
            EXPECT_EQ(f.found, crossed) << "k " << k << " rel " << rel * sign;
            if (f.found && crossed) EXPECT_EQ(h.t, full.back().t);
        }
        EXPECT_GT(past, 1000);  // about half the steps end past the face
    }
}

TEST(TriangleGrid, GatherEqualsBvhGather) {
    {
        Scene s(1.0, 1.0);
        std::vector<Mesh> m;
        box_pair(s, m, 0);
        std::cout << "box pair: BVH gather short on " << same_gathers(s, m, 2.0, 2000, 21) << " of 2000 balls\n";
    }
    {
        Scene s(1.0, 1.0);  // huge coordinates: 1e6 away from the origin
        std::vector<Mesh> m;
        box_pair(s, m, 1e6f);
        std::cout << "box pair at 1e6: BVH gather short on " << same_gathers(s, m, 2.0, 2000, 22) << " of 2000 balls\n";
    }
    {
        Scene s(1.0, 1.0);
        std::vector<Mesh> m;
        colon_like(s, m);
        EXPECT_GT(s.grid().cell_count(), 1000u);
        std::cout << "colon: BVH gather short on " << same_gathers(s, m, 1.0, 300, 23) << " of 300 balls\n";
    }
}

// The gathers reject most triangles by lower bounds of their distance (the
// plane, the planes through the edges) before the exact closest-point test;
// those must never reject a triangle the exact test keeps. The exact test
// keeps every triangle within the padded radius r (1 + 1e-8) + 1e-9 (|c| + r)
// (scene.cpp's padded_radius): a ball whose padded radius exceeds a
// triangle's distance by 1e-10 of it, far above the rounding of either
// distance, must keep that triangle, at faces, edges and vertices alike.
void keeps_triangles_at_the_padded_radius(const Scene& s, const std::vector<Mesh>& meshes, Float near, int n,
                                          uint64_t seed) {
    std::mt19937_64 rng(seed);
    std::uniform_real_distribution<double> U(0, 1);
    TriangleCacheBuilder cache;
    int tested = 0;
    for (int k = 0; k < n; ++k) {
        int kind;
        const Vec3 c = near_feature(meshes, rng, &kind) + random_unit(rng) * (near * U(rng));
        for (size_t m = 0; m < meshes.size(); ++m)
            for (size_t i = 0; i < meshes[m].t.size() / 3; ++i) {
                const double d = mesh_triangle_distance(c, meshes[m], i);
                if (!(d < 2 * near) || d < 1e-8 * (max_abs_component(c) + near)) continue;
                const double r = (d * (1 + 1e-10) - 1e-9 * max_abs_component(c)) / (1 + 1e-8 + 1e-9);
                ASSERT_TRUE(s.gather_triangles(c, r, 1 << 20, cache));
                bool kept = false;
                for (const auto& t : cache.triangles()) kept |= t.region == m && t.prim == i;
                EXPECT_TRUE(kept) << "ball " << k << " at distance " << d << " drops " << m << "/" << i;
                ++tested;
            }
    }
    EXPECT_GT(tested, n);
}

TEST(TriangleGrid, GatherKeepsTrianglesAtThePaddedRadius) {
    {
        Scene s(1.0, 1.0);
        std::vector<Mesh> m;
        box_pair(s, m, 0);
        keeps_triangles_at_the_padded_radius(s, m, 0.5, 300, 31);
    }
    {
        Scene s(1.0, 1.0);  // huge coordinates: 1e6 away from the origin
        std::vector<Mesh> m;
        box_pair(s, m, 1e6f);
        keeps_triangles_at_the_padded_radius(s, m, 0.5, 300, 32);
    }
    {
        Scene s(1.0, 1.0);
        std::vector<Mesh> m;
        colon_like(s, m);
        keeps_triangles_at_the_padded_radius(s, m, 0.05, 100, 33);
    }
}

// A sliver keeps no edge planes (scene.cpp's compute_edge_planes), so the
// gathers' lower bounds cannot place the ball's centre beside it: a ball in
// the sliver's plane, far beyond its ends, passes the plane test and must
// still be left out by the exact test (a gather that kept every triangle
// "behind all its edge planes" would keep it: a sliver's are at -inf). A
// flat tetrahedron whose bottom face is that sliver, at 0 and 1e6 along z.
TEST(TriangleGrid, GatherLeavesOutASliverFarInItsPlane) {
    for (const float z0 : {0.0f, 1e6f}) {
        Scene s(1.0, 1.0);
        // A, B on the x axis, C 1e-5 off their line (area 5e-6 of a unit
        // edge: a sliver), D above; faces outward (det(B-A, C-A, D-A) > 0).
        const std::vector<float> v = {0, 0, z0, 1, 0, z0, 0.5f, 1e-5f, z0, 0.5f, 0.5f, z0 + 1};
        const std::vector<uint32_t> t = {0, 2, 1, 0, 1, 3, 1, 2, 3, 2, 0, 3};
        s.add_region("flat", v.data(), 4, t.data(), 4, plain_medium(), 0);
        s.commit();
        TriangleCacheBuilder cache;
        for (const double x : {-4.0, 5.0}) {  // on the line AB, 4 beyond A or B
            const Vec3 c(x, 0, z0);
            ASSERT_TRUE(s.gather_triangles(c, 0.5, 1 << 20, cache));
            EXPECT_EQ(cache.size(), 0u) << "ball at x " << x << " z " << z0;
            ASSERT_TRUE(s.gather_triangles_bvh(c, 0.5, 1 << 20, cache));
            EXPECT_EQ(cache.size(), 0u) << "BVH ball at x " << x << " z " << z0;
        }
        // A ball reaching the sliver's middle from below keeps it (and the
        // ball's foot on each face decides nothing it should not).
        ASSERT_TRUE(s.gather_triangles(Vec3(0.5, 0, z0 - 0.1), 0.2, 1 << 20, cache));
        bool sliver = false;
        for (const auto& tri : cache.triangles()) sliver |= tri.prim == 0;
        EXPECT_TRUE(sliver) << "z " << z0;
    }
}

TEST(TriangleCache, SameCrossingsAsFullQueryOnColonTubeWithPolyp) {
    Scene s(1.0, 1.0);
    std::vector<Mesh> meshes;
    colon_like(s, meshes);
    const int crossed = compare(s, meshes, 20000, 13);
    EXPECT_GT(crossed, 20000 / 3);
}

namespace {

// The transport's grouping tolerance (transport.cpp, group_tolerance).
double group_tol(const Vec3& p, double t, const Scene& s) {
    return 2e-6 * (max_abs_component(p) + t) + 1e-7 * s.extent();
}

// The regions containing o: along a ray from o, a region whose first
// (non-grazing) crossing is an exit contains it (locate_start's rule).
uint64_t regions_at(const Scene& s, const Vec3& o, const Vec3& d) {
    std::vector<Hit> hits;
    s.intersect_all(o, d, 0, kInf, hits);
    uint64_t seen = 0, set = 0;
    for (const Hit& h : hits) {
        const uint64_t bit = uint64_t(1) << h.region;
        if ((seen & bit) || h.cos_dn == 0) continue;
        seen |= bit;
        if (h.cos_dn > 0) set |= bit;
    }
    return set;
}

// The first interface (a group of hits that changes the top region) of an
// all-hits list for a packet in `set`, as next_interface finds it: the index
// range of its group, or {n, n} if there is none.
std::pair<size_t, size_t> first_interface(const Scene& s, const std::vector<Hit>& hits, const Vec3& p, uint64_t set) {
    const int region = s.top(set);
    size_t i = 0;
    while (i < hits.size()) {
        const double t0 = hits[i].t, tol = group_tol(p, t0, s);
        uint64_t enter = 0, leave = 0;
        size_t j = i;
        for (; j < hits.size() && hits[j].t <= t0 + tol; ++j) {
            if (hits[j].cos_dn < 0) enter |= uint64_t(1) << hits[j].region;
            if (hits[j].cos_dn > 0) leave |= uint64_t(1) << hits[j].region;
        }
        const uint64_t both = enter & leave;
        const uint64_t new_set = (set | (enter & ~both)) & ~(leave & ~both);
        if (new_set != set && s.top(new_set) != region) return {i, j};
        set = new_set;
        i = j;
    }
    return {hits.size(), hits.size()};
}

// A segment aimed at a face, an edge or a vertex (`kind`), missing it by
// 1e-7 to 0.1, from a packet in the true region set at its start; a ray to
// infinity one time in `inf_one_in`, as the look-ahead across the lumen.
struct Segment {
    Vec3 o, d;
    double tfar, back, miss;
    uint64_t set;
    int kind;
};

Segment random_segment(const Scene& s, const std::vector<Mesh>& meshes, std::mt19937_64& rng, int inf_one_in) {
    std::uniform_real_distribution<double> U(0, 1);
    Segment g;
    const Vec3 q = near_feature(meshes, rng, &g.kind);
    g.d = random_unit(rng);
    const double L = 0.05 + 0.2 * U(rng);
    g.miss = std::pow(10.0, -7 + 6 * U(rng));
    g.o = q - g.d * (L * U(rng)) + random_unit(rng) * g.miss;
    g.tfar = rng() % uint64_t(inf_one_in) == 0 ? kInf : L;
    g.back = 4e-7 * (max_abs_component(g.o) + 1e-3 * s.extent());
    g.set = regions_at(s, g.o, random_unit(rng));
    return g;
}

// Single-hit against all-hits on n segments aimed at faces, edges and vertices
// (a quarter of them rays to infinity, as the look-ahead across the lumen),
// for a packet in the true region set at the segment's start. Where the
// single-hit query answers alone (clearance above twice the tolerance and an
// interface), its hit must be the whole first interface group of the all-hits
// list, bit for bit; where it finds nothing, the all-hits list must hold no
// interface. Returns how many segments the single hit answered alone.
int compare_single(const Scene& s, const std::vector<Mesh>& meshes, int n, uint64_t seed, int* shared_fallbacks) {
    std::mt19937_64 rng(seed);
    std::vector<Hit> all;
    int alone = 0, empty = 0;
    for (int k = 0; k < n; ++k) {
        const Segment g0 = random_segment(s, meshes, rng, 4);
        const Vec3 &o = g0.o, &d = g0.d;
        const double tfar = g0.tfar, back = g0.back, miss = g0.miss;
        const uint64_t set = g0.set;
        const int kind = g0.kind;
        Hit h{};
        const Scene::FirstHit f = s.intersect_first(o, d, -back, tfar, set, h);
        s.intersect_all(o, d, -back, tfar, all);
        const auto g = first_interface(s, all, o, set);
        if (!f.found) {
            ++empty;
            EXPECT_EQ(g.first, all.size()) << "segment " << k << ": the all-hits list has an interface";
            continue;
        }
        const uint64_t new_set = set ^ (uint64_t(1) << h.region);
        if (!(f.clearance > 2 * group_tol(o, std::max(h.t, 0.0), s)) || s.top(new_set) == s.top(set)) {
            // Falls back to all-hits. On a box pair, every hit on the shared face must.
            if (std::fabs(o.z + h.t * d.z + 1) < 1e-9) ++*shared_fallbacks;
            continue;
        }
        ++alone;
        EXPECT_FALSE(std::fabs(o.z + h.t * d.z + 1) < 1e-9) << "segment " << k << ": a shared-face hit answered alone";
        EXPECT_LT(g.first, all.size()) << "segment " << k;
        if (g.first >= all.size()) continue;
        EXPECT_EQ(g.second - g.first, 1u) << "segment " << k << " kind " << kind << " miss " << miss;
        const Hit& e = all[g.first];
        EXPECT_EQ(e.region, h.region) << "segment " << k;
        EXPECT_EQ(e.prim, h.prim) << "segment " << k;
        EXPECT_EQ(e.t, h.t) << "segment " << k;  // the same refined distance, bit for bit
        EXPECT_EQ(e.cos_dn, h.cos_dn) << "segment " << k;
    }
    EXPECT_GT(empty, 0);
    return alone;
}

}  // namespace

TEST(SingleHit, AgreesWithAllHitsOnBoxesWithSharedFace) {
    Scene s(1.0, 1.0);
    std::vector<Mesh> m;
    box_pair(s, m, 0);
    int shared = 0;
    const int alone = compare_single(s, m, 20000, 31, &shared);
    EXPECT_GT(alone, 20000 / 20);  // most segments aim at edges and vertices, or meet nothing
    EXPECT_GT(shared, 0);          // hits on the face the two regions share went to all-hits
}

TEST(SingleHit, AgreesWithAllHitsOnColonTubeWithPolyp) {
    Scene s(1.0, 1.0);
    std::vector<Mesh> m;
    colon_like(s, m);
    int shared = 0;
    const int alone = compare_single(s, m, 20000, 32, &shared);
    EXPECT_GT(alone, 20000 / 10);
}

TEST(SingleHit, SharedFaceTrianglesHaveNoClearance) {
    // A hit in the middle of the face the two boxes share (z = -1) cannot be
    // answered alone; one in the middle of the top face (z = 0) can.
    Scene s(1.0, 1.0);
    std::vector<Mesh> m;
    box_pair(s, m, 0);
    Hit h{};
    const uint64_t top_bit = 1;
    Scene::FirstHit f = s.intersect_first(Vec3(0.1, 0.2, -0.5), Vec3(0, 0, -1), -1e-9, kInf, top_bit, h);
    ASSERT_TRUE(f.found);
    EXPECT_NEAR(h.t, 0.5, 1e-15);
    EXPECT_LT(f.clearance, 1e-12);
    f = s.intersect_first(Vec3(0.1, 0.2, -0.5), Vec3(0, 0, 1), -1e-9, kInf, top_bit, h);
    ASSERT_TRUE(f.found);
    EXPECT_NEAR(h.t, 0.5, 1e-15);
    EXPECT_GT(f.clearance, 1e-4);  // the isolation cap 1e-4 (|x| + extent), below the diagonal's 0.07
    EXPECT_GT(h.cos_dn, 0);        // leaving the top box
}

// ClearSteps (the transport's interior steps) answers "nothing to cross" only
// where the cache's own tests would: for chains of random steps near faces,
// edges and vertices, every step it calls clear is covered by the ball and
// meets no cached triangle from its look-behind on; and it is not so
// conservative that it clears nothing.
static int clear_steps_agree(const Scene& s, const std::vector<Mesh>& meshes, int chains, uint64_t seed) {
    std::mt19937_64 rng(seed);
    std::uniform_real_distribution<double> U(0, 1);
    TriangleCacheBuilder cache;
    std::vector<Hit> hits;
    int cleared = 0;
    for (int c = 0; c < chains; ++c) {
        int kind;
        const double radius = 0.05 + 0.25 * U(rng);
        Vec3 p = near_feature(meshes, rng, &kind) + random_unit(rng) * (radius * U(rng));
        EXPECT_TRUE(s.gather_triangles(p, radius, 4096, cache));
        if (cache.plane_count() > ClearSteps::kMaxPlanes) continue;
        const double max_back =
            4e-7 * (max_abs_component(cache.center()) + cache.radius() + 1e-3 * s.extent()) * 1.000001;
        ClearSteps zone;
        if (!zone.start(cache, p, max_back)) continue;
        for (int k = 0; k < 200; ++k) {
            const Vec3 d = random_unit(rng);
            const double len = radius * std::pow(10.0, -4 * U(rng)) * U(rng);
            const Vec3 b = p + d * len;
            if (!zone.clear(b, len)) break;
            ++cleared;
            const double back = 4e-7 * (max_abs_component(p) + 1e-3 * s.extent());
            EXPECT_LE(back, max_back);
            EXPECT_TRUE(cache.covers(p - d * back, b)) << "chain " << c << " step " << k;
            cache.intersect(s, p, d, -back, len, hits);
            EXPECT_TRUE(hits.empty()) << "chain " << c << " step " << k << " kind " << kind;
            p = b;
        }
    }
    return cleared;
}

TEST(ClearSteps, ClearOnlyWhereTheCacheFindsNothingOnBoxesWithCoincidentFaces) {
    Scene s(1.0, 1.0);
    std::vector<Mesh> meshes(2);
    box_pair(s, meshes);
    EXPECT_GT(clear_steps_agree(s, meshes, 4000, 21), 4000);
}

TEST(ClearSteps, ClearOnlyWhereTheCacheFindsNothingOnCurvedMesh) {
    Scene s(1.0, 1.0);
    const Medium m = plain_medium();
    std::vector<Mesh> meshes(1);
    sphere(1.0f, 0, 0, 0, 48, 24, meshes[0].v, meshes[0].t);
    s.add_region("sphere", meshes[0].v.data(), meshes[0].v.size() / 3, meshes[0].t.data(), meshes[0].t.size() / 3, m,
                 0);
    s.commit();
    EXPECT_GT(clear_steps_agree(s, meshes, 4000, 22), 1000);
}

// The any-hit query (Scene::intersect_any, the transport's mirror-ray test)
// finds a set-changing crossing exactly where the closest-hit query does, and
// the one it reports is in the all-hits list bit for bit. From the ambient
// (set 0), one with clearance above twice the grouping tolerance means the
// all-hits list has an interface (the ray lands), as mirror_lands assumes.
TEST(SingleHit, AnyHitAgreesWithClosestHitOnColonTubeWithPolyp) {
    Scene s(1.0, 1.0);
    std::vector<Mesh> m;
    colon_like(s, m);
    std::mt19937_64 rng(33);
    std::vector<Hit> all;
    int found = 0, lands = 0;
    for (int k = 0; k < 20000; ++k) {
        const Segment g = random_segment(s, m, rng, 2);
        const Vec3 &o = g.o, &d = g.d;
        const double tfar = g.tfar, back = g.back;
        const uint64_t set = g.set;
        Hit a{}, f{};
        const Scene::FirstHit any = s.intersect_any(o, d, -back, tfar, set, a);
        const Scene::FirstHit first = s.intersect_first(o, d, -back, tfar, set, f);
        ASSERT_EQ(any.found, first.found) << "segment " << k;
        if (!any.found) continue;
        ++found;
        s.intersect_all(o, d, -back, tfar, all);
        const bool listed = std::any_of(all.begin(), all.end(), [&](const Hit& h) {
            return h.region == a.region && h.prim == a.prim && h.t == a.t && h.cos_dn == a.cos_dn;
        });
        EXPECT_TRUE(listed) << "segment " << k;
        const bool inside = (set >> a.region) & 1;
        EXPECT_TRUE(inside ? a.cos_dn > 0 : a.cos_dn < 0) << "segment " << k << ": the crossing changes no set";
        if (set == 0 && any.clearance > 2 * group_tol(o, std::max(a.t, 0.0), s)) {
            ++lands;
            EXPECT_LT(first_interface(s, all, o, 0).first, all.size()) << "segment " << k << ": no landing";
        }
    }
    EXPECT_GT(found, 20000 / 4);
    EXPECT_GT(lands, 100);
}

// A wall whose top face a small block pokes through: the face's triangles
// touch the block, so their commit-time isolation is 0, but a crossing far
// from the block is clear of it (near_clearance), and one beside it is not.
TEST(SingleHit, ClearanceIsMeasuredAtTheCrossing) {
    Scene s(1.0, 1.0);
    std::vector<Mesh> m(2);
    box(-1, -1, -1, 1, 1, 0, m[0].v, m[0].t);
    s.add_region("wall", m[0].v.data(), 8, m[0].t.data(), 12, plain_medium(), 0);
    box(-0.05, -0.05, -0.1, 0.05, 0.05, 0.1, m[1].v, m[1].t);
    s.add_region("block", m[1].v.data(), 8, m[1].t.data(), 12, plain_medium(), 1);
    s.commit();
    const Vec3 down(0, 0, -1);
    Hit h{};
    Scene::FirstHit f = s.intersect_first(Vec3(0.5, 0.3, 1), down, 0, kInf, 0, h);
    ASSERT_TRUE(f.found);
    EXPECT_EQ(h.region, 0u);
    EXPECT_NEAR(h.t, 1.0, 1e-15);
    EXPECT_GT(f.clearance, 2 * group_tol(Vec3(0.5, 0.3, 1), 1.0, s));
    // 1e-6 beside the block's side face x = 0.05: no more clearance than that.
    f = s.intersect_first(Vec3(0.05 + 1e-6, 0.02, 1), down, 0, kInf, 0, h);
    ASSERT_TRUE(f.found);
    EXPECT_EQ(h.region, 0u);
    EXPECT_LE(f.clearance, 1.0001e-6);
    EXPECT_GT(f.clearance, 0.9e-6);
}
