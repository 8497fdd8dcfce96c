// The rules a user's spectrum (endophoton.Spectrum) and excitation-emission
// matrix (endophoton.EEM, ep::EEM) must follow, in one place: the package
// calls them through the binding (endophoton._core.check_spectrum,
// check_eem) before it keeps the arrays, and ep::EEM's constructor calls
// check_eem. Each throws std::invalid_argument naming the owner, the field,
// the index and the value.
#pragma once
#include <cstddef>
#include <string>
#include <vector>

namespace ep {

// An array as the caller holds it: its values (row-major) and its shape.
struct ShapedValues {
    const double* data = nullptr;
    std::vector<size_t> shape;
    size_t size() const;
};

// wavelength_nm: 1-D, >= 2 entries, finite, in [kMinWavelengthNm,
// kMaxWavelengthNm] (spectrum.h), strictly increasing; values: 1-D, as many,
// finite, >= 0. Messages start "spectrum '<name>': ".
void check_spectrum(const std::string& name, const ShapedValues& wavelength_nm, const ShapedValues& values);

// excitation_nm: n_ex >= 1 wavelengths, emission_nm: n_em >= 2 (the rules of
// check_spectrum's wavelengths); values: n_ex x n_em entries of shape
// (n_ex, n_em), finite, >= 0, at least one > 0; name not empty. Messages
// start "eem '<name>': ".
void check_eem(const std::string& name, const ShapedValues& excitation_nm, const ShapedValues& emission_nm,
               const ShapedValues& values);

}  // namespace ep
