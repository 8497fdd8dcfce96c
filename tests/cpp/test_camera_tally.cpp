// The camera tally's next event (native/camera_tally.h) against an
// independent computation: the exit point by Fermat's principle (least
// optical path, golden-section search), the solid-angle Jacobian by finite
// differences of the inner direction over the pinhole's position, Fresnel in
// the sine/tangent form of the oracle, and the Henyey-Greenstein density.
#include <gtest/gtest.h>

#include <cmath>
#include <vector>

#include "camera_tally.h"
#include "rng.h"
#include "scene.h"
#include "test_meshes.h"

using namespace ep;

namespace {

constexpr double kPiTest = 3.14159265358979323846;

Medium tissue() {
    Medium m;
    m.mua = 2;
    m.mus = 30;
    m.g = 0.6;
    m.n = 1.4;
    return m;
}

// A slab [-5, 5]^2 x [-1, 0] (top face z = 0), optionally a blocker above it.
std::unique_ptr<Scene> slab(bool blocker) {
    auto s = std::make_unique<Scene>(1.0, 1.0);
    std::vector<float> v;
    std::vector<uint32_t> t;
    box(-5, -5, -1, 5, 5, 0, v, t);
    s->add_region("slab", v.data(), 8, t.data(), 12, tissue(), 0);
    if (blocker) {
        box(-0.5, -0.5, 0.8, 0.5, 0.5, 1.0, v, t);
        s->add_region("blocker", v.data(), 8, t.data(), 12, tissue(), 0);
    }
    s->commit();
    return s;
}

CameraView view_at(const Vec3& c) {
    CameraView v;
    v.position = c;
    v.forward = Vec3(0, 0, -1);
    v.right = Vec3(1, 0, 0);
    v.up = Vec3(0, 1, 0);
    v.tan_x = v.tan_y = 1;
    v.width = v.height = 8;
    v.pixel_solid_angle.assign(64, 0.02);
    v.batches = 2;
    v.packets = 10;
    v.tau_cut = 100;  // no roulette
    v.channels = 1;
    v.table = {1.0};
    v.fluorescent_only = {0};
    v.spectrum_bin = {-1};
    v.spectrum_fluorescent_weight = {0};
    v.spectrum_bins = 0;
    v.check();
    return v;
}

// Exit point on z = 0 from p (z < 0, index n1) to c (z > 0, index n0) by
// least optical path n1 |x - p| + n0 |c - x|: the point lies on the segment
// between the feet of p and c (golden section along it).
Vec3 fermat_exit(const Vec3& p, const Vec3& c, double n1, double n0) {
    const Vec3 a(p.x, p.y, 0), b(c.x, c.y, 0);
    auto path = [&](double s) {
        const Vec3 x = a + (b - a) * s;
        return n1 * length(x - p) + n0 * length(c - x);
    };
    double lo = 0, hi = 1;
    const double r = (std::sqrt(5.0) - 1) / 2;
    for (int i = 0; i < 200; ++i) {
        const double m1 = hi - r * (hi - lo), m2 = lo + r * (hi - lo);
        (path(m1) < path(m2) ? hi : lo) = (path(m1) < path(m2) ? m2 : m1);
    }
    return a + (b - a) * (0.5 * (lo + hi));
}

Vec3 inner_direction(const Vec3& p, const Vec3& c, double n1, double n0) {
    const Vec3 x = fermat_exit(p, c, n1, n0);
    return (x - p) / length(x - p);
}

double fresnel_oracle(double ci, double n1, double n2) {
    const double i = std::acos(ci), t = std::asin(n1 / n2 * std::sin(i));
    if (i < 1e-9) return std::pow((n1 - n2) / (n1 + n2), 2);
    return 0.5 * (std::pow(std::sin(i - t) / std::sin(i + t), 2) + std::pow(std::tan(i - t) / std::tan(i + t), 2));
}

// An event of weight (energy) 1 at 500 nm in the slab (region 0; g 0.6, n 1.4).
CameraEvent slab_event(const Vec3& p, const Vec3& d) {
    CameraEvent e;
    e.p = p;
    e.d = d / length(d);
    e.set = 1;
    e.region = 0;
    e.weight_energy = 1;
    e.lambda_nm = 500;
    e.g = 0.6;
    e.n = 1.4;
    return e;
}

double score_of(const Scene& s, const CameraView& v, const CameraEvent& e) {
    std::vector<Hit> hits;
    CameraScores out;
    next_event(s, v, e, 0.0, hits, out);
    return out.scores.empty() ? 0.0 : out.scores[0].value;
}

}  // namespace

TEST(CameraTally, ScoreMatchesFermatAndFiniteDifferenceJacobian) {
    auto scene = slab(false);
    const Vec3 c(0.4, -0.3, 2.0);
    const CameraView v = view_at(c);
    CameraEvent e = slab_event(Vec3(-0.2, 0.25, -0.07), Vec3(0.3, -0.2, 0.9));
    e.weight_energy = 0.8;
    e.packet = 7;
    const double got = score_of(*scene, v, e);

    const double n1 = 1.4, n0 = 1.0;
    const Vec3 x = fermat_exit(e.p, c, n1, n0);
    const Vec3 w = (x - e.p) / length(x - e.p);
    const Vec3 u = (c - x) / length(c - x);
    // Jacobian: the inner solid angle per area across the ray at the pinhole.
    Vec3 e1 = cross(u, Vec3(0, 0, 1));
    e1 = e1 / length(e1);
    const Vec3 e2 = cross(u, e1);
    const double h = 1e-4;
    const Vec3 wa = (inner_direction(e.p, c + e1 * h, n1, n0) - inner_direction(e.p, c - e1 * h, n1, n0)) / (2 * h);
    const Vec3 wb = (inner_direction(e.p, c + e2 * h, n1, n0) - inner_direction(e.p, c - e2 * h, n1, n0)) / (2 * h);
    const double G = std::fabs(dot(cross(wa, wb), w));
    const double mu = dot(e.d, w), g = 0.6;
    const double p_hg = (1 - g * g) / (4 * kPiTest * std::pow(1 + g * g - 2 * g * mu, 1.5));
    const double T = 1 - fresnel_oracle(w.z, n1, n0);  // w leaves through z = 0 (normal +z)
    const double expected = 0.8 * p_hg * std::exp(-32.0 * length(x - e.p)) * T * G / 0.02;
    EXPECT_NEAR(got, expected, 2e-4 * expected);
}

TEST(CameraTally, OccludedExitScoresNothing) {
    auto scene = slab(true);
    const CameraView v = view_at(Vec3(0, 0, 2));
    const CameraEvent e = slab_event(Vec3(0.05, 0.05, -0.05), Vec3(0, 0, 1));
    std::vector<Hit> hits;
    CameraScores out;
    next_event(*scene, v, e, 0.0, hits, out);
    EXPECT_TRUE(out.scores.empty());
    EXPECT_EQ(out.counters.occluded, 1u);
}

TEST(CameraTally, BatchesAndPixelsFollowThePythonConventions) {
    CameraView v = view_at(Vec3(0, 0, 2));
    v.batches = 3;
    v.packets = 10;  // analysis.batch_index: edges floor(b P / B) = 0, 3, 6, 10
    const int want[10] = {0, 0, 0, 1, 1, 1, 2, 2, 2, 2};
    for (uint64_t i = 0; i < 10; ++i) EXPECT_EQ(v.batch_of(i), want[i]) << i;
    // Camera.project: row 0 at the top (image up = +y), column 0 at the left (-x).
    EXPECT_EQ(v.pixel_of(Vec3(-1.9, 1.9, 0)), 0);
    EXPECT_EQ(v.pixel_of(Vec3(1.9, -1.9, 0)), 63);
    EXPECT_EQ(v.pixel_of(Vec3(0, 0, 3)), -1);  // behind the pinhole
}

TEST(CameraTally, DepthRouletteIsUnbiased) {
    auto scene = slab(false);
    CameraView v = view_at(Vec3(0, 0, 2));
    const CameraEvent e = slab_event(Vec3(0.01, 0.02, -0.2), Vec3(0, 0, 1));  // tau ~ 32 x 0.2 = 6.4 > tau_cut
    const double exact = score_of(*scene, v, e);
    v.tau_cut = 4.0;  // survives with exp(4 - 6.4) ~ 0.09
    std::vector<Hit> hits;
    CameraScores out;
    const int n = 20000;
    for (int i = 0; i < n; ++i) {
        Rng rng(3, uint64_t(i));
        next_event(*scene, v, e, rng.uniform(), hits, out);
    }
    double sum = 0, sum2 = 0;
    for (const CameraScore& s : out.scores) {
        sum += s.value;
        sum2 += s.value * s.value;
    }
    const double mean = sum / n, se = std::sqrt((sum2 / n - mean * mean) / (n - 1));
    EXPECT_GT(out.counters.thinned, 0u);
    EXPECT_LT(std::fabs(mean - exact), 4 * se);
}

TEST(CameraTally, SurfaceClearanceIsALowerBoundOfTheDistance) {
    // The exact distance to the slab's faces (Embree's point query) bounds
    // the cube cache's clearance from above at points all through the slab;
    // near the top face the bound is that face's distance (one plane).
    auto scene = slab(false);
    Rng rng(5, 0);
    int positive = 0, tight = 0;
    for (int i = 0; i < 2000; ++i) {
        const Vec3 p(4 * rng.uniform() - 2, 4 * rng.uniform() - 2, -rng.uniform());
        const double exact = scene->distance_to_surface(p, 10);
        const double got = surface_clearance(scene->cell_cache(p), p);
        ASSERT_GE(got, 0) << i;
        ASSERT_LE(got, exact) << i;
        positive += got > 0;
        tight += got > exact - 1e-6;
    }
    EXPECT_GT(positive, 1000);
    EXPECT_GT(tight, 100);
    EXPECT_EQ(surface_clearance(scene->cell_cache(Vec3(0, 0, -0.5)), Vec3(3, 3, 3)), 0);  // outside the ball
}

TEST(CameraTally, PrefilterThinsOnlyEventsTheSolvedPathThins) {
    // Events all through the slab, each with its roulette number u: where
    // camera_prefilter's bound drops one, next_event with the same u scores
    // nothing either (thinned), and where it passes one, the score is
    // next_event's. With depth_bound off every event in view is passed.
    auto scene = slab(false);
    CameraView v = view_at(Vec3(0.1, -0.2, 2));
    v.tau_cut = 3;
    Rng rng(7, 0);
    CameraCounters bound, exact;
    int dropped_and_thinned = 0;
    std::vector<Hit> hits;
    for (int i = 0; i < 4000; ++i) {
        const Vec3 p(2 * rng.uniform() - 1, 2 * rng.uniform() - 1, -0.5 * rng.uniform());
        const CameraEvent e = slab_event(p, Vec3(rng.uniform() - 0.5, rng.uniform() - 0.5, rng.uniform() - 0.5));
        const double u = rng.uniform();
        const double mut = 32;  // tissue(): mua + mus, cm^-1 (unit_cm = 1)
        auto clearance = [&] { return surface_clearance(scene->cell_cache(p), p); };
        const bool pass = camera_prefilter(v, p, u, mut, clearance, bound);
        v.depth_bound = false;
        ASSERT_TRUE(camera_prefilter(v, p, u, mut, clearance, exact)) << i;
        v.depth_bound = true;
        CameraScores solved;
        next_event(*scene, v, e, u, hits, solved);
        if (!pass) {
            ASSERT_TRUE(solved.scores.empty()) << i;
            ASSERT_EQ(solved.counters.thinned, 1u) << i;
            ++dropped_and_thinned;
        }
    }
    EXPECT_EQ(bound.events, 4000u);
    EXPECT_EQ(bound.bounded, uint64_t(dropped_and_thinned));
    EXPECT_GT(dropped_and_thinned, 1000);
    EXPECT_EQ(exact.bounded, 0u);
}

TEST(CameraTally, LookBackMixtureWeightsAreUnbiasedAndBounded) {
    // The look-back's direction w ~ q = (1 - alpha) p_HG,g(d.w) + alpha p_HG,gb(a.w)
    // with weight p_HG,g / q: E[weight f(w)] = E_HG[f], so E[weight] = 1 and
    // E[weight d.w] = g (the HG mean cosine), and every weight <= 1 / (1 - alpha).
    const Vec3 d = normalize(Vec3(0.3, -0.2, 1)), axis = normalize(Vec3(-1, 0.5, 0.4));
    const double g = 0.9, alpha = 0.5, gb = 0.8;
    Rng rng(11, 0);
    const int n = 200000;
    double s1 = 0, s1q = 0, sc = 0, scq = 0, worst = 0;
    for (int i = 0; i < n; ++i) {
        const LookBackDraw v = sample_look_back(d, axis, g, alpha, gb, rng.uniform(), rng.uniform(), rng.uniform());
        ASSERT_NEAR(length(v.w), 1.0, 1e-12);
        const double c = v.ratio * dot(d, v.w);
        s1 += v.ratio;
        s1q += v.ratio * v.ratio;
        sc += c;
        scq += c * c;
        worst = std::max(worst, v.ratio);
    }
    const double m1 = s1 / n, mc = sc / n;
    const double se1 = std::sqrt((s1q / n - m1 * m1) / n), sec = std::sqrt((scq / n - mc * mc) / n);
    EXPECT_LT(std::fabs(m1 - 1), 4 * se1) << m1 << " +- " << se1;
    EXPECT_LT(std::fabs(mc - g), 4 * sec) << mc << " +- " << sec;
    EXPECT_LE(worst, 1 / (1 - alpha) * (1 + 1e-12));
    // A wrong weight (the ratio dropped) is seen by the same test: E[d.w] under q is not g.
    double wrong = 0;
    for (int i = 0; i < 20000; ++i)
        wrong += dot(d, sample_look_back(d, axis, g, alpha, gb, rng.uniform(), rng.uniform(), rng.uniform()).w);
    EXPECT_GT(std::fabs(wrong / 20000 - g), 10 * sec * std::sqrt(10.0));
}

TEST(CameraTally, SegmentClearMeansNoTriangleOnTheSegment) {
    // Random segments through the slab, many longer than their cube's ball:
    // segment_clear says clear exactly when Embree finds no crossing.
    auto scene = slab(false);
    Rng rng(13, 0);
    int clear = 0, blocked = 0;
    std::vector<Hit> hits;
    for (int i = 0; i < 4000; ++i) {
        const Vec3 a(4 * rng.uniform() - 2, 4 * rng.uniform() - 2, -1.2 * rng.uniform() + 0.1);
        const Vec3 w = normalize(Vec3(rng.uniform() - 0.5, rng.uniform() - 0.5, rng.uniform() - 0.5));
        const double len = 0.6 * rng.uniform();
        const bool clear_here = segment_clear(*scene, scene->cell_cache(a), a, w, 0, len);
        scene->intersect_all(a, w, 0, len, hits);
        ASSERT_EQ(clear_here, hits.empty()) << i;
        if (!clear_here) {
            ++blocked;
            continue;
        }
        ++clear;
        ASSERT_TRUE(hits.empty()) << i;
    }
    EXPECT_GT(clear, 500);
    EXPECT_GT(blocked, 500);
    EXPECT_FALSE(
        segment_clear(*scene, scene->cell_cache(Vec3(0, 0, -0.01)), Vec3(0, 0, -0.01), Vec3(0, 0, 1), 0, 0.02));
}

TEST(CameraTally, CameraAxisInsideObeysSnell) {
    // Under the slab's top face (normal +z, n = 1.4): the axis refracts into
    // the straight direction to the camera, n sin(t1) = sin(t0), in its plane.
    auto scene = slab(false);
    const Vec3 p(0.1, 0.05, -0.05), c(1.0, -0.3, 0.8);
    const Vec3 w = camera_axis_inside(scene->cell_cache(p), p, c, 1.4);
    const Vec3 out = normalize(c - p);
    const double sin1 = std::sqrt(1 - w.z * w.z), sin0 = std::sqrt(1 - out.z * out.z);
    EXPECT_NEAR(1.4 * sin1, sin0, 1e-12);
    EXPECT_GT(w.z, 0);
    EXPECT_NEAR(dot(cross(w, out), Vec3(0, 0, 1)), 0, 1e-12);  // the same plane of incidence
}
