// The scene's per-cube triangle caches (Scene::cell_cache, issue 11): the
// cache of the cube around a point holds the triangles that meet its ball
// (the grid gather's), the ball holds the cube, two points of one
// cube share one cache, and a step inside the ball gets the crossings of the
// full Embree query.
#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <set>
#include <vector>

#include "scene.h"
#include "test_meshes.h"
#include "triangle_cache.h"

using namespace ep;

namespace {

// Two touching boxes (coincident faces at z = -1) and a small tilted box
// inside the top one, so that cubes see faces, edges, corners and
// coincident faces; 36 triangles make a grid of 10 cells a side.
struct Scenery {
    Scene s{1.0, 1.0};
    std::vector<float> v[3];
    std::vector<uint32_t> t[3];
    Scenery() {
        box(-1, -1, -1, 1, 1, 0, v[0], t[0]);
        box(-1, -1, -2, 1, 1, -1, v[1], t[1]);
        box(-0.3f, -0.2f, -0.6f, 0.2f, 0.3f, -0.2f, v[2], t[2]);
        for (size_t i = 0; i < v[2].size(); i += 3) {  // tilt the small box about x by 0.3 rad
            const double y = v[2][i + 1], z = v[2][i + 2] + 0.4;
            v[2][i + 1] = float(std::cos(0.3) * y - std::sin(0.3) * z);
            v[2][i + 2] = float(std::sin(0.3) * y + std::cos(0.3) * z - 0.4);
        }
        const char* names[3] = {"top", "bottom", "inclusion"};
        for (int r = 0; r < 3; ++r) s.add_region(names[r], v[r].data(), 8, t[r].data(), 12, plain_medium(), r);
        s.commit();
    }
};

}  // namespace

TEST(CellCache, HoldsItsCubeAndEveryTriangleMeetingItsBall) {
    Scenery sc;
    std::mt19937_64 rng(5);
    std::uniform_real_distribution<double> U(0, 1);
    const double side = sc.s.grid().cell_size() / Scene::kCellSplit;
    int used = 0;
    for (int k = 0; k < 3000; ++k) {
        const Vec3 p(-1.05 + 2.1 * U(rng), -1.05 + 2.1 * U(rng), -2.05 + 2.1 * U(rng));
        const TriangleCache& c = sc.s.cell_cache(p);
        if (c.radius() == 0) continue;  // crowded: the caller asks Embree
        ++used;
        // Exactly the grid gather's cache about its centre: the same
        // triangles in the same order, hence the same planes (the cube's
        // gather goes through its cell's candidates instead of the cells).
        TriangleCache same;
        ASSERT_TRUE(sc.s.gather_triangles(c.center(), c.radius(), Scene::kCellMaxTriangles, same));
        ASSERT_EQ(c.size(), same.size());
        for (size_t i = 0; i < c.size(); ++i) {
            EXPECT_EQ(c.triangles()[i].region, same.triangles()[i].region);
            EXPECT_EQ(c.triangles()[i].prim, same.triangles()[i].prim);
            EXPECT_EQ(c.triangles()[i].plane, same.triangles()[i].plane);
        }
        ASSERT_EQ(c.plane_count(), same.plane_count());
        for (size_t i = 0; i < c.plane_count(); ++i) {
            EXPECT_EQ(c.planes()[i].off, same.planes()[i].off);
            EXPECT_EQ(c.planes()[i].margin, same.planes()[i].margin);
        }
        EXPECT_NEAR(c.radius(), side, 1e-12);
        // The ball holds the whole cube around p (half-diagonal 0.87 side).
        EXPECT_LT(length(p - c.center()), 0.8661 * side);
        // The same cache for another point of the same cube.
        const Vec3 q = c.center() + (p - c.center()) * 0.5;
        EXPECT_EQ(&sc.s.cell_cache(q), &c);
        // The same triangles as the grid gather about its centre (itself
        // checked against brute force in test_triangle_cache).
        TriangleCache ref;
        ASSERT_TRUE(sc.s.gather_triangles(c.center(), c.radius(), 1 << 20, ref));
        std::set<std::pair<uint32_t, uint32_t>> got, want;
        for (const auto& t : c.triangles()) got.emplace(t.region, t.prim);
        for (const auto& t : ref.triangles()) want.emplace(t.region, t.prim);
        EXPECT_EQ(got, want) << "cube at " << c.center().x << " " << c.center().y << " " << c.center().z;
    }
    EXPECT_GT(used, 2000);
}

TEST(CellCache, SameCrossingsAsFullQuery) {
    Scenery sc;
    std::mt19937_64 rng(6);
    std::uniform_real_distribution<double> U(0, 1);
    const double side = sc.s.grid().cell_size() / Scene::kCellSplit;
    std::vector<Hit> full, cached;
    int covered = 0, crossed = 0;
    for (int k = 0; k < 20000; ++k) {
        // Points near the faces (within a step of the planes z = 0, -1, -2).
        const double z = -double(rng() % 3) + 0.1 * side * (2 * U(rng) - 1);
        const Vec3 o(-1.02 + 2.04 * U(rng), -1.02 + 2.04 * U(rng), z);
        const double zz = 2 * U(rng) - 1, ph = 2 * kPi * U(rng);
        const Vec3 d(std::sqrt(1 - zz * zz) * std::cos(ph), std::sqrt(1 - zz * zz) * std::sin(ph), zz);
        const double L = 0.2 * side * U(rng), back = 4e-7 * (max_abs_component(o) + 1e-3 * sc.s.extent());
        const TriangleCache& c = sc.s.cell_cache(o);
        if (!c.covers(o - d * back, o + d * L)) continue;
        ++covered;
        sc.s.intersect_all(o, d, -back, L, full);
        c.intersect(o, d, -back, L, cached);
        // Embree's float ambiguities (grazing hits, crossings at an edge where
        // either triangle may be listed) are left out.
        bool ambiguous = false;
        for (const auto* h : {&full, &cached})
            for (size_t i = 0; i < h->size(); ++i)
                ambiguous |= std::fabs((*h)[i].cos_dn) < 1e-2 || (i > 0 && (*h)[i].t - (*h)[i - 1].t < 1e-6);
        if (ambiguous) continue;
        ASSERT_EQ(full.size(), cached.size()) << "segment " << k;
        for (size_t i = 0; i < full.size(); ++i) {
            EXPECT_EQ(full[i].region, cached[i].region) << "segment " << k;
            EXPECT_EQ(full[i].prim, cached[i].prim) << "segment " << k;
            EXPECT_EQ(full[i].t, cached[i].t) << "segment " << k;  // the same double plane refinement
            EXPECT_EQ(full[i].cos_dn, cached[i].cos_dn) << "segment " << k;
        }
        crossed += !full.empty();
    }
    EXPECT_GT(covered, 10000);
    EXPECT_GT(crossed, 1000);
}
