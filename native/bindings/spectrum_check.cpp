// Binding of ep::check_spectrum and ep::check_eem (native/spectrum_check.h),
// the one owner of the spectrum and EEM rules (endophoton.spectra's Spectrum
// and EEM call them). Arrays arrive as float64 with their shapes, which the
// rules check too.
#include "spectrum_check.h"

#include "common.h"

namespace ep::bind {

namespace {

using DoubleArray = py::array_t<double, py::array::c_style | py::array::forcecast>;

ShapedValues shaped(const DoubleArray& a) {
    ShapedValues v;
    v.data = a.data();
    for (py::ssize_t k = 0; k < a.ndim(); ++k) v.shape.push_back(size_t(a.shape(k)));
    return v;
}

}  // namespace

void bind_spectrum_check(py::module_& m) {
    m.def(
        "check_spectrum",
        [](const std::string& name, DoubleArray wavelength_nm, DoubleArray values) {
            check_spectrum(name, shaped(wavelength_nm), shaped(values));
        },
        py::arg("name"), py::arg("wavelength_nm"), py::arg("values"),
        "Check a spectrum: wavelength_nm (nm) 1-D, >= 2 entries, finite, in [MIN_WAVELENGTH_NM, MAX_WAVELENGTH_NM], "
        "strictly increasing; values 1-D, as many, finite, >= 0. Raises ValueError naming the spectrum, the field, "
        "the index and the value.");
    m.def(
        "check_eem",
        [](const std::string& name, DoubleArray excitation_nm, DoubleArray emission_nm, DoubleArray values) {
            check_eem(name, shaped(excitation_nm), shaped(emission_nm), shaped(values));
        },
        py::arg("name"), py::arg("excitation_nm"), py::arg("emission_nm"), py::arg("values"),
        "Check an excitation-emission matrix: excitation_nm (nm) >= 1 and emission_nm (nm) >= 2 wavelengths as for "
        "check_spectrum, values of shape (n_ex, n_em), finite, >= 0, at least one > 0, name not empty. Raises "
        "ValueError naming the EEM, the field, the index and the value.");
}

}  // namespace ep::bind
