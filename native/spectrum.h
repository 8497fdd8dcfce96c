// spectrum.h -- a piecewise-linear, non-negative function of wavelength.
//
// Tabulated1D is the one representation EndoPhoton uses for anything that
// varies with wavelength: a light source's spectrum, a wavelength-dependent
// absorption or scattering coefficient, one emission row of an
// excitation-emission matrix (eem.h).  It is a list of nodes (x_i, y_i) with
// strictly increasing x (nm) joined by straight lines; outside [x_0, x_n] the
// function is 0.
//
// A table with a single node is a *constant*: a wavelength-independent value
// that eval() returns for every x.  Constants are how a plain number such as
// "mua = 20 cm^-1" travels through the same code path as a measured table.
// A constant has no finite integral, so integral(), sample() and pdf() refuse
// it (std::logic_error).
//
// Sampling inverts the exact CDF of the piecewise-linear density: inside a
// segment the CDF is a quadratic in the position, and we solve it in the
// cancellation-free form (see spectrum.cpp), so sample() is an exact
// transform of u, not a fit.
#pragma once

#include <cstddef>
#include <string>
#include <vector>

namespace ep {

// Range of every wavelength an EEM (eem.h) may tabulate, nm: soft X-rays (1 nm) to the far infrared
// (1 mm). Far wider than any optical tissue data, it keeps the spectral energy weight 500 nm / wavelength
// in [5e-4, 500], so that no tally or its variance overflows (1e-300 nm made escaped_energy_stderr = inf).
// The one owner of the rule: the binding exposes them as endophoton._core.MIN_WAVELENGTH_NM and
// MAX_WAVELENGTH_NM, which endophoton.spectra (Spectrum, EEM) checks with, and docs/scene.schema.json's
// spectrum.wavelength_nm carries as its minimum and maximum (tests/python/test_hostile_input.py keeps
// the schema in step).
constexpr double kMinWavelengthNm = 1.0;
constexpr double kMaxWavelengthNm = 1e6;

class Tabulated1D {
  public:
    // Nodes x (nm, strictly increasing, finite) and values y (finite, >= 0;
    // units are the caller's, e.g. cm^-1 or relative power).  `field` names
    // the quantity in error messages, e.g. "region 'tissue': medium.mua".
    // One node = a constant (see above).  Throws std::invalid_argument whose
    // message names field, the offending index and value.
    Tabulated1D(std::vector<double> x, std::vector<double> y, std::string field);

    // A wavelength-independent value (finite, >= 0); eval() returns it for
    // every x.
    static Tabulated1D constant(double value, std::string field = "constant");

    // Linear interpolation between nodes; 0 outside [x_min, x_max].  Same
    // units as y.
    double eval(double x) const;

    // Integral over [x_min, x_max] (y-units x nm).  The trapezoid rule is
    // exact for a piecewise-linear function.  Throws for a constant.
    double integral() const;

    // Maps u in [0, 1] to x (nm) distributed with density eval(x)/integral().
    // Monotone in u; u = 0 gives the left end of the first segment with
    // positive area.  Throws std::invalid_argument for u outside [0, 1] and
    // std::logic_error for a constant or an identically-zero function.
    double sample(double u) const;

    // Density of sample() at x, in nm^-1: eval(x) / integral().
    // Throws std::logic_error for a constant or an identically-zero function.
    double pdf(double x) const;

    // Domain ends in nm; -inf / +inf for a constant.
    double x_min() const;
    double x_max() const;

    bool is_constant() const { return x_.size() == 1; }
    const std::vector<double>& x() const { return x_; }
    const std::vector<double>& y() const { return y_; }
    const std::string& field() const { return field_; }

  private:
    // Index i of the segment [x_i, x_{i+1}] containing x; requires
    // x_min <= x <= x_max and at least two nodes.
    std::size_t segment(double x) const;
    void require_normalisable(const char* what) const;

    std::vector<double> x_, y_;
    std::vector<double> cdf_;  // cdf_[i] = integral of the function over [x_0, x_i]
    std::string field_;
};

}  // namespace ep
