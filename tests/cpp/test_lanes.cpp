// The float32 lane kernel (native/lane_block.h, lane_kernel.h) driven
// directly: its sampling laws against their closed forms (chi-square through
// each law's CDF, moments where float32 cannot resolve the peak), its
// clearance against the zone's exact geometry, its exits, and the same bits
// from every instruction set this processor has.
#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <functional>
#include <vector>

#include "lane_block.h"
#include "stat_util.h"

namespace {

using ep::LaneBlock;
constexpr int kSlots = LaneBlock::kSlots;

// Slot k of B: at the centre heading +z with the frame (x, y, z), in a
// medium of 1 / mu_t = inv_mut, capture fraction `loss` and HG's g (the
// constants as PacketWalk::to_lane computes them), a stream from `seed`,
// a ball of radius `radius` and no plane, no roulette, one step a call.
void set_slot(LaneBlock& B, int k, double g, float inv_mut, float loss, float radius, uint32_t seed) {
    B.s0[k] = 0x9E3779B9u * (seed + 1), B.s1[k] = 0x85EBCA6Bu ^ seed, B.s2[k] = 0xC2B2AE35u + seed;
    B.s3[k] = (0x27D4EB2Fu * (seed + 7)) | 1u;
    B.count[k] = 0, B.steps[k] = 0, B.room[k] = 1;
    B.qx[k] = B.qy[k] = B.qz[k] = 0;
    B.tx[k] = 1, B.ty[k] = 0, B.tz[k] = 0, B.bx[k] = 0, B.by[k] = 1, B.bz[k] = 0, B.nx[k] = 0, B.ny[k] = 0;
    B.nz[k] = 1;
    B.w[k] = 1, B.tau[k] = 1, B.depth[k] = -1e30f, B.budget[k] = 0;
    B.inv_mut[k] = inv_mut, B.loss[k] = loss;
    B.small_g[k] = std::fabs(g) < 0.25 ? -1 : 0;
    B.g[k] = float(g), B.hg0[k] = float(1 - g * g), B.hg1[k] = float(1 - g), B.hg2[k] = float(2 * g);
    B.hg3[k] = float(1 + g * g), B.hg_inv2g[k] = B.small_g[k] ? 0.f : float(1 / (2 * g));
    B.threshold[k] = 0;
    B.inner[k] = radius, B.inner_r2[k] = radius * radius, B.slack[k] = 1e-6f * radius;
    B.ex[k] = B.ey[k] = B.ez[k] = 0, B.ix[k] = B.iy[k] = B.iz[k] = 0;
    B.active[k] = -1, B.reason[k] = 0;
}

// The kernels this processor can run.
std::vector<std::function<uint32_t(LaneBlock&)>> kernels() {
    std::vector<std::function<uint32_t(LaneBlock&)>> k = {ep::run_lanes_sse2};
    if (__builtin_cpu_supports("avx2")) k.push_back(ep::run_lanes_avx2);
    if (__builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512vl") && __builtin_cpu_supports("avx512dq"))
        k.push_back(ep::run_lanes_avx512);
    return k;
}

// One scattering of every slot (room 1): the cosine between the directions
// before and after, the azimuth of the new direction in the old frame, the
// free path drawn for the next step, in double.
struct Scatter {
    double cos_theta, phi, tau;
};
std::vector<Scatter> scatterings(double g, int calls) {
    LaneBlock B;
    for (int k = 0; k < kSlots; ++k) set_slot(B, k, g, 1e-3f, 0.f, 1e6f, uint32_t(k));
    std::vector<Scatter> out;
    out.reserve(size_t(calls) * kSlots);
    for (int c = 0; c < calls; ++c) {
        double n0[kSlots][3], t0[kSlots][3], b0[kSlots][3];
        for (int k = 0; k < kSlots; ++k) {
            n0[k][0] = B.nx[k], n0[k][1] = B.ny[k], n0[k][2] = B.nz[k];
            t0[k][0] = B.tx[k], t0[k][1] = B.ty[k], t0[k][2] = B.tz[k];
            b0[k][0] = B.bx[k], b0[k][1] = B.by[k], b0[k][2] = B.bz[k];
        }
        EXPECT_EQ(ep::run_lanes(B), 0xFFFFu);
        for (int k = 0; k < kSlots; ++k) {
            const double n[3] = {B.nx[k], B.ny[k], B.nz[k]};
            auto dot = [&](const double* a) { return a[0] * n[0] + a[1] * n[1] + a[2] * n[2]; };
            const double len = std::sqrt(dot(n));
            out.push_back({dot(n0[k]) / len, std::atan2(dot(b0[k]), dot(t0[k])), double(B.tau[k])});
            EXPECT_EQ(B.reason[k], ep::kLaneSlow);
            B.steps[k] = 0, B.active[k] = -1, B.qx[k] = B.qy[k] = B.qz[k] = 0;
        }
    }
    return out;
}

// HG's CDF in cos theta (long double: it cancels as g -> 0).
double hg_cdf(double g, double mu) {
    if (g == 0) return (mu + 1) / 2;
    const long double G = g, M = mu;
    return double((1 - G * G) / (2 * G) * (1 / std::sqrt(1 + G * G - 2 * G * M) - 1 / (1 + G)));
}

// Chi-square of values already mapped through their CDF: uniform on [0, 1].
void expect_uniform(const std::vector<double>& u, int bins, uint64_t seed) {
    size_t i = 0;
    ep_test::expect_chi_square_fit([&](std::mt19937_64&) { return std::min(1.0, std::max(0.0, u[i++])); },
                                   [](double a, double b) { return b - a; }, 0, 1, bins, int(u.size()), seed);
}

// A sample mean's z against its expected value, from the sample's own spread.
double z_of_mean(const std::vector<double>& x, double expected) {
    double m = 0, m2 = 0;
    for (double v : x) m += v, m2 += v * v;
    const double n = double(x.size());
    m /= n;
    const double var = m2 / n - m * m;
    return (m - expected) / std::sqrt(var / n);
}

TEST(Lanes, HGCosineFollowsItsCDF) {
    // Both forms: MCML's (|g| >= 1/4) and the small-|g| one, with g = 0 and
    // 1e-4, where MCML's form cancels in float32.
    for (double g : {0.9, 0.99, 0.5, 0.25, -0.5, -0.9, 0.2, 1e-4, 0.0, -0.2}) {
        SCOPED_TRACE(g);
        const auto s = scatterings(g, 8000);
        std::vector<double> u;
        for (const Scatter& x : s) u.push_back(hg_cdf(g, x.cos_theta));
        expect_uniform(u, 64, 11);
    }
}

TEST(Lanes, HGMomentsNearTheDeltas) {
    // g -> +-1: the peak is narrower than float32's spacing near +-1, so the
    // law is checked where transport feels it, <cos> = g and <cos^2> =
    // (1 + 2 g^2) / 3 (HG's first two Legendre moments), within 4 sigma.
    for (double g : {0.9999, -0.9999, 0.999}) {
        SCOPED_TRACE(g);
        const auto s = scatterings(g, 20000);
        std::vector<double> c, c2;
        for (const Scatter& x : s) c.push_back(x.cos_theta), c2.push_back(x.cos_theta * x.cos_theta);
        EXPECT_LT(std::fabs(z_of_mean(c, g)), 4.0);
        EXPECT_LT(std::fabs(z_of_mean(c2, (1 + 2 * g * g) / 3)), 4.0);
        for (const Scatter& x : s) ASSERT_LE(std::fabs(x.cos_theta), 1 + 1e-6);
    }
}

TEST(Lanes, AzimuthAndFreePathFollowTheirCDFs) {
    const auto s = scatterings(0.9, 8000);
    std::vector<double> phi, tau;
    for (const Scatter& x : s) phi.push_back((x.phi + M_PI) / (2 * M_PI)), tau.push_back(1 - std::exp(-x.tau));
    expect_uniform(phi, 64, 12);
    expect_uniform(tau, 64, 13);
    for (const Scatter& x : s) ASSERT_TRUE(std::isfinite(x.tau) && x.tau >= 0 && x.tau < 17);
}

TEST(Lanes, IsotropicDirectionsAreUniformOnTheSphere) {
    // g = 0: every component of the new direction uniform on [-1, 1]
    // (Archimedes), whatever the frame after many turns.
    LaneBlock B;
    for (int k = 0; k < kSlots; ++k) set_slot(B, k, 0.0, 1e-3f, 0.f, 1e6f, uint32_t(100 + k));
    std::vector<double> x, y, z;
    for (int c = 0; c < 8000; ++c) {
        ASSERT_EQ(ep::run_lanes(B), 0xFFFFu);
        for (int k = 0; k < kSlots; ++k) {
            x.push_back((B.nx[k] + 1) / 2), y.push_back((B.ny[k] + 1) / 2), z.push_back((B.nz[k] + 1) / 2);
            B.steps[k] = 0, B.active[k] = -1, B.qx[k] = B.qy[k] = B.qz[k] = 0;
        }
    }
    expect_uniform(x, 64, 14);
    expect_uniform(y, 64, 15);
    expect_uniform(z, 64, 16);
}

TEST(Lanes, StepsStayInTheZoneAndLeaveOnlyNearItsEdge) {
    // A ball of radius R and a plane z > -d0 (n = (0, 0, 1), off = -d0): every
    // step taken ends inside both (in exact arithmetic on the float32
    // position: the zone is convex, so its segment is inside too); a blocked
    // step ends outside or within a hair of an edge. The budget carries over
    // from call to call, as in a run.
    const float R = 0.5f, d0 = 0.2f;
    LaneBlock B;
    for (int k = 0; k < kSlots; ++k) {
        set_slot(B, k, 0.3, 0.05f, 0.f, R, uint32_t(200 + k));
        B.planes[k] = 1;
        B.pnx[0][k] = 0, B.pny[0][k] = 0, B.pnz[0][k] = 1, B.poff[0][k] = -d0;
    }
    B.n_planes = 1;
    long taken = 0, blocked = 0;
    for (int c = 0; c < 20000; ++c) {
        const uint32_t left = ep::run_lanes(B);
        ASSERT_NE(left, 0u);
        for (int k = 0; k < kSlots; ++k) {
            if (!(left >> k & 1)) continue;
            const double q[3] = {B.qx[k], B.qy[k], B.qz[k]};
            if (B.reason[k] == ep::kLaneSlow) {
                ++taken;
                ASSERT_LT(std::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2]), R);
                ASSERT_GT(q[2], -d0);
            } else {
                ASSERT_EQ(B.reason[k], ep::kLaneBlocked);
                ++blocked;
                // Blocked: the step's end lies within 1e-5 of an edge or past one.
                const double s = double(B.tau[k]) * B.inv_mut[k];
                const double b[3] = {q[0] + B.nx[k] * s, q[1] + B.ny[k] * s, q[2] + B.nz[k] * s};
                const double r = std::sqrt(b[0] * b[0] + b[1] * b[1] + b[2] * b[2]);
                EXPECT_TRUE(r > R - 1e-5 || b[2] < -d0 + 1e-5) << r << " " << b[2];
                // The walk would take that step; here the packet starts again
                // at the centre, with a short step.
                B.qx[k] = B.qy[k] = B.qz[k] = 0, B.budget[k] = 0, B.tau[k] = 1;
            }
            B.steps[k] = 0, B.active[k] = -1;
        }
    }
    std::printf("[ lanes    ] %ld steps taken, %ld blocked\n", taken, blocked);
    EXPECT_GT(taken, 100000);
    EXPECT_GT(blocked, 1000);
}

TEST(Lanes, RouletteIsDueWhereTheWeightFallsBelowTheThreshold) {
    // Capture 1/2 a step, threshold 0.01: 1/2^7 = 0.0078 is the first below,
    // so every slot leaves after its 7th step, weight exactly 2^-7.
    LaneBlock B;
    for (int k = 0; k < kSlots; ++k) {
        set_slot(B, k, 0.9, 1e-3f, 0.5f, 1e6f, uint32_t(k));
        B.threshold[k] = 0.01f, B.room[k] = 1000;
    }
    EXPECT_EQ(ep::run_lanes(B), 0xFFFFu);
    for (int k = 0; k < kSlots; ++k) {
        EXPECT_EQ(B.steps[k], 7u);
        EXPECT_EQ(B.w[k], 0x1.0p-7f);
        EXPECT_EQ(B.reason[k], ep::kLaneSlow);
    }
    EXPECT_EQ(ep::run_lanes(B), 0u);  // none active
}

TEST(Lanes, FluorescenceTrialsFireWithTheirChances) {
    // Slots 0-11 try three fluorophores at every interaction (seed §4: j
    // fires where u1 < d_j and u2 < c_j, the first that fires ends them), no
    // capture, an endless ball: each stay ends at its first event. Per
    // interaction: none with chance prod (1 - p_j), j with prod_{i<j} (1 -
    // p_i) p_j, p_j = d_j c_j; chi-square over the four outcomes. The trials
    // counted are exact: 3 for a step without an event, j + 1 for an event
    // of j. Slots 12-15 try none (the paper's rule after an event) and leave
    // at their step cap with no trial and no event.
    const float d[3] = {0.2f, 0.1f, 0.5f}, c[3] = {0.4f, 0.33f, 0.5f};
    double p[3], none = 1;
    for (int j = 0; j < 3; ++j) p[j] = double(d[j]) * double(c[j]);
    double outcome_p[4];
    for (int j = 0; j < 3; ++j) outcome_p[j + 1] = none * p[j], none *= 1 - p[j];
    outcome_p[0] = none;
    for (const auto& run : kernels()) {
        LaneBlock B;
        for (int k = 0; k < kSlots; ++k) {
            set_slot(B, k, 0.9, 1e-3f, 0.f, 1e6f, uint32_t(k * 7 + 1));
            B.room[k] = k < 12 ? 1000000 : 50;
            B.trials[k] = k < 12 ? 3 : 0;
            for (int j = 0; j < 3; ++j) B.trial_d[j][k] = d[j], B.trial_c[j][k] = c[j];
        }
        B.max_trials = 3;
        std::vector<double> outcomes;  // 0: none, j + 1: fluorophore j fired
        int stays[kSlots] = {};
        while (const uint32_t left = run(B)) {
            for (int k = 0; k < kSlots; ++k) {
                if (!(left >> k & 1)) continue;
                const uint32_t steps = B.steps[k];
                if (k < 12) {
                    ASSERT_EQ(B.reason[k], ep::kLaneFluoresced);
                    ASSERT_GE(B.fired[k], 0);
                    ASSERT_LT(B.fired[k], 3);
                    EXPECT_EQ(B.tried[k], 3 * (steps - 1) + uint32_t(B.fired[k]) + 1);
                    outcomes.insert(outcomes.end(), steps - 1, 0.5);
                    outcomes.push_back(B.fired[k] + 1.5);
                } else {
                    EXPECT_EQ(B.reason[k], ep::kLaneSlow);
                    EXPECT_EQ(B.tried[k], 0u);
                    EXPECT_EQ(steps, 50u);
                }
                EXPECT_EQ(B.w[k], 1.f);  // no capture
                B.steps[k] = 0, B.tried[k] = 0;
                B.active[k] = ++stays[k] < 3000 ? -1 : 0;
            }
        }
        size_t i = 0;
        ep_test::expect_chi_square_fit([&](std::mt19937_64&) { return outcomes[i++]; },
                                       [&](double a, double) { return outcome_p[int(a)]; }, 0, 4, 4,
                                       int(outcomes.size()), 1);
        std::printf("[ lanes    ] %zu interactions, %.0f events\n", outcomes.size(), 12.0 * 3000);
    }
}

TEST(Lanes, EveryInstructionSetGivesTheSameBits) {
    // 16 slots of mixed media (both HG forms), a plane, roulette and the step
    // cap, each stepped to 300 exits by each kernel. A kernel returns when a
    // group of its width has an exit, so the calls differ from width to width;
    // what each slot does at each of its exits must not (the walk merges
    // packets in index order, so only that reaches a result).
    auto fill = [](LaneBlock& B) {
        for (int k = 0; k < kSlots; ++k) {
            const double g = k % 4 == 0 ? 0.0 : k % 4 == 1 ? 0.1 : k % 4 == 2 ? 0.9 : -0.7;
            set_slot(B, k, g, 0.01f * float(1 + k % 3), 0.05f, 0.3f, uint32_t(k * 31));
            B.threshold[k] = 1e-4f, B.room[k] = 40 + uint32_t(k);
            B.planes[k] = 1;
            B.pnx[0][k] = 0.6f, B.pny[0][k] = 0, B.pnz[0][k] = 0.8f, B.poff[0][k] = -0.1f;
            B.ez[k] = 0.05f, B.ix[k] = 0.6f, B.iz[k] = -0.8f;  // the depth below an entry point
            if (k % 2 == 0) {                                  // fluorescence trials of two fluorophores
                B.trials[k] = 2;
                B.trial_d[0][k] = 0.2f, B.trial_c[0][k] = 0.4f, B.trial_d[1][k] = 0.1f, B.trial_c[1][k] = 0.33f;
            }
        }
        B.n_planes = 1;
        B.max_trials = 2;
        B.track_depth = true;
    };
    auto slot_bytes = [](const LaneBlock& B, int k, std::vector<uint8_t>& out) {
        const float f[] = {B.qx[k], B.qy[k], B.qz[k], B.tx[k], B.ty[k], B.tz[k],  B.bx[k],    B.by[k],
                           B.bz[k], B.nx[k], B.ny[k], B.nz[k], B.w[k],  B.tau[k], B.depth[k], B.budget[k]};
        const uint32_t reason = uint32_t(B.reason[k]), fired = uint32_t(B.fired[k]);
        const uint32_t u[] = {B.s0[k], B.s1[k], B.s2[k], B.s3[k], B.count[k], B.steps[k], reason, B.tried[k], fired};
        out.insert(out.end(), reinterpret_cast<const uint8_t*>(f), reinterpret_cast<const uint8_t*>(f) + sizeof f);
        out.insert(out.end(), reinterpret_cast<const uint8_t*>(u), reinterpret_cast<const uint8_t*>(u) + sizeof u);
    };
    std::vector<std::vector<uint8_t>> traces;  // per kernel: every slot's exits, slot by slot
    for (const auto& run : kernels()) {
        LaneBlock B;
        fill(B);
        std::vector<uint8_t> per_slot[kSlots];
        int exits[kSlots] = {};
        long calls = 0;
        while (const uint32_t left = run(B)) {
            ++calls;
            for (int k = 0; k < kSlots; ++k) {
                if (!(left >> k & 1)) continue;
                slot_bytes(B, k, per_slot[k]);
                if (B.reason[k] == ep::kLaneSlow) B.w[k] = 1;  // roulette survived, the cap renewed
                if (B.reason[k] == ep::kLaneBlocked) B.qx[k] = B.qy[k] = B.qz[k] = 0, B.budget[k] = 0, B.tau[k] = 1;
                B.steps[k] = 0, B.tried[k] = 0;
                B.active[k] = ++exits[k] < 300 ? -1 : 0;
            }
        }
        std::vector<uint8_t> all;
        for (const auto& v : per_slot) all.insert(all.end(), v.begin(), v.end());
        traces.push_back(std::move(all));
        std::printf("[ lanes    ] kernel %zu: %ld calls\n", traces.size(), calls);
    }
    for (size_t i = 1; i < traces.size(); ++i) EXPECT_TRUE(traces[i] == traces[0]) << "kernel " << i;
    std::printf("[ lanes    ] %zu instruction sets compared (sse2%s%s)\n", traces.size(),
                traces.size() > 1 ? ", avx2" : "", traces.size() > 2 ? ", avx512" : "");
}

TEST(Lanes, TheChoiceOfInstructionSetIsNamed) {
    EXPECT_STREQ(ep::lane_isa_name(ep::LaneIsa::kSse2), "sse2");
    EXPECT_STREQ(ep::lane_isa_name(ep::LaneIsa::kAvx2), "avx2");
    EXPECT_STREQ(ep::lane_isa_name(ep::LaneIsa::kAvx512), "avx512");
}

}  // namespace
