// The stop rule and the per-packet standard error, without clocks or threads:
// the elapsed time is an argument, so every verdict here is deterministic.
#include <gtest/gtest.h>

#include <cmath>
#include <vector>

#include "engine.h"
#include "tally.h"

using namespace ep;

namespace {

UnitTally unit_with(uint64_t packets, const std::vector<double>& per_packet_rd) {
    UnitTally u;
    u.reset(0);
    for (double w : per_packet_rd) {
        u.packets += 1;
        u.scalar[kDiffuse] = w;
        u.record_packet();
    }
    u.packets = packets;
    return u;
}

}  // namespace

TEST(StopRule, FixedCountStopsAtTheLastUnitOrAtTheBudget) {
    RunConfig c;
    c.photons = 300;
    c.time_budget_s = 2.0;
    StopRule rule(c, 3);
    const UnitTally u = unit_with(100, {});
    EXPECT_EQ(rule.after_merge(u, 1, 0, 0.5), StopReason::kNone);
    EXPECT_EQ(rule.after_merge(u, 2, 0, 1.999), StopReason::kNone);
    EXPECT_EQ(rule.after_merge(u, 2, 0, 2.0), StopReason::kTime);      // the first merge at/after the budget
    EXPECT_EQ(rule.after_merge(u, 3, 0, 99.0), StopReason::kPhotons);  // done beats the budget
}

TEST(StopRule, StoreStopsAtNRecordsOrSaysItCannot) {
    RunConfig c;
    c.store = 10;
    StopRule rule(c, 1u << 30);
    const UnitTally u = unit_with(1024, {});
    EXPECT_EQ(rule.after_merge(u, 1, 9, 0), StopReason::kNone);
    EXPECT_EQ(rule.after_merge(u, 2, 10, 0), StopReason::kStore);
    StopRule none(c, 1u << 30);
    EXPECT_EQ(none.after_merge(u, StopRule::kZeroUnits - 1, 0, 0), StopReason::kNone);
    EXPECT_EQ(none.after_merge(u, StopRule::kZeroUnits, 0, 0), StopReason::kStoreZero);
    StopRule capped(c, 5);
    EXPECT_EQ(capped.after_merge(u, 5, 3, 0), StopReason::kMaxPhotons);
}

TEST(StopRule, TargetNeedsTwentyUnitsAndStopsOnZeroTallies) {
    RunConfig c;
    c.target_tally = kDiffuse;
    c.target_rel_error = 0.5;
    StopRule rule(c, 1u << 30);
    // Units alternating 1 and 3 (per 1 packet each): mean 2, clearly below 50 % error
    // once 20 units exist, never before.
    for (size_t k = 1; k < StopRule::kMinTargetUnits; ++k)
        EXPECT_EQ(rule.after_merge(unit_with(1, {k % 2 ? 1.0 : 3.0}), k, 0, 0), StopReason::kNone) << k;
    EXPECT_EQ(rule.after_merge(unit_with(1, {1.0}), StopRule::kMinTargetUnits, 0, 0), StopReason::kTarget);
    StopRule zero(c, 1u << 30);
    for (size_t k = 1; k < StopRule::kZeroUnits; ++k)
        ASSERT_EQ(zero.after_merge(unit_with(1, {0.0}), k, 0, 0), StopReason::kNone) << k;
    EXPECT_EQ(zero.after_merge(unit_with(1, {0.0}), StopRule::kZeroUnits, 0, 0), StopReason::kTargetZero);
}

TEST(PerPacketStderr, MatchesTheSampleFormulaAndIsFiniteForOnePacket) {
    // Weights 0, 1, 1, 0, 1: mean 0.6, sample variance 0.3, stderr sqrt(0.3 / 5).
    EXPECT_NEAR(per_packet_stderr(5, 3.0, 3.0), std::sqrt(0.3 / 5), 1e-15);
    EXPECT_EQ(per_packet_stderr(1, 0.7, 0.49), 0.7);  // one packet: sqrt(sum w^2)
    EXPECT_EQ(per_packet_stderr(0, 0, 0), 0.0);
    EXPECT_EQ(per_packet_stderr(4, 2.0, 1.0), 0.0);  // constant 0.5: variance 0 (no rounding below 0)
    // A single unit: batch means cannot give an error, the per-packet moments do.
    const std::vector<UnitTally> one = {unit_with(5, {0, 1, 1, 0, 1})};
    const Estimate e =
        batch_estimate(one, 50, [](const UnitTally& u) -> const Moments& { return u.scalar_m[kDiffuse]; });
    EXPECT_DOUBLE_EQ(e.mean, 0.6);
    EXPECT_NEAR(e.stderr_, std::sqrt(0.3 / 5), 1e-15);
}

TEST(StopReason, EveryReasonHasADistinctName) {
    EXPECT_STREQ(stop_reason_name(StopReason::kStoreZero), "store_zero");
    EXPECT_STREQ(stop_reason_name(StopReason::kTargetZero), "target_zero");
    EXPECT_STREQ(stop_reason_name(StopReason::kCancelled), "cancelled");
}
