// Tests for ep::EEM (native/eem.h).
//
// The reference distributions are built here by hand from the tabulated
// matrix (linear interpolation in excitation, piecewise linear in emission)
// and compared with EEM's sampler by a chi-square test whose critical value
// comes from the Wilson-Hilferty approximation (Wilson & Hilferty 1931).
#include <gtest/gtest.h>

#include "stat_util.h"

#include <cmath>
#include <cstdint>
#include <functional>
#include <limits>
#include <random>
#include <stdexcept>
#include <string>
#include <vector>

#include "eem.h"

namespace {

using namespace ep_test;

using ep::EEM;

// Piecewise-linear interpolant of (xs, ys) at x, 0 outside.
double lin_eval(const std::vector<double>& xs, const std::vector<double>& ys, double x) {
    for (std::size_t i = 0; i + 1 < xs.size(); ++i)
        if (x >= xs[i] && x <= xs[i + 1]) return ys[i] + (ys[i + 1] - ys[i]) * (x - xs[i]) / (xs[i + 1] - xs[i]);
    return 0.0;
}

// Chi-square goodness of fit of `draw` against the piecewise-linear density
// through (xs, ys), in `bins` equal bins over [xs.front(), xs.back()].
void expect_fits_row(const std::function<double(std::mt19937_64&)>& draw, const std::vector<double>& xs,
                     const std::vector<double>& ys, int bins, int n, std::uint64_t seed) {
    const double lo = xs.front(), hi = xs.back();
    const double total = lin_integral(xs, ys, lo, hi);
    expect_chi_square_fit(
        draw, [&](double a, double b) { return lin_integral(xs, ys, a, b) / total; }, lo, hi, bins, n, seed);
}

// Hand-built EEM: 3 excitation rows x 3 emission columns.
//   ex 300: [0, 1, 1]  integral 10*(0+1)/2 + 20*(1+1)/2 = 5 + 20 = 25
//   ex 320: [2, 2, 0]  integral 10*(2+2)/2 + 20*(2+0)/2 = 20 + 20 = 40
//   ex 340: [0, 0, 0]  integral 0 (a row that does not emit)
const std::vector<double> kEx = {300, 320, 340};
const std::vector<double> kEm = {350, 360, 380};
const std::vector<double> kValues = {0, 1, 1, 2, 2, 0, 0, 0, 0};

EEM hand_eem() { return EEM("hand", kEx, kEm, kValues); }

// Row at lambda_ex by linear interpolation in excitation, built independently.
std::vector<double> interpolated_row(double lambda_ex) {
    std::vector<double> row(kEm.size());
    std::size_t i = lambda_ex < kEx[1] ? 0 : 1;
    const double t = (lambda_ex - kEx[i]) / (kEx[i + 1] - kEx[i]);
    for (std::size_t j = 0; j < kEm.size(); ++j)
        row[j] = (1 - t) * kValues[i * kEm.size() + j] + t * kValues[(i + 1) * kEm.size() + j];
    return row;
}

TEST(EEM, StoresItsArrays) {
    const EEM e = hand_eem();
    EXPECT_EQ(e.name(), "hand");
    EXPECT_EQ(e.excitation_nm(), kEx);
    EXPECT_EQ(e.emission_nm(), kEm);
    EXPECT_EQ(e.values(), kValues);
    EXPECT_EQ(e.n_excitation(), 3u);
    EXPECT_EQ(e.n_emission(), 3u);
    EXPECT_EQ(e.value(1, 0), 2.0);
    EXPECT_DOUBLE_EQ(e.row_integral(0), 25.0);
    EXPECT_DOUBLE_EQ(e.row_integral(1), 40.0);
    EXPECT_DOUBLE_EQ(e.row_integral(2), 0.0);
}

TEST(EEM, EfficiencyMatchesHandComputedIntegrals) {
    const EEM e = hand_eem();
    // eta = I(lambda) / max_i I_i with max_i I_i = 40.
    EXPECT_DOUBLE_EQ(e.efficiency(300), 25.0 / 40.0);
    EXPECT_DOUBLE_EQ(e.efficiency(320), 1.0);
    EXPECT_DOUBLE_EQ(e.efficiency(310), (0.5 * 25 + 0.5 * 40) / 40.0);    // 0.8125
    EXPECT_DOUBLE_EQ(e.efficiency(305), (0.75 * 25 + 0.25 * 40) / 40.0);  // 0.71875
    EXPECT_DOUBLE_EQ(e.efficiency(330), 0.5 * 40 / 40.0);
    EXPECT_DOUBLE_EQ(e.efficiency(340), 0.0);
    // Outside the excitation range the efficiency is 0 (no clamping).
    EXPECT_EQ(e.efficiency(299.9), 0.0);
    EXPECT_EQ(e.efficiency(340.1), 0.0);
    EXPECT_EQ(e.efficiency(std::numeric_limits<double>::quiet_NaN()), 0.0);
    // The definition integrates the interpolated row; check against the
    // independent integrator at an off-node wavelength.
    const double lam = 313.7;
    EXPECT_NEAR(e.efficiency(lam), lin_integral(kEm, interpolated_row(lam), 350, 380) / 40.0, 1e-14);
}

TEST(EEM, SampleEmissionBetweenRowsFollowsTheInterpolatedRow) {
    const EEM e = hand_eem();
    for (double lam : {300.0, 306.0, 310.0, 317.5, 320.0, 335.0}) {
        SCOPED_TRACE("lambda_ex = " + std::to_string(lam));
        expect_fits_row([&](std::mt19937_64& r) { return e.sample_emission(lam, uniform(r), uniform(r)); }, kEm,
                        interpolated_row(lam), 30, 200000, 1000 + static_cast<int>(lam * 10));
    }
}

TEST(EEM, SampleEmissionOutsideTheRangeUsesTheNearestRow) {
    const EEM e = hand_eem();
    // Below the range: clamped to the ex 300 row [0, 1, 1].
    expect_fits_row([&](std::mt19937_64& r) { return e.sample_emission(250, uniform(r), uniform(r)); }, kEm, {0, 1, 1},
                    30, 200000, 11);
    // At and above 340 nm the (clamped) row does not emit; the nearest
    // emitting row is ex 320 = [2, 2, 0].
    for (double lam : {340.0, 900.0}) {
        expect_fits_row([&](std::mt19937_64& r) { return e.sample_emission(lam, uniform(r), uniform(r)); }, kEm,
                        {2, 2, 0}, 30, 200000, 12);
    }
    // u1 = 1 with all the weight on one row must not pick the silent row.
    EXPECT_NO_THROW(e.sample_emission(320, 1.0, 0.5));
    EXPECT_NO_THROW(e.sample_emission(335, 1.0, 0.5));
}

TEST(EEM, SampleEmissionOnAGeneralMatrixChiSquare) {
    // 4 x 6 matrix with a Stokes-like zero corner and uneven grids.
    const std::vector<double> ex = {330, 350, 380, 400};
    const std::vector<double> em = {360, 380, 400, 430, 470, 520};
    const std::vector<double> v = {0.5, 3.0, 4.0, 2.0, 0.5, 0.1,  //
                                   0.0, 1.0, 5.0, 3.0, 1.0, 0.2,  //
                                   0.0, 0.0, 0.5, 4.0, 2.0, 0.5,  //
                                   0.0, 0.0, 0.0, 1.0, 3.0, 1.0};
    const EEM e("general", ex, em, v);
    for (double lam : {342.0, 371.0, 395.0}) {
        SCOPED_TRACE("lambda_ex = " + std::to_string(lam));
        std::size_t i = lam < 350 ? 0 : (lam < 380 ? 1 : 2);
        const double t = (lam - ex[i]) / (ex[i + 1] - ex[i]);
        std::vector<double> row(em.size());
        for (std::size_t j = 0; j < em.size(); ++j)
            row[j] = (1 - t) * v[i * em.size() + j] + t * v[(i + 1) * em.size() + j];
        expect_fits_row([&](std::mt19937_64& r) { return e.sample_emission(lam, uniform(r), uniform(r)); }, em, row, 40,
                        300000, 77 + static_cast<int>(lam));
        // emission_pdf is the normalised interpolated row.
        const double total = lin_integral(em, row, em.front(), em.back());
        for (double x : {365.0, 390.0, 415.0, 450.0, 500.0, 520.0}) {
            const double expected = lin_eval(em, row, x) / total;
            EXPECT_NEAR(e.emission_pdf(lam, x), expected, 1e-13 * expected);
        }
        EXPECT_EQ(e.emission_pdf(lam, 359.0), 0.0);
        EXPECT_EQ(e.emission_pdf(lam, 521.0), 0.0);
    }
}

TEST(EEM, EmissionPdfIsNormalisedAndMatchesTheRowIncludingFallback) {
    const EEM e = hand_eem();
    for (double lam : {290.0, 300.0, 312.0, 335.0, 340.0, 700.0}) {
        // Trapezoid over a fine grid: exact for the piecewise-linear density
        // because the grid contains the nodes 350, 360, 380.
        double sum = 0.0;
        for (int k = 0; k < 300; ++k) {
            const double a = 350 + 0.1 * k, b = a + 0.1;
            sum += 0.05 * (e.emission_pdf(lam, a) + e.emission_pdf(lam, b));
        }
        EXPECT_NEAR(sum, 1.0, 1e-12) << "lambda_ex = " << lam;
    }
    // Fallback row [2, 2, 0] (integral 40): pdf at 355 is 2/40.
    EXPECT_DOUBLE_EQ(e.emission_pdf(340, 355), 2.0 / 40.0);
    // Clamped row [0, 1, 1] (integral 25): pdf at 370 is 1/25.
    EXPECT_DOUBLE_EQ(e.emission_pdf(200, 370), 1.0 / 25.0);
}

TEST(EEM, WavelengthsAtTheRangeEndsAreAccepted) {
    const EEM e("ends", {ep::kMinWavelengthNm}, {ep::kMinWavelengthNm, ep::kMaxWavelengthNm}, {1, 1});
    EXPECT_EQ(e.emission_nm().front(), 1.0);
    EXPECT_EQ(e.emission_nm().back(), 1e6);
}

TEST(EEM, SingleExcitationRow) {
    const EEM e("laser", {405}, {600, 650, 700}, {0, 2, 1});
    EXPECT_EQ(e.efficiency(405), 1.0);
    EXPECT_EQ(e.efficiency(404), 0.0);
    EXPECT_EQ(e.efficiency(406), 0.0);
    expect_fits_row([&](std::mt19937_64& r) { return e.sample_emission(532, uniform(r), uniform(r)); }, {600, 650, 700},
                    {0, 2, 1}, 20, 100000, 5);
}

TEST(EEM, ValidationErrorsNameTheEemFieldAndValue) {
    const double nan = std::numeric_limits<double>::quiet_NaN();
    // The exact message from the design contract.
    try {
        EEM("collagen", {300, 310, 320}, {350, 360, 370, 380, 390}, std::vector<double>(12, 1.0));
        ADD_FAILURE() << "no exception";
    } catch (const std::invalid_argument& e) {
        EXPECT_STREQ(e.what(), "eem 'collagen': values has 12 entries, expected 3 x 5 = 15");
    }
    expect_invalid(
        [] {
            EEM("collagen", {300, 320, 310}, {350, 360}, {1, 1, 1, 1, 1, 1});
        },
        {"eem 'collagen'", "excitation_nm[2] = 310", "excitation_nm[1] = 320", "strictly increasing"});
    expect_invalid(
        [&] {
            EEM("photofrin", {300, 310}, {350, nan, 370}, std::vector<double>(6, 1.0));
        },
        {"eem 'photofrin'", "emission_nm[1] = nan", "finite"});
    expect_invalid([] { EEM("x", {0, 310}, {350, 360}, {1, 1, 1, 1}); }, {"eem 'x'", "excitation_nm[0] = 0", "> 0"});
    // The range [1, 1e6] nm (spectrum.h), the messages of endophoton.spectra.
    expect_invalid(
        [] {
            EEM("x", {300, 310}, {1e-300, 360}, {1, 1, 1, 1});
        },
        {"eem 'x'", "emission_nm[0] = 1e-300", "is outside [1, 1e+06] nm"});
    expect_invalid(
        [] {
            EEM("x", {300, 2e6}, {350, 360}, {1, 1, 1, 1});
        },
        {"eem 'x'", "excitation_nm[1] = 2e+06", "is outside [1, 1e+06] nm"});
    expect_invalid(
        [] {
            EEM("x", {300, 310}, {360, 360}, {1, 1, 1, 1});
        },
        {"eem 'x'", "emission_nm[1] = 360", "strictly increasing"});
    expect_invalid(
        [] {
            EEM("x", {300, 310}, {350, 360, 370}, {1, 1, 1, 1, 1, -0.5});
        },
        {"eem 'x'", "values[1][2]", "ex 310 nm", "em 370 nm", "-0.5", ">= 0"});
    expect_invalid(
        [&] {
            EEM("x", {300, 310}, {350, 360}, {1, nan, 1, 1});
        },
        {"eem 'x'", "values[0][1]", "nan", "finite"});
    expect_invalid([] { EEM("x", {300, 310}, {350, 360}, {0, 0, 0, 0}); }, {"eem 'x'", "all 0"});
    expect_invalid([] { EEM("x", {}, {350, 360}, {}); }, {"eem 'x'", "excitation_nm", "at least 1", "got 0"});
    expect_invalid([] { EEM("x", {300}, {350}, {1}); }, {"eem 'x'", "emission_nm", "at least 2", "got 1"});
    expect_invalid([] { EEM("", {300}, {350, 360}, {1, 1}); }, {"eem", "name"});
    const EEM e = hand_eem();
    expect_invalid([&] { e.sample_emission(310, 1.5, 0.5); }, {"eem 'hand'", "u1 = 1.5"});
    expect_invalid([&] { e.sample_emission(310, 0.5, -1); }, {"eem 'hand'", "u = -1"});
}

}  // namespace
