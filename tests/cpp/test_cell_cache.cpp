// The scene's per-cube triangle caches (Scene::cell_cache, issue 11): the
// cache of the cube around a point holds every triangle that meets its ball
// (checked against brute force), the ball holds the cube, two points of one
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

Medium tissue() {
    Medium m;
    m.mua = 1;
    m.mus = 10;
    return m;
}

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
        for (int r = 0; r < 3; ++r) s.add_region(names[r], v[r].data(), 8, t[r].data(), 12, tissue(), r);
        s.commit();
    }
};

double point_triangle_distance(const Vec3& p, const Vec3& a, const Vec3& b, const Vec3& c) {
    const Vec3 n = normalize(cross(b - a, c - a));
    const Vec3 q = p - n * dot(p - a, n);
    const double e0 = dot(cross(b - a, q - a), n), e1 = dot(cross(c - b, q - b), n), e2 = dot(cross(a - c, q - c), n);
    if (e0 >= 0 && e1 >= 0 && e2 >= 0) return std::fabs(dot(p - a, n));
    auto seg = [&](const Vec3& u, const Vec3& w) {
        const double s = std::clamp(dot(p - u, w - u) / dot(w - u, w - u), 0.0, 1.0);
        return length(p - (u + (w - u) * s));
    };
    return std::min({seg(a, b), seg(b, c), seg(c, a)});
}

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
        EXPECT_NEAR(c.radius(), side, 1e-12);
        // The ball holds the whole cube around p (half-diagonal 0.87 side).
        EXPECT_LT(length(p - c.center()), 0.8661 * side);
        // The same cache for another point of the same cube.
        const Vec3 q = c.center() + (p - c.center()) * 0.5;
        EXPECT_EQ(&sc.s.cell_cache(q), &c);
        std::set<std::pair<uint32_t, uint32_t>> got;
        for (const auto& t : c.triangles()) got.emplace(t.region, t.prim);
        for (uint32_t r = 0; r < 3; ++r)
            for (uint32_t i = 0; i < 12; ++i) {
                Vec3 P[3];
                for (int j = 0; j < 3; ++j) {
                    const float* x = &sc.v[r][3 * size_t(sc.t[r][3 * i + uint32_t(j)])];
                    P[j] = Vec3(x[0], x[1], x[2]);
                }
                if (point_triangle_distance(c.center(), P[0], P[1], P[2]) <= c.radius())
                    EXPECT_TRUE(got.count({r, i})) << "cube at " << c.center().x << " misses " << r << "/" << i;
            }
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
