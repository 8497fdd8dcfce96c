// Unit tests of the engine's building blocks against analytic references.
#include <gtest/gtest.h>

#include "test_meshes.h"

#include <algorithm>
#include <cmath>
#include <set>
#include <vector>

#include "engine.h"
#include "fresnel.h"
#include "halton.h"
#include "mesh_check.h"
#include "phase.h"
#include "rng.h"
#include "scene.h"
#include "source.h"

using namespace ep;

namespace {

// The oracle's unpolarised Fresnel form (oracles §4), independent of the
// engine's cosine form: R = 1/2 [sin^2(i-t)/sin^2(i+t) + tan^2(i-t)/tan^2(i+t)].
double fresnel_sin_tan(double theta_i, double n1, double n2) {
    const double st = n1 / n2 * std::sin(theta_i);
    if (st >= 1) return 1;
    const double tt = std::asin(st);
    const double a = std::sin(theta_i - tt) / std::sin(theta_i + tt);
    const double b = std::tan(theta_i - tt) / std::tan(theta_i + tt);
    return 0.5 * (a * a + b * b);
}

}  // namespace

TEST(Fresnel, MatchesSinTanFormAndNormalIncidence) {
    const double n1 = 1.0, n2 = 1.5;
    double ct;
    EXPECT_NEAR(fresnel_dielectric(1.0, n1, n2, &ct), std::pow((n1 - n2) / (n1 + n2), 2), 1e-15);
    for (double deg : {1.0, 10.0, 30.0, 45.0, 60.0, 75.0, 85.0, 89.0}) {
        const double th = deg * kPi / 180;
        EXPECT_NEAR(fresnel_dielectric(std::cos(th), n1, n2, &ct), fresnel_sin_tan(th, n1, n2), 1e-12) << deg;
        // Snell: n1 sin i = n2 sin t.
        EXPECT_NEAR(n1 * std::sin(th), n2 * std::sqrt(1 - ct * ct), 1e-12);
    }
    EXPECT_EQ(fresnel_dielectric(0.0, n1, n2, &ct), 1.0);  // grazing
}

TEST(Fresnel, TotalInternalReflectionBeyondCriticalAngle) {
    const double n1 = 1.4, n2 = 1.0, crit = std::asin(n2 / n1);
    double ct;
    EXPECT_EQ(fresnel_dielectric(std::cos(crit + 1e-6), n1, n2, &ct), 1.0);
    EXPECT_EQ(ct, 0.0);
    EXPECT_LT(fresnel_dielectric(std::cos(crit - 1e-3), n1, n2, &ct), 1.0);
    EXPECT_NEAR(fresnel_dielectric(std::cos(crit - 1e-3), n1, n2, &ct), fresnel_sin_tan(crit - 1e-3, n1, n2), 1e-10);
}

TEST(Fresnel, RefractObeysSnell) {
    const Vec3 n(0, 0, 1);
    const double th = 40 * kPi / 180;
    const Vec3 d(std::sin(th), 0, -std::cos(th));
    double ct;
    fresnel_dielectric(std::cos(th), 1.0, 1.33, &ct);
    const Vec3 t = refract(d, n, 1.0 / 1.33, std::cos(th), ct);
    EXPECT_NEAR(length(t), 1.0, 1e-14);
    EXPECT_NEAR(t.x, std::sin(th) / 1.33, 1e-14);
    EXPECT_LT(t.z, 0);
}

TEST(HenyeyGreenstein, PdfIsNormalisedAndMeanIsG) {
    for (double g : {-0.9, -0.3, 0.0, 0.5, 0.9, 0.99}) {
        const HenyeyGreenstein hg(g);
        // Simpson on cos in [-1, 1] with many nodes: integral of p = 1, of cos p = g.
        const int n = 200000;
        double s0 = 0, s1 = 0, s_sr = 0;
        for (int i = 0; i <= n; ++i) {
            const double c = -1 + 2.0 * i / n;
            const double w = (i == 0 || i == n) ? 1 : (i % 2 ? 4 : 2);
            s0 += w * hg.pdf_cos(c);
            s1 += w * c * hg.pdf_cos(c);
            s_sr += w * 2 * M_PI * hg.pdf(c);  // per steradian: d(omega) = 2 pi d(cos)
        }
        s0 *= 2.0 / n / 3;
        s1 *= 2.0 / n / 3;
        s_sr *= 2.0 / n / 3;
        EXPECT_NEAR(s0, 1.0, 2e-4) << g;
        EXPECT_NEAR(s_sr, 1.0, 2e-4) << g;
        EXPECT_NEAR(s1, g, 2e-4) << g;
    }
}

TEST(HenyeyGreenstein, SamplingInvertsTheCdf) {
    // The HG CDF in closed form: F(c) = (1-g^2)/(2g) [ (1+g^2-2gc)^-1/2 - (1+g)^-1 ].
    for (double g : {-0.8, 0.3, 0.9, 0.9999}) {
        const HenyeyGreenstein hg(g);
        for (double u : {0.01, 0.2, 0.5, 0.8, 0.99}) {
            const double c = hg.sample_cos(u);
            const double F = (1 - g * g) / (2 * g) * (1 / std::sqrt(1 + g * g - 2 * g * c) - 1 / (1 + g));
            EXPECT_NEAR(F, u, 1e-9) << g << " " << u;
        }
    }
    EXPECT_EQ(HenyeyGreenstein(1.0).sample_cos(0.3), 1.0);
    EXPECT_EQ(HenyeyGreenstein(-1.0).sample_cos(0.3), -1.0);
    EXPECT_EQ(HenyeyGreenstein(0.0).sample_cos(0.25), -0.5);
    const Vec3 d(0, 0.6, 0.8);
    const Vec3 r = HenyeyGreenstein(-1.0).sample_p(d, 0.3, 0.6, 0.8);
    EXPECT_EQ(r.y, -0.6);
    EXPECT_EQ(r.z, -0.8);
}

TEST(Rng, StreamsAreDeterministicAndDistinct) {
    Rng a(7, 123), b(7, 123), c(7, 124), d(8, 123);
    std::vector<uint64_t> va, vc, vd;
    for (int i = 0; i < 1000; ++i) {
        const uint64_t x = a.next_u64();
        EXPECT_EQ(x, b.next_u64());
        va.push_back(x);
        vc.push_back(c.next_u64());
        vd.push_back(d.next_u64());
    }
    EXPECT_NE(va, vc);
    EXPECT_NE(va, vd);
    Rng e(1, 2);
    double mean = 0;
    const int n = 1000000;
    for (int i = 0; i < n; ++i) {
        const double u = e.uniform_open_low();
        ASSERT_GT(u, 0.0);
        ASSERT_LE(u, 1.0);
        mean += u;
    }
    mean /= n;
    EXPECT_NEAR(mean, 0.5, 3 * std::sqrt(1.0 / 12 / n) + 1e-12);
}

TEST(Halton, DeterministicUniformAndScrambled) {
    const Halton h(3), h2(3), h3(4);
    for (int dim = 0; dim < Halton::kMaxDimensions; ++dim) {
        // The first b^2 points of a digit-permuted radical inverse are the
        // lattice j / b^2 plus one common offset below 1 / b^2: sorted, every gap
        // is 1 / b^2 (checked on gaps, which rounding cannot push across a cell edge).
        const int b = Halton::base(dim), m = b * b;
        std::vector<double> xs;
        for (int i = 0; i < m; ++i) {
            const double x = h.sample(uint64_t(i), dim);
            ASSERT_GE(x, 0.0);
            ASSERT_LT(x, 1.0);
            EXPECT_EQ(x, h2.sample(uint64_t(i), dim));
            xs.push_back(x);
        }
        std::sort(xs.begin(), xs.end());
        EXPECT_LT(xs.front(), 1.0 / m + 1e-12) << "dim " << dim;
        for (int i = 1; i < m; ++i) EXPECT_NEAR(xs[size_t(i)] - xs[size_t(i) - 1], 1.0 / m, 1e-12) << "dim " << dim;
    }
    int differ = 0;
    for (int i = 1; i < 50; ++i) differ += h.sample(uint64_t(i), 3) != h3.sample(uint64_t(i), 3);
    EXPECT_GT(differ, 0);
    EXPECT_LT(h.sample(uint64_t(1) << 40, 2), 1.0);
    // Far into the sequence indices stay distinct: 2^40 is not 0 in base 2.
    EXPECT_NE(h.sample(uint64_t(1) << 40, 0), h.sample(0, 0));
}

// Base 2 is computed in closed form (a bit reversal); it must equal the
// permuted radical inverse's digit loop bit for bit, for both permutations of
// {0, 1} (seeds whose tables differ in dimension 0) and for indices of every size.
TEST(Halton, BaseTwoEqualsTheDigitLoop) {
    auto digit_loop = [](const Halton& h, uint64_t index) {
        const double p0 = h.sample(0, 0) > 0.5 ? 1.0 : 0.0;  // p[0]: index 0 is all leading zeros
        double inv_bk = 0.5, value = 0.0;
        while (index != 0 && inv_bk > 0x1.0p-53) {
            value += double(index % 2 == 0 ? p0 : 1 - p0) * inv_bk;
            index /= 2;
            inv_bk *= 0.5;
        }
        while (inv_bk > 0x1.0p-53) {
            value += p0 * inv_bk;
            inv_bk *= 0.5;
        }
        return value;
    };
    int swapped = 0;
    for (uint64_t seed = 1; seed <= 8; ++seed) {
        const Halton h(seed);
        swapped += h.sample(0, 0) > 0.5;
        Rng rng(seed, 0);
        for (uint64_t i = 0; i < 3000; ++i) {
            const uint64_t index = i < 1000 ? i : rng.next_u64() >> (rng.next_u64() % 64);
            ASSERT_EQ(h.sample(index, 0), digit_loop(h, index)) << "seed " << seed << " index " << index;
        }
    }
    EXPECT_GT(swapped, 0);  // both permutations were checked
    EXPECT_LT(swapped, 8);
}

// The other bases read their terms from a table; they must equal the
// permuted radical inverse's digit loop bit for bit (the same products, added
// in the same order), for indices of every size.
TEST(Halton, TableEqualsTheDigitLoop) {
    auto digit_loop = [](const std::vector<uint16_t>& p, uint64_t b, uint64_t index) {
        const double inv_b = 1.0 / double(b);
        double inv_bk = inv_b, value = 0.0;
        while (index != 0 && inv_bk > 0x1.0p-53) {
            value += double(p[index % b]) * inv_bk;
            index /= b;
            inv_bk *= inv_b;
        }
        while (inv_bk > 0x1.0p-53) {
            value += double(p[0]) * inv_bk;
            inv_bk *= inv_b;
        }
        return value < 1.0 ? value : 0x1.fffffffffffffp-1;
    };
    for (uint64_t seed = 1; seed <= 4; ++seed) {
        const Halton h(seed);
        Rng rng(seed, 1);
        for (int dim = 1; dim < Halton::kMaxDimensions; ++dim)
            for (uint64_t i = 0; i < 3000; ++i) {
                const uint64_t index = i < 1000 ? i : rng.next_u64() >> (rng.next_u64() % 64);
                ASSERT_EQ(h.sample(index, dim), digit_loop(h.permutation(dim), uint64_t(Halton::base(dim)), index))
                    << "seed " << seed << " dim " << dim << " index " << index;
            }
    }
}

TEST(MeshCheck, RejectsEveryClassOfBadMesh) {
    std::vector<float> v;
    std::vector<uint32_t> t;
    box(0, 0, 0, 1, 1, 1, v, t);
    EXPECT_GT(check_mesh("region 'b'", v.data(), 8, t.data(), 12).signed_volume, 0.999);
    auto expect_error = [&](std::vector<float> vv, std::vector<uint32_t> tt, const std::string& needle) {
        try {
            check_mesh("region 'b'", vv.data(), vv.size() / 3, tt.data(), tt.size() / 3);
            ADD_FAILURE() << "no error for " << needle;
        } catch (const std::invalid_argument& e) {
            EXPECT_NE(std::string(e.what()).find("region 'b'"), std::string::npos) << e.what();
            EXPECT_NE(std::string(e.what()).find(needle), std::string::npos) << e.what();
        }
    };
    auto open = t;
    open.resize(t.size() - 3);
    expect_error(v, open, "open");
    auto flipped = t;
    std::swap(flipped[1], flipped[2]);
    expect_error(v, flipped, "inconsistent");
    auto inward = t;
    for (size_t i = 0; i < inward.size(); i += 3) std::swap(inward[i + 1], inward[i + 2]);
    expect_error(v, inward, "inward");
    auto nan = v;
    nan[4] = std::nanf("");
    expect_error(nan, t, "mesh.vertices[1][1] = nan");
    auto degenerate = t;
    degenerate[2] = degenerate[1];
    expect_error(v, degenerate, "degenerate");
}

TEST(Scene, CollectsCoincidentFacesOfTouchingBoxes) {
    Scene s(1.0, 1.0);
    std::vector<float> v;
    std::vector<uint32_t> t;
    Medium m;
    m.mua = 1;
    m.mus = 1;
    box(-1, -1, -1, 1, 1, 0, v, t);
    s.add_region("top", v.data(), 8, t.data(), 12, m, 0);
    box(-1, -1, -2, 1, 1, -1, v, t);
    s.add_region("bottom", v.data(), 8, t.data(), 12, m, 0);
    s.commit();
    std::vector<Hit> hits;
    s.intersect_all(Vec3(0.1, 0.2, 1), Vec3(0, 0, -1), 0, kInf, hits);
    ASSERT_EQ(hits.size(), 4u);  // enter top, leave top + enter bottom at z=-1, leave bottom
    EXPECT_NEAR(hits[0].t, 1.0, 1e-6);
    EXPECT_LT(hits[0].cos_dn, 0);
    EXPECT_NEAR(hits[1].t, 2.0, 1e-6);
    EXPECT_NEAR(hits[2].t, 2.0, 1e-6);
    EXPECT_NE(hits[1].region, hits[2].region);
    EXPECT_NEAR(hits[3].t, 3.0, 1e-6);
    EXPECT_GT(hits[3].cos_dn, 0);
    EXPECT_NEAR(s.distance_to_surface(Vec3(0, 0, -0.3), 10.0), 0.3, 1e-6);
}

TEST(Engine, BitIdenticalOnOneAndTwoThreadsAndBalanced) {
    Scene s(1.0, 1.0);
    std::vector<float> v;
    std::vector<uint32_t> t;
    Medium m;
    m.mua = 10;
    m.mus = 90;
    m.g = 0.75;
    m.n = 1.4;
    box(-50, -50, -0.02f, 50, 50, 0, v, t);
    s.add_region("slab", v.data(), 8, t.data(), 12, m, 0);
    s.commit();
    Light l;
    l.center = Vec3(0, 0, 1);
    l.axis = Vec3(0, 0, -1);
    const Source src({l});
    RunConfig c;
    c.photons = 20000;
    c.seed = 5;
    c.threads = 1;
    const RunResult a = run(s, src, c, nullptr, nullptr);
    c.threads = 2;
    const RunResult b = run(s, src, c, nullptr, nullptr);
    double sum = 0;
    for (int k = 0; k < kBalanceTallies; ++k) {
        EXPECT_EQ(a.scalar[k].mean, b.scalar[k].mean) << tally_name(k);
        EXPECT_EQ(a.scalar[k].stderr_, b.scalar[k].stderr_) << tally_name(k);
        sum += a.scalar[k].mean;
    }
    EXPECT_NEAR(sum, 1.0, 1e-9);
    EXPECT_EQ(a.records.weight, b.records.weight);
    EXPECT_EQ(a.records.position, b.records.position);
    // Rsp at normal incidence is exact.
    EXPECT_NEAR(a.scalar[kSpecular].mean, std::pow(0.4 / 2.4, 2), 1e-15);
}

// The rig head (issue 9): a cylinder of radius 0.6 reaching 5 behind its front
// face at z = 1, looking down -z, with an aperture of radius 0.1 at the centre.
TEST(RigBody, RayCylinderHitsAgainstHandComputedDistances) {
    RigBody b;
    b.front = Vec3(0, 0, 1);
    b.axis = Vec3(0, 0, -1);
    b.radius = 0.6;
    b.length = 5;
    b.camera = Vec3(0, 0, 1);
    b.camera_radius = 0.1;
    // Straight up the axis from z = 0: the aperture, 1 away.
    BodyHit h = intersect_body(b, Vec3(0, 0, 0), Vec3(0, 0, 1));
    EXPECT_EQ(h.part, BodyPart::kCamera);
    EXPECT_NEAR(h.t, 1.0, 1e-15);
    // Up at x = 0.3: the front face outside the aperture.
    h = intersect_body(b, Vec3(0.3, 0, 0), Vec3(0, 0, 1));
    EXPECT_EQ(h.part, BodyPart::kHead);
    EXPECT_NEAR(h.t, 1.0, 1e-15);
    // Sideways at z = 3 from x = -2: the side wall at x = -0.6, 1.4 away.
    h = intersect_body(b, Vec3(-2, 0, 3), Vec3(1, 0, 0));
    EXPECT_EQ(h.part, BodyPart::kHead);
    EXPECT_NEAR(h.t, 1.4, 1e-12);
    // Down from the back (z = 7): the back face at z = 6, 1 away.
    h = intersect_body(b, Vec3(0, 0, 7), Vec3(0, 0, -1));
    EXPECT_EQ(h.part, BodyPart::kHead);
    EXPECT_NEAR(h.t, 1.0, 1e-15);
    // Misses: beside the cylinder, beyond its back, and a light on the front face emitting forward.
    EXPECT_EQ(intersect_body(b, Vec3(0.7, 0, 0), Vec3(0, 0, 1)).part, BodyPart::kNone);
    EXPECT_EQ(intersect_body(b, Vec3(-2, 0, 6.5), Vec3(1, 0, 0)).part, BodyPart::kNone);
    EXPECT_EQ(intersect_body(b, Vec3(0.35, 0, 1), normalize(Vec3(0.1, 0, -1))).part, BodyPart::kNone);
    // Oblique onto the face at 45 degrees: enters at (0.05, 0, 1) inside the aperture, t = sqrt(2).
    h = intersect_body(b, Vec3(-0.95, 0, 0), normalize(Vec3(1, 0, 1)));
    EXPECT_EQ(h.part, BodyPart::kCamera);
    EXPECT_NEAR(h.t, std::sqrt(2.0), 1e-12);
}
