// EntryPlanes (native/entry_planes.h) may answer "this ray enters nothing"
// only where Embree's closest-hit query from the ambient finds nothing: exit
// rays from random points of a box's faces (near edges and corners too, and
// along the axes), in a convex scene and next to a second box, must never get
// a "none ahead" that the query contradicts; in the convex scene most exits
// must get it (else the shortcut would never pay).
#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <vector>

#include "entry_planes.h"
#include "scene.h"
#include "test_meshes.h"

using namespace ep;

namespace {

// Counts of exits from the box [-1, 1]^2 x [-1, 0] that none_ahead answered,
// after checking each answer against intersect_first.
struct Tally {
    int exits = 0, answered = 0;
};

Tally check_exits(const Scene& s, const EntryPlanes& planes, unsigned seed) {
    std::mt19937_64 gen(seed);
    std::uniform_real_distribution<double> u(0, 1);
    Tally tally;
    for (int k = 0; k < 20000; ++k) {
        // A point on a random face (axis a, side +-1); coordinates near the
        // edges (within 1e-9 .. 1e-2) a quarter of the time.
        const int axis = int(u(gen) * 3), side = u(gen) < 0.5 ? -1 : 1;
        const double lo[3] = {-1, -1, -1}, hi[3] = {1, 1, 0};
        double p[3], n[3] = {0, 0, 0};
        for (int i = 0; i < 3; ++i) {
            double f = u(gen);
            if (u(gen) < 0.25) f = u(gen) < 0.5 ? std::pow(10.0, -9 + 7 * u(gen)) : 1 - std::pow(10.0, -9 + 7 * u(gen));
            p[i] = lo[i] + f * (hi[i] - lo[i]);
        }
        p[axis] = side > 0 ? hi[axis] : lo[axis];
        n[axis] = side;
        // An outward direction: along the normal every eighth time, else random.
        Vec3 d(n[0], n[1], n[2]);
        if (k % 8 != 0) {
            Vec3 r(u(gen) - 0.5, u(gen) - 0.5, u(gen) - 0.5);
            r = r / length(r);
            if (dot(r, d) < 0) r = -r;
            d = r;
        }
        const Vec3 o(p[0], p[1], p[2]);
        const double back = 4e-7 * (max_abs_component(o) + 1e-3 * s.extent());  // transport's ray_offset
        ++tally.exits;
        if (!planes.none_ahead(o, d, back)) continue;
        ++tally.answered;
        Hit h;
        const Scene::FirstHit f = s.intersect_first(o, d, -back, kInf, 0, h);
        EXPECT_FALSE(f.found) << "o " << o.x << " " << o.y << " " << o.z << " d " << d.x << " " << d.y << " " << d.z;
    }
    return tally;
}

}  // namespace

TEST(EntryPlanes, ConvexBoxExitsNeedNoQuery) {
    Scene s(1.0, 1.0);
    std::vector<float> v;
    std::vector<uint32_t> t;
    box(-1, -1, -1, 1, 1, 0, v, t);
    s.add_region("box", v.data(), 8, t.data(), 12, plain_medium(), 0);
    s.commit();
    EntryPlanes planes;
    planes.build(s);
    const Tally tally = check_exits(s, planes, 1);
    // A quarter of the points lie within 1e-2 of an edge, some within the
    // margin (1e-5): those aimed back over the edge are left to Embree.
    EXPECT_GT(tally.answered, tally.exits * 3 / 4);
}

TEST(EntryPlanes, NeighbourBoxIsNeverMissed) {
    Scene s(1.0, 1.0);
    std::vector<float> v, v2;
    std::vector<uint32_t> t, t2;
    box(-1, -1, -1, 1, 1, 0, v, t);
    s.add_region("box", v.data(), 8, t.data(), 12, plain_medium(), 0);
    box(1.5, -1, -1, 2.5, 1, 0, v2, t2);  // beside the +x face
    s.add_region("neighbour", v2.data(), 8, t2.data(), 12, plain_medium(), 0);
    s.commit();
    EntryPlanes planes;
    planes.build(s);
    const Tally tally = check_exits(s, planes, 2);
    EXPECT_GT(tally.answered, 0);
    // A ray from the +x face straight at the neighbour must go to Embree.
    EXPECT_FALSE(planes.none_ahead(Vec3(1, 0, -0.5), Vec3(1, 0, 0), 1e-6));
}

TEST(EntryPlanes, LargeScenesAreLeftToEmbree) {
    Scene s(1.0, 1.0);
    std::vector<std::vector<float>> vs(6);
    std::vector<std::vector<uint32_t>> ts(6);
    for (int k = 0; k < 6; ++k) {  // 72 triangles > kMaxTriangles
        box(-1, -1, -1 - 2 * k, 1, 1, -2 * k, vs[size_t(k)], ts[size_t(k)]);
        s.add_region("box" + std::to_string(k), vs[size_t(k)].data(), 8, ts[size_t(k)].data(), 12, plain_medium(), 0);
    }
    s.commit();
    EntryPlanes planes;
    planes.build(s);
    EXPECT_FALSE(planes.none_ahead(Vec3(0, 0, 0), Vec3(0, 0, 1), 1e-6));
}
