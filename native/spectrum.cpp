// spectrum.cpp -- Tabulated1D: validation, evaluation, integration, and
// exact inverse-CDF sampling of a piecewise-linear density.
#include "spectrum.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <stdexcept>
#include <utility>

#include "format.h"

namespace ep {

namespace {

std::string fmt(double v) { return format_g(v); }

}  // namespace

Tabulated1D::Tabulated1D(std::vector<double> x, std::vector<double> y, std::string field)
    : x_(std::move(x)), y_(std::move(y)), field_(std::move(field)) {
    if (x_.size() != y_.size())
        throw std::invalid_argument(field_ + ": x has " + std::to_string(x_.size()) + " entries but y has " +
                                    std::to_string(y_.size()) + "; they must have the same length");
    if (x_.empty()) throw std::invalid_argument(field_ + ": needs at least 1 node (1 = constant, >= 2 = table), got 0");
    for (std::size_t i = 0; i < x_.size(); ++i) {
        const std::string at = "[" + std::to_string(i) + "] = ";
        if (!std::isfinite(x_[i])) throw std::invalid_argument(field_ + ": x" + at + fmt(x_[i]) + " must be finite");
        if (!std::isfinite(y_[i])) throw std::invalid_argument(field_ + ": y" + at + fmt(y_[i]) + " must be finite");
        if (y_[i] < 0.0) throw std::invalid_argument(field_ + ": y" + at + fmt(y_[i]) + " must be >= 0");
        if (i > 0 && !(x_[i] > x_[i - 1]))
            throw std::invalid_argument(field_ + ": x" + at + fmt(x_[i]) + " must be greater than x[" +
                                        std::to_string(i - 1) + "] = " + fmt(x_[i - 1]) +
                                        " (x must be strictly increasing)");
    }
    // Running integral at the nodes.  Each segment contributes its trapezoid
    // h (y_i + y_{i+1}) / 2, which is the exact area under a straight line.
    cdf_.assign(x_.size(), 0.0);
    for (std::size_t i = 0; i + 1 < x_.size(); ++i)
        cdf_[i + 1] = cdf_[i] + 0.5 * (x_[i + 1] - x_[i]) * (y_[i] + y_[i + 1]);
}

Tabulated1D Tabulated1D::constant(double value, std::string field) {
    return Tabulated1D({0.0}, {value}, std::move(field));
}

std::size_t Tabulated1D::segment(double x) const {
    const auto it = std::upper_bound(x_.begin(), x_.end(), x);
    std::size_t i = static_cast<std::size_t>(it - x_.begin());
    i = i == 0 ? 0 : i - 1;
    return std::min(i, x_.size() - 2);  // x == x_max belongs to the last segment
}

double Tabulated1D::eval(double x) const {
    if (is_constant()) return y_[0];
    if (!(x >= x_.front() && x <= x_.back())) return 0.0;  // also maps NaN to 0
    const std::size_t i = segment(x);
    const double t = (x - x_[i]) / (x_[i + 1] - x_[i]);
    // (1-t) a + t b rather than a + t (b - a): stays >= 0 for a, b >= 0.
    return (1.0 - t) * y_[i] + t * y_[i + 1];
}

void Tabulated1D::require_normalisable(const char* what) const {
    if (is_constant())
        throw std::logic_error(field_ + ": cannot " + what +
                               " a constant (wavelength-independent) value; it has no finite integral");
    if (!(cdf_.back() > 0.0)) throw std::logic_error(field_ + ": cannot " + what + " a function that is 0 everywhere");
}

double Tabulated1D::integral() const {
    if (is_constant())
        throw std::logic_error(field_ + ": a constant (wavelength-independent) value has no finite integral");
    return cdf_.back();
}

double Tabulated1D::sample(double u) const {
    require_normalisable("sample");
    if (!(u >= 0.0 && u <= 1.0)) throw std::invalid_argument(field_ + ": sample u = " + fmt(u) + " must be in [0, 1]");
    const double total = cdf_.back();
    const double target = u * total;

    // First node whose running integral exceeds the target: the segment just
    // before it has positive area and contains the target.  Zero-area
    // segments are skipped automatically because their two cdf_ values are
    // equal.  target == total (u = 1, or rounding) falls off the end; use
    // the last segment with positive area, at its right end.
    const std::size_t n = x_.size();
    std::size_t k = static_cast<std::size_t>(std::upper_bound(cdf_.begin(), cdf_.end(), target) - cdf_.begin());
    std::size_t i;
    double r;  // area still to cover inside segment i
    if (k >= n) {
        i = n - 2;
        while (i > 0 && !(cdf_[i + 1] > cdf_[i])) --i;
        r = cdf_[i + 1] - cdf_[i];
    } else {
        i = k - 1;  // k >= 1 because cdf_[0] = 0 <= target
        r = target - cdf_[i];
    }

    // Inside the segment, with s = (x - x_i)/h in [0, 1] and the line
    // f(s) = y0 + (y1 - y0) s, the area from the left end is
    //     A(s) = h (y0 s + (y1 - y0) s^2 / 2).
    // A(s) = r is the quadratic  (y1 - y0)/2 s^2 + y0 s - q = 0, q = r/h.
    // The textbook root (-y0 + sqrt(D)) / (y1 - y0) cancels catastrophically
    // when y1 ~ y0 (and is 0/0 on a flat segment); multiplying by the
    // conjugate gives the equivalent, always-stable form
    //     s = 2 q / (y0 + sqrt(y0^2 + 2 (y1 - y0) q)).
    // D >= y1^2 >= 0 for q up to the segment area, so the root is real; the
    // denominator is 0 only when y0 = 0 and q = 0, where s = 0.
    const double h = x_[i + 1] - x_[i];
    const double y0 = y_[i], y1 = y_[i + 1];
    const double q = r / h;
    const double disc = std::max(0.0, y0 * y0 + 2.0 * (y1 - y0) * q);
    const double denom = y0 + std::sqrt(disc);
    double s = denom > 0.0 ? 2.0 * q / denom : 0.0;
    s = std::min(1.0, std::max(0.0, s));
    return x_[i] + s * h;
}

double Tabulated1D::pdf(double x) const {
    require_normalisable("compute the pdf of");
    return eval(x) / cdf_.back();
}

double Tabulated1D::x_min() const { return is_constant() ? -std::numeric_limits<double>::infinity() : x_.front(); }

double Tabulated1D::x_max() const { return is_constant() ? std::numeric_limits<double>::infinity() : x_.back(); }

}  // namespace ep
