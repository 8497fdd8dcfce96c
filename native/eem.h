// eem.h -- excitation-emission matrix of one fluorophore.
//
// An EEM F(lambda_ex, lambda_em) is the fluorescence a fluorophore emits at
// lambda_em when excited at lambda_ex, in relative units (only ratios
// matter).  It is tabulated on an excitation grid (rows) and an emission grid
// (columns); between rows it is interpolated linearly in lambda_ex, and each
// row is piecewise linear in lambda_em (Tabulated1D).
//
// Two quantities are derived from it (docs/fluorescence.md):
//
//   row integral  I(lambda_ex) = integral of F(lambda_ex, lambda_em) d lambda_em
//                 (linear in lambda_ex between rows, so it is the linear
//                 interpolation of the per-row integrals I_i)
//   efficiency    eta(lambda_ex) = I(lambda_ex) / max_i I_i,   in [0, 1],
//                 0 outside the tabulated excitation range
//
// eta is the relative excitation efficiency the "eem" fluorescence rule uses;
// the emission wavelength of a fluorescence event is drawn from the
// normalised row F(lambda_ex, .) / I(lambda_ex).
//
// Excitation outside the tabulated range.  The seed paper's rule decides
// *whether* a packet fluoresces from d and c alone, so a white-light packet
// may fluoresce at a wavelength the EEM does not tabulate (e.g. collagen,
// tabulated from 250 nm, hit at 700 nm is inside; a user EEM measured only
// up to 520 nm, hit at 600 nm, is not).  For sampling, lambda_ex is
// therefore clamped to [excitation_nm.front(), excitation_nm.back()]: the
// emission shape of the nearest tabulated row is used.  efficiency() is NOT
// clamped: it is 0 outside the range, so the "eem" rule never fluoresces
// there.
//
// Rows that do not emit.  If the (interpolated) row at lambda_ex has zero
// integral, sampling uses the nearest tabulated row (in excitation
// wavelength; the shorter one on a tie) that has a positive integral.  The
// constructor guarantees such a row exists.  With the default EEMs
// (data/eem) every row emits, so this never happens there; with a measured
// EEM it can yield emission shorter than lambda_ex (documented in
// docs/fluorescence.md).
#pragma once

#include <cstddef>
#include <string>
#include <vector>

#include "spectrum.h"

namespace ep {

class EEM {
  public:
    // excitation_nm: n_ex >= 1 wavelengths (nm, finite, in [kMinWavelengthNm,
    // kMaxWavelengthNm] = [1, 1e6] (spectrum.h), strictly increasing);
    // emission_nm: n_em >= 2 such wavelengths; values: row-major
    // n_ex x n_em relative fluorescence (finite, >= 0, at least one > 0).
    // Throws std::invalid_argument naming the EEM, the field and the value,
    // e.g. "eem 'collagen': values has 12 entries, expected 3 x 5 = 15".
    EEM(std::string name, std::vector<double> excitation_nm, std::vector<double> emission_nm,
        std::vector<double> values);

    // Relative excitation efficiency eta(lambda_ex) in [0, 1] (see above);
    // lambda_ex in nm.  0 outside the excitation range.
    double efficiency(double lambda_ex) const;

    // Emission wavelength (nm) drawn from the EEM row at lambda_ex (nm).
    // Between tabulated rows i and i+1 with weight t, row i+1 is chosen when
    // u1 >= (1-t) I_i / ((1-t) I_i + t I_{i+1}) -- i.e. with probability
    // proportional to t I_{i+1} -- and the emission is then sampled inside
    // that row with u2.  This mixture has exactly the density of the
    // linearly interpolated, normalised row.  lambda_ex is clamped to the
    // excitation range (see above).  u1, u2 in [0, 1].
    double sample_emission(double lambda_ex, double u1, double u2) const;

    // Density (nm^-1) of sample_emission's result at lambda_em, for the same
    // lambda_ex: ((1-t) F_i(lambda_em) + t F_{i+1}(lambda_em)) /
    // ((1-t) I_i + t I_{i+1}), or the fallback row's density (see above).
    double emission_pdf(double lambda_ex, double lambda_em) const;

    const std::string& name() const { return name_; }
    const std::vector<double>& excitation_nm() const { return excitation_; }
    const std::vector<double>& emission_nm() const { return emission_; }
    const std::vector<double>& values() const { return values_; }  // row-major
    std::size_t n_excitation() const { return excitation_.size(); }
    std::size_t n_emission() const { return emission_.size(); }
    double value(std::size_t i_ex, std::size_t i_em) const { return values_[i_ex * emission_.size() + i_em]; }
    // Integral over emission of row i, I_i (value units x nm).
    double row_integral(std::size_t i_ex) const { return row_integral_[i_ex]; }

  private:
    // The rows (at most two) that make up the emission distribution at
    // lambda_ex and their selection probabilities p0 + p1 = 1.
    struct RowMix {
        std::size_t i0, i1;
        double p0, p1;
    };
    RowMix mix(double lambda_ex) const;

    std::string name_;
    std::vector<double> excitation_, emission_, values_;
    std::vector<Tabulated1D> rows_;
    std::vector<double> row_integral_;
    double max_row_integral_ = 0.0;
};

}  // namespace ep
