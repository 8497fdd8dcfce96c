// eem.cpp -- EEM: validation, excitation efficiency and emission sampling.
#include "eem.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <stdexcept>
#include <utility>

#include "format.h"
#include "spectrum_check.h"

namespace ep {

namespace {

std::string fmt(double v) { return format_g(v); }

}  // namespace

EEM::EEM(std::string name, std::vector<double> excitation_nm, std::vector<double> emission_nm,
         std::vector<double> values)
    : name_(std::move(name)),
      excitation_(std::move(excitation_nm)),
      emission_(std::move(emission_nm)),
      values_(std::move(values)) {
    const std::size_t n_ex = excitation_.size(), n_em = emission_.size();
    // Row-major n_ex x n_em when the count fits (check_eem names a wrong count).
    const std::vector<size_t> shape =
        values_.size() == n_ex * n_em ? std::vector<size_t>{n_ex, n_em} : std::vector<size_t>{values_.size()};
    check_eem(name_, {excitation_.data(), {n_ex}}, {emission_.data(), {n_em}}, {values_.data(), shape});
    const std::string where = "eem '" + name_ + "': ";

    rows_.reserve(n_ex);
    row_integral_.reserve(n_ex);
    for (std::size_t i = 0; i < n_ex; ++i) {
        std::vector<double> row(values_.begin() + static_cast<std::ptrdiff_t>(i * n_em),
                                values_.begin() + static_cast<std::ptrdiff_t>((i + 1) * n_em));
        rows_.emplace_back(emission_, std::move(row), where + "row ex " + fmt(excitation_[i]) + " nm");
        row_integral_.push_back(rows_.back().integral());
        max_row_integral_ = std::max(max_row_integral_, row_integral_.back());
    }
}

double EEM::efficiency(double lambda_ex) const {
    if (!(lambda_ex >= excitation_.front() && lambda_ex <= excitation_.back())) return 0.0;
    if (excitation_.size() == 1) return 1.0;  // lambda_ex is the one tabulated row
    // I(lambda_ex) is linear between rows because integration over emission
    // commutes with the linear interpolation in excitation.
    const auto it = std::upper_bound(excitation_.begin(), excitation_.end(), lambda_ex);
    const std::size_t i = std::min(static_cast<std::size_t>(it - excitation_.begin()) - 1, excitation_.size() - 2);
    const double t = (lambda_ex - excitation_[i]) / (excitation_[i + 1] - excitation_[i]);
    const double I = (1.0 - t) * row_integral_[i] + t * row_integral_[i + 1];
    return std::min(1.0, I / max_row_integral_);
}

EEM::RowMix EEM::mix(double lambda_ex) const {
    const std::size_t n_ex = excitation_.size();
    // Clamp to the tabulated excitation range (see eem.h).  NaN goes to the
    // first row rather than propagating into an index.
    double lam = std::isnan(lambda_ex) ? excitation_.front() : lambda_ex;
    lam = std::min(excitation_.back(), std::max(excitation_.front(), lam));

    if (n_ex > 1) {
        const auto it = std::upper_bound(excitation_.begin(), excitation_.end(), lam);
        const std::size_t i = std::min(static_cast<std::size_t>(it - excitation_.begin()) - 1, n_ex - 2);
        const double t = (lam - excitation_[i]) / (excitation_[i + 1] - excitation_[i]);
        // The interpolated row (1-t) F_i + t F_{i+1}, normalised, is the
        // mixture of the normalised rows with weights (1-t) I_i and t I_{i+1}.
        const double w0 = (1.0 - t) * row_integral_[i];
        const double w1 = t * row_integral_[i + 1];
        if (w0 + w1 > 0.0) return {i, i + 1, w0 / (w0 + w1), w1 / (w0 + w1)};
    } else if (row_integral_[0] > 0.0) {
        return {0, 0, 1.0, 0.0};
    }

    // The row at lam does not emit: nearest emitting row (shorter on a tie).
    std::size_t best = 0;
    double best_dist = std::numeric_limits<double>::infinity();
    for (std::size_t k = 0; k < n_ex; ++k) {
        if (!(row_integral_[k] > 0.0)) continue;
        const double dist = std::fabs(excitation_[k] - lam);
        if (dist < best_dist) {
            best = k;
            best_dist = dist;
        }
    }
    return {best, best, 1.0, 0.0};
}

double EEM::sample_emission(double lambda_ex, double u1, double u2) const {
    if (!(u1 >= 0.0 && u1 <= 1.0))
        throw std::invalid_argument("eem '" + name_ + "': sample_emission u1 = " + fmt(u1) + " must be in [0, 1]");
    const RowMix m = mix(lambda_ex);
    // Row i1 only if it carries probability: with p0 = 1 a u1 of exactly 1
    // must not pick a row that does not emit.
    const std::size_t row = (m.p1 > 0.0 && u1 >= m.p0) ? m.i1 : m.i0;
    return rows_[row].sample(u2);
}

double EEM::emission_pdf(double lambda_ex, double lambda_em) const {
    const RowMix m = mix(lambda_ex);
    double p = 0.0;
    if (m.p0 > 0.0) p += m.p0 * rows_[m.i0].pdf(lambda_em);
    if (m.p1 > 0.0) p += m.p1 * rows_[m.i1].pdf(lambda_em);
    return p;
}

}  // namespace ep
