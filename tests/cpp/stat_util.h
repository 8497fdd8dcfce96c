// Statistics and assertion helpers shared by the C++ unit tests. References
// are computed independently of the code under test.
#pragma once
#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <functional>
#include <random>
#include <stdexcept>
#include <string>
#include <vector>

namespace ep_test {

// Uniform double in [0, 1) from the top 53 bits of a 64-bit draw.
double uniform(std::mt19937_64& rng) { return static_cast<double>(rng() >> 11) * 0x1.0p-53; }

// Upper-tail standard-normal quantile: z with P(Z > z) = p, by bisection on
// P(Z > z) = erfc(z / sqrt 2) / 2, which is decreasing in z.
double normal_upper_quantile(double p) {
    double lo = -10.0, hi = 10.0;
    for (int it = 0; it < 200; ++it) {
        const double mid = 0.5 * (lo + hi);
        if (0.5 * std::erfc(mid / std::sqrt(2.0)) > p)
            lo = mid;
        else
            hi = mid;
    }
    return 0.5 * (lo + hi);
}

// Wilson-Hilferty: (X/k)^(1/3) is approximately normal with mean 1 - 2/(9k)
// and variance 2/(9k), so the upper-p critical value of chi-square with k
// degrees of freedom is k (1 - 2/(9k) + z_p sqrt(2/(9k)))^3.
double chi_square_critical(int dof, double p) {
    const double k = dof;
    const double z = normal_upper_quantile(p);
    const double a = 2.0 / (9.0 * k);
    return k * std::pow(1.0 - a + z * std::sqrt(a), 3.0);
}

// Draws n samples, bins them on [lo, hi] in `bins` equal bins and runs a
// chi-square test against the expected bin probabilities `prob(a, b)`.
// Bins with zero expected probability must stay empty; they are excluded
// from the statistic.  Requires every used bin to expect >= 5 counts.
inline void expect_chi_square_fit(const std::function<double(std::mt19937_64&)>& draw,
                                  const std::function<double(double, double)>& prob, double lo, double hi, int bins,
                                  int n, std::uint64_t seed) {
    std::mt19937_64 rng(seed);
    std::vector<long> count(bins, 0);
    for (int s = 0; s < n; ++s) {
        const double x = draw(rng);
        ASSERT_GE(x, lo);
        ASSERT_LE(x, hi);
        int b = static_cast<int>((x - lo) / (hi - lo) * bins);
        if (b == bins) b = bins - 1;
        ++count[b];
    }
    double chi2 = 0.0;
    int used = 0;
    for (int b = 0; b < bins; ++b) {
        const double a = lo + (hi - lo) * b / bins, c = lo + (hi - lo) * (b + 1) / bins;
        const double expected = n * prob(a, c);
        if (expected <= 0.0) {
            EXPECT_EQ(count[b], 0) << "bin [" << a << ", " << c << "] has zero probability";
            continue;
        }
        ASSERT_GE(expected, 5.0) << "bin [" << a << ", " << c << "] too small for chi-square";
        chi2 += (count[b] - expected) * (count[b] - expected) / expected;
        ++used;
    }
    ASSERT_GE(used, 2);
    const double critical = chi_square_critical(used - 1, 0.001);
    EXPECT_LT(chi2, critical) << "dof " << used - 1;
}

// Exact integral of the piecewise-linear interpolant of (xs, ys) over [a, b],
// 0 outside [xs.front(), xs.back()].  Independent of Tabulated1D.
double lin_integral(const std::vector<double>& xs, const std::vector<double>& ys, double a, double b) {
    double sum = 0.0;
    for (std::size_t i = 0; i + 1 < xs.size(); ++i) {
        const double lo = std::max(a, xs[i]), hi = std::min(b, xs[i + 1]);
        if (!(hi > lo)) continue;
        auto line = [&](double x) { return ys[i] + (ys[i + 1] - ys[i]) * (x - xs[i]) / (xs[i + 1] - xs[i]); };
        sum += 0.5 * (hi - lo) * (line(lo) + line(hi));
    }
    return sum;
}

// Runs fn, expects std::invalid_argument whose message contains every part.
void expect_invalid(const std::function<void()>& fn, const std::vector<std::string>& parts) {
    try {
        fn();
    } catch (const std::invalid_argument& e) {
        const std::string msg = e.what();
        for (const auto& p : parts) EXPECT_NE(msg.find(p), std::string::npos) << "'" << p << "' not in: " << msg;
        return;
    }
    ADD_FAILURE() << "no std::invalid_argument thrown";
}

}  // namespace ep_test
