// ep::first_surface / first_surfaces (native/surface_hits.h): the surface a ray
// from the ambient medium sees, against hand-computed geometry.
#include <gtest/gtest.h>

#include <array>
#include <vector>

#include "scene.h"
#include "surface_hits.h"

using namespace ep;

namespace {

// Axis-aligned box as 8 corners and 12 outward counter-clockwise triangles.
struct BoxMesh {
    std::vector<float> v;
    std::vector<uint32_t> t;
    BoxMesh(std::array<float, 3> lo, std::array<float, 3> hi) {
        for (int k = 0; k < 8; ++k)
            for (int a = 0; a < 3; ++a) v.push_back((k >> a) & 1 ? hi[a] : lo[a]);
        const uint32_t faces[6][4] = {{0, 2, 3, 1}, {4, 5, 7, 6}, {0, 1, 5, 4},
                                      {2, 6, 7, 3}, {0, 4, 6, 2}, {1, 3, 7, 5}};
        for (auto& f : faces) t.insert(t.end(), {f[0], f[1], f[2], f[0], f[2], f[3]});
    }
};

Medium plain() {
    Medium m;
    m.mua = 1;
    m.mus = 10;
    m.g = 0;
    m.n = 1;
    return m;
}

void add(Scene& s, const char* name, std::array<float, 3> lo, std::array<float, 3> hi, int priority) {
    BoxMesh b(lo, hi);
    s.add_region(name, b.v.data(), 8, b.t.data(), 12, plain(), priority);
}

}  // namespace

TEST(SurfaceHits, TouchingLayersShowTheTopLayer) {
    Scene s(1.0, 1.0);
    add(s, "top", {-5, -5, -1}, {5, 5, 0}, 0);
    add(s, "bottom", {-5, -5, -3}, {5, 5, -1}, 0);
    s.commit();
    const SurfaceHit h = first_surface(s, Vec3(0.3, -0.2, 2), Vec3(0, 0, -2), 0, kInf);
    EXPECT_NEAR(h.t, 2.0, 1e-12);
    EXPECT_EQ(h.region, 0);
    EXPECT_NEAR(h.normal.z, 1.0, 1e-12);
    // Oblique ray: t = 2 / cos(theta).
    const Vec3 d = normalize(Vec3(1, 0, -2));
    const SurfaceHit o = first_surface(s, Vec3(0, 0, 2), d, 0, kInf);
    EXPECT_NEAR(o.t, 2.0 / -d.z, 1e-9);
    // From below the stack the bottom layer is seen, through its lower face.
    const SurfaceHit b = first_surface(s, Vec3(0, 0, -10), Vec3(0, 0, 1), 0, kInf);
    EXPECT_EQ(b.region, 1);
    EXPECT_NEAR(b.t, 7.0, 1e-12);
    EXPECT_NEAR(b.normal.z, -1.0, 1e-12);
}

TEST(SurfaceHits, PriorityPolypAndMissesAndInsideStarts) {
    Scene s(1.0, 1.0);
    add(s, "wall", {-5, -5, -1}, {5, 5, 0}, 0);
    add(s, "polyp", {-0.5f, -0.5f, -0.25f}, {0.5f, 0.5f, 0.5f}, 1);
    s.commit();
    const SurfaceHit p = first_surface(s, Vec3(0, 0, 2), Vec3(0, 0, -1), 0, kInf);
    EXPECT_EQ(p.region, 1);
    EXPECT_NEAR(p.t, 1.5, 1e-12);
    EXPECT_EQ(first_surface(s, Vec3(0.8, 0, 2), Vec3(0, 0, -1), 0, kInf).region, 0);
    EXPECT_EQ(first_surface(s, Vec3(0, 0, 2), Vec3(0, 0, 1), 0, kInf).region, kNoSurface);
    EXPECT_EQ(first_surface(s, Vec3(0, 0, 2), Vec3(0, 0, -1), 0, 1.0).region, kNoSurface);  // tfar stops short
    EXPECT_EQ(first_surface(s, Vec3(2, 0, -0.5), Vec3(0, 0, 1), 0, kInf).region, kStartsInside);
}

TEST(SurfaceHits, BatchIsIndependentOfThreads) {
    Scene s(1.0, 1.0);
    add(s, "wall", {-5, -5, -1}, {5, 5, 0}, 0);
    add(s, "polyp", {-0.5f, -0.5f, -0.25f}, {0.5f, 0.5f, 0.5f}, 1);
    s.commit();
    const size_t n = 2000;
    std::vector<double> o, d;
    for (size_t k = 0; k < n; ++k) {
        o.insert(o.end(), {0.0, 0.0, 3.0});
        const double a = -1.0 + 2.0 * double(k) / double(n);
        d.insert(d.end(), {a, 0.3 * a, -1.0});
    }
    std::vector<double> t1(n), t2(n), n1(3 * n), n2(3 * n);
    std::vector<int32_t> r1(n), r2(n), p1(n), p2(n);
    first_surfaces(s, o.data(), d.data(), nullptr, n, 0, 1, t1.data(), r1.data(), p1.data(), n1.data());
    first_surfaces(s, o.data(), d.data(), nullptr, n, 0, 2, t2.data(), r2.data(), p2.data(), n2.data());
    EXPECT_EQ(t1, t2);
    EXPECT_EQ(r1, r2);
    EXPECT_EQ(n1, n2);
    // A ray through the polyp's top face at z = 0.5: t = 2.5 |d| / |d_z|.
    const size_t mid = n / 2;
    EXPECT_EQ(r1[mid], 1);
    EXPECT_NEAR(t1[mid], 2.5, 1e-9);
}
