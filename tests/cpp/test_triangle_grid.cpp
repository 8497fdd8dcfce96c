// The triangle grid's compact listings and the gathers' per-triangle record
// (issue 11): a listing's sphere is float (centre rounded to float, reach
// rounded up) and still bounds its triangle; a listing names its region and
// triangle through the scene-wide id; a gather keeps the mesh's float
// vertices exactly, though the record holds vertices 1 and 2 as float.
#include <gtest/gtest.h>

#include <cmath>
#include <vector>

#include "scene.h"
#include "test_meshes.h"
#include "triangle_cache.h"
#include "triangle_grid.h"

using namespace ep;

namespace {

// Every listing of the grid, as visited over the whole grid.
std::vector<TriangleGrid::Ref> all_listings(const TriangleGrid& g) {
    std::vector<TriangleGrid::Ref> out;
    g.visit(Vec3(-1e30, -1e30, -1e30), Vec3(1e30, 1e30, 1e30), [&](const TriangleGrid::Ref& r) {
        out.push_back(r);
        return true;
    });
    return out;
}

}  // namespace

TEST(TriangleGrid, ListingSphereIsFloatAndBoundsItsTriangle) {
    // Far from the origin, where float spacing is 1/16: the centroid
    // (1000000 + 1/3, 1/3, 0) rounds to (1000000.3125, 0.33333334, 0).
    const std::vector<std::vector<float>> v = {{1000000.f, 0.f, 0.f, 1000001.f, 0.f, 0.f, 1000000.f, 1.f, 0.f}};
    const std::vector<std::vector<uint32_t>> t = {{0, 1, 2}};
    TriangleGrid g;
    g.build(v, t);
    const std::vector<TriangleGrid::Ref> refs = all_listings(g);
    ASSERT_FALSE(refs.empty());
    for (const TriangleGrid::Ref& r : refs) {
        EXPECT_EQ(r.id, 0u);
        EXPECT_EQ(r.c[0], 1000000.3125f);
        EXPECT_EQ(r.c[1], 0.33333334f);
        EXPECT_EQ(r.c[2], 0.f);
        // The farthest vertex, (1000001, 0, 0), lies sqrt(0.6875^2 +
        // 0.33333334^2) = 0.7640467 from that centre; the reach covers every
        // vertex, padded by the grid's margin (1e-9 of the coordinates: 1e-3).
        const Float far = length(Vec3(1000001.0, 0, 0) - r.centre());
        EXPECT_NEAR(far, 0.7640467, 1e-7);
        for (int k = 0; k < 3; ++k)
            EXPECT_GE(Float(r.reach), length(Vec3(v[0][3 * k], v[0][3 * k + 1], v[0][3 * k + 2]) - r.centre()));
        EXPECT_NEAR(Float(r.reach), 0.7650467, 1e-6);
    }
}

TEST(TriangleGrid, IdNamesRegionAndTriangle) {
    // Regions of 2, 0 and 3 triangles: ids 0-1 are region 0, 2-4 region 2.
    std::vector<std::vector<float>> v(3);
    std::vector<std::vector<uint32_t>> t(3);
    v[0] = {0, 0, 0, 1, 0, 0, 0, 1, 0, 1, 1, 0};
    t[0] = {0, 1, 2, 1, 3, 2};
    v[2] = {0, 0, 1, 1, 0, 1, 0, 1, 1, 1, 1, 1};
    t[2] = {0, 1, 2, 1, 3, 2, 0, 3, 1};
    TriangleGrid g;
    g.build(v, t);
    ASSERT_EQ(g.triangle_count(), 5u);
    const uint32_t region[5] = {0, 0, 2, 2, 2}, prim[5] = {0, 1, 0, 1, 2};
    for (uint32_t id = 0; id < 5; ++id) {
        EXPECT_EQ(g.region_of(id), region[id]) << id;
        EXPECT_EQ(g.prim_of(id, region[id]), prim[id]) << id;
        for (uint32_t r = 0; r < 3; ++r) EXPECT_EQ(g.in_region(id, r), r == region[id]) << id << " " << r;
    }
}

TEST(TriangleGrid, GatherKeepsTheMeshVerticesExactly) {
    // One box with vertices that are not short binary fractions: a gather
    // about a corner returns its triangles with the float vertices exactly.
    std::vector<float> v;
    std::vector<uint32_t> t;
    box(0.1f, 0.2f, 0.3f, 0.7f, 0.9f, 1.3f, v, t);
    Scene s(1.0, 1.0);
    s.add_region("box", v.data(), v.size() / 3, t.data(), t.size() / 3, plain_medium(), 0);
    s.commit();
    TriangleCacheBuilder cache;
    ASSERT_TRUE(s.gather_triangles(Vec3(0.1, 0.2, 0.3), 0.05, 64, cache));
    ASSERT_GT(cache.size(), 0u);
    const Float xs[2] = {0.1f, 0.7f}, ys[2] = {0.2f, 0.9f}, zs[2] = {0.3f, 1.3f};
    auto is_corner = [&](const Vec3& p) {
        return (p.x == xs[0] || p.x == xs[1]) && (p.y == ys[0] || p.y == ys[1]) && (p.z == zs[0] || p.z == zs[1]);
    };
    for (const TriangleCache::Triangle& cached : cache.triangles()) {
        // A cached triangle names the scene's triangle (one region: id = prim).
        EXPECT_EQ(cached.id, cached.prim);
        const Scene::EdgePlanes& tri = s.triangle(cached.id);
        EXPECT_TRUE(is_corner(tri.p0));
        EXPECT_TRUE(is_corner(tri.v1()));
        EXPECT_TRUE(is_corner(tri.v2()));
        // The same vertices, in the same order, as the mesh lists them.
        const uint32_t* k = &t[3 * size_t(cached.prim)];
        EXPECT_EQ(tri.p0.x, Float(v[3 * k[0]]));
        EXPECT_EQ(tri.v1().x, Float(v[3 * k[1]]));
        EXPECT_EQ(tri.v1().y, Float(v[3 * k[1] + 1]));
        EXPECT_EQ(tri.v2().z, Float(v[3 * k[2] + 2]));
    }
}
