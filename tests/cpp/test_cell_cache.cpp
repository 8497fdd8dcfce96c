// The scene's per-cube triangle caches (Scene::cell_cache, issue 11): the
// cache of the cube around a point holds the triangles that meet its ball
// (the grid gather's), the ball holds the cube, two points of one
// cube share one cache, and a step inside the ball gets the crossings of the
// full Embree query.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
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
        TriangleCacheBuilder same;
        ASSERT_TRUE(sc.s.gather_triangles(c.center(), c.radius(), Scene::kCellMaxTriangles, same));
        ASSERT_EQ(c.size(), same.size());
        for (size_t i = 0; i < c.size(); ++i) {
            const TriangleCache::Triangle& t = c.triangles()[i];
            EXPECT_EQ(t.id, same.triangles()[i].id);
            // The id names the scene's triangle of that region and primitive.
            EXPECT_EQ(t.region, sc.s.grid().region_of(t.id));
            EXPECT_EQ(t.prim, sc.s.grid().prim_of(t.id, t.region));
            EXPECT_EQ(c.triangles()[i].region, same.triangles()[i].region);
            EXPECT_EQ(c.triangles()[i].prim, same.triangles()[i].prim);
            EXPECT_EQ(c.triangles()[i].plane, same.triangles()[i].plane);
        }
        ASSERT_EQ(c.plane_count(), same.plane_count());
        for (size_t i = 0; i < c.plane_count(); ++i) {
            EXPECT_EQ(c.planes()[i].off, same.planes()[i].off);
            EXPECT_EQ(c.planes()[i].margin, same.planes()[i].margin);
        }
        // One side; an empty cube's ball may be wider (WidenedEmptyBallMeetsNoTriangle).
        if (c.size() > 0) EXPECT_NEAR(c.radius(), side, 1e-12);
        EXPECT_GT(c.radius(), side * (1 - 1e-12));
        // The ball holds the whole cube around p (half-diagonal 0.87 side).
        EXPECT_LT(length(p - c.center()), 0.8661 * side);
        // The same cache for another point of the same cube, and the lookup
        // alone finds it built.
        const Vec3 q = c.center() + (p - c.center()) * 0.5;
        EXPECT_EQ(&sc.s.cell_cache(q), &c);
        EXPECT_EQ(sc.s.built_cell_cache(q), &c);
        // A frozen cache starts a cache line, and its planes follow it.
        EXPECT_EQ(reinterpret_cast<uintptr_t>(&c) % TriangleCache::kFrozenAlign, 0u);
        if (c.plane_count() > 0)
            EXPECT_EQ(reinterpret_cast<const char*>(&c.planes()[0]),
                      reinterpret_cast<const char*>(&c) + sizeof(TriangleCache));
        // The same triangles as the grid gather about its centre (itself
        // checked against brute force in test_triangle_cache).
        TriangleCacheBuilder ref;
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
        c.intersect(sc.s, o, d, -back, L, cached);
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

// An empty cube's ball is widened to the widest of Scene::kEmptyWiden that no
// triangle meets (cell_cache): a strict bound, checked at far coordinates
// (1e6, where a float vertex is a multiple of 1/16) next to a thin sliver box
// one float ulp (1/16) thick, whose narrow faces are slivers ~800 times
// longer than wide. Every widened ball lies strictly nearer its centre than
// every triangle (Embree's closest-point query, a separate code path), and
// segments inside it -- random ones and ones aimed at the sliver -- cross
// nothing in Embree's full query. A ball one step too wide fails here: many
// widened cubes lie within a few sides of the sliver.
TEST(CellCache, WidenedEmptyBallMeetsNoTriangle) {
    const float o = 1e6f;
    Scene s{1.0, 1.0};
    std::vector<float> v[2];
    std::vector<uint32_t> t[2];
    box(o, o, o, o + 64, o + 64, o + 64, v[0], t[0]);
    box(o + 20, o + 8, o + 8, o + 20.0625f, o + 56, o + 56, v[1], t[1]);
    s.add_region("outer", v[0].data(), 8, t[0].data(), 12, plain_medium(), 0);
    s.add_region("sliver", v[1].data(), 8, t[1].data(), 12, plain_medium(), 1);
    s.commit();
    const double side = s.grid().cell_size() / Scene::kCellSplit;
    std::mt19937_64 rng(9);
    std::uniform_real_distribution<double> U(0, 1);
    auto in_ball = [&](const Vec3& c, double r) {  // a uniform point strictly inside the ball (c, r)
        while (true) {
            const Vec3 q(2 * U(rng) - 1, 2 * U(rng) - 1, 2 * U(rng) - 1);
            if (dot(q, q) < 1) return c + q * (r * (1 - 1e-12));
        }
    };
    std::vector<Hit> hits;
    int widened = 0, near_sliver = 0;
    for (int k = 0; k < 4000; ++k) {
        const Vec3 p(o + 64 * U(rng), o + 64 * U(rng), o + 64 * U(rng));
        const TriangleCache& c = s.cell_cache(p);
        if (c.radius() == 0 || c.size() > 0) continue;
        const double r = c.radius();
        // One side, or a wider radius that the gather confirms empty.
        bool listed = std::fabs(r - side) < 1e-9 * side;
        for (const Float w : Scene::kEmptyWiden) listed |= std::fabs(r - w * side) < 1e-9 * side;
        ASSERT_TRUE(listed) << r / side;
        if (r < 1.5 * side) continue;
        ++widened;
        const double dist = s.distance_to_surface(c.center(), 100 * side);
        ASSERT_GT(dist, r) << "cube at " << c.center().x - o << " " << c.center().y - o << " " << c.center().z - o;
        near_sliver += dist < r + side;
        for (int j = 0; j < 8; ++j) {
            const Vec3 a = in_ball(c.center(), r), b = in_ball(c.center(), r);
            const double L = length(b - a);
            if (!(L > 0)) continue;
            s.intersect_all(a, (b - a) * (1 / L), 0, L, hits);
            ASSERT_TRUE(hits.empty()) << "segment in a widened ball crosses a triangle";
        }
        // Across the whole ball along x, through the sliver's side.
        const Vec3 dx(1, 0, 0), start = c.center() - dx * (r * (1 - 1e-12));
        s.intersect_all(start, dx, 0, 2 * r * (1 - 1e-12), hits);
        ASSERT_TRUE(hits.empty());
    }
    EXPECT_GT(widened, 100);
    EXPECT_GT(near_sliver, 10);  // the test has teeth: these balls end within a side of a triangle
}

// The store's budget (Scene::set_cache_store_cap_bytes): a cube built before
// the store filled keeps its cache; a cube not built by then gets one that
// covers nothing (the caller asks Embree), and the store stops growing.
TEST(CellCache, StoreStopsGrowingAtItsBudget) {
    Scenery sc;
    EXPECT_EQ(sc.s.cache_store_cap_bytes(), Scene::kDefaultStoreCapBytes);
    std::mt19937_64 rng(11);
    std::uniform_real_distribution<double> U(0, 1);
    auto point = [&] { return Vec3(-1.05 + 2.1 * U(rng), -1.05 + 2.1 * U(rng), -2.05 + 2.1 * U(rng)); };
    std::vector<Vec3> early;
    std::vector<const TriangleCache*> early_cache;
    for (int k = 0; k < 200; ++k) {
        early.push_back(point());
        early_cache.push_back(&sc.s.cell_cache(early.back()));
    }
    const size_t bytes = sc.s.cache_store_bytes();
    ASSERT_GT(bytes, 0u);
    sc.s.set_cache_store_cap_bytes(bytes);  // full from now on
    int refused = 0;
    for (int k = 0; k < 3000; ++k) {
        const Vec3 p = point();
        const TriangleCache& c = sc.s.cell_cache(p);
        if (c.radius() == 0 && c.size() == 0) ++refused;
    }
    EXPECT_GT(refused, 500);  // most cubes were not built among the first 200 points'
    EXPECT_EQ(sc.s.cache_store_bytes(), bytes);
    for (size_t k = 0; k < early.size(); ++k) EXPECT_EQ(&sc.s.cell_cache(early[k]), early_cache[k]);

    Scenery none;
    none.s.set_cache_store_cap_bytes(0);
    for (int k = 0; k < 100; ++k) {
        const TriangleCache& c = none.s.cell_cache(point());
        EXPECT_EQ(c.radius(), 0);
        EXPECT_EQ(c.size(), 0u);
    }
    EXPECT_EQ(none.s.cache_store_bytes(), 0u);
}

// The store grows by small chunks while it is small (a small scene's store
// stays small) and by huge pages once it holds one (CellCacheStore::block).
TEST(CellCache, StoreGrowsBySmallChunksThenByHugePages) {
    Scenery sc;
    const double side = sc.s.grid().cell_size() / Scene::kCellSplit;
    size_t last = 0, small_steps = 0, huge_steps = 0;
    // Every cube's centre, one after the other: ~27k cubes.
    for (double z = -2.05 + side / 2; z < 0.05; z += side)
        for (double y = -1.05 + side / 2; y < 1.05; y += side)
            for (double x = -1.05 + side / 2; x < 1.05; x += side) {
                sc.s.cell_cache(Vec3(x, y, z));
                const size_t now = sc.s.cache_store_bytes();
                if (now == last) continue;
                if (last < CellCacheStore::kHugePage) {
                    EXPECT_EQ(now - last, CellCacheStore::kSmallChunk) << "at " << last << " bytes";
                    ++small_steps;
                } else {
                    EXPECT_EQ(now - last, CellCacheStore::kHugePage) << "at " << last << " bytes";
                    ++huge_steps;
                }
                last = now;
            }
    EXPECT_EQ(small_steps, CellCacheStore::kHugePage / CellCacheStore::kSmallChunk);
    EXPECT_GE(huge_steps, 1u);  // the test has teeth: the store grew past a huge page
}
