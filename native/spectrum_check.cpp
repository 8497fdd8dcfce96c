#include "spectrum_check.h"

#include <cmath>
#include <stdexcept>

#include "format.h"
#include "spectrum.h"

namespace ep {

namespace {

std::string fmt(double v) { return format_g(v); }

// A shape as Python prints a tuple: (3, 5), (15,), ().
std::string shape_text(const std::vector<size_t>& shape) {
    std::string s = "(";
    for (size_t k = 0; k < shape.size(); ++k) s += (k ? ", " : "") + std::to_string(shape[k]);
    return s + (shape.size() == 1 ? ",)" : ")");
}

void check_wavelengths(const std::string& where, const char* field, const ShapedValues& a, size_t min_size) {
    if (a.shape.size() != 1)
        throw std::invalid_argument(where + field + " must be 1-D, got shape " + shape_text(a.shape));
    const double* w = a.data;
    const size_t n = a.size();
    if (n < min_size)
        throw std::invalid_argument(where + field + " needs at least " + std::to_string(min_size) +
                                    (min_size == 1 ? " entry" : " entries") + ", got " + std::to_string(n));
    for (size_t i = 0; i < n; ++i) {
        const std::string at = std::string(field) + "[" + std::to_string(i) + "] = " + fmt(w[i]);
        if (!std::isfinite(w[i])) throw std::invalid_argument(where + at + " must be finite");
        if (!(w[i] > 0.0)) throw std::invalid_argument(where + at + " must be > 0");
        if (!(w[i] >= kMinWavelengthNm && w[i] <= kMaxWavelengthNm))
            throw std::invalid_argument(where + at + " is outside [" + fmt(kMinWavelengthNm) + ", " +
                                        fmt(kMaxWavelengthNm) + "] nm (soft X-rays to the far infrared)");
        if (i > 0 && !(w[i] > w[i - 1]))
            throw std::invalid_argument(where + at + " must be greater than " + field + "[" + std::to_string(i - 1) +
                                        "] = " + fmt(w[i - 1]) + " (wavelengths must be strictly increasing)");
    }
}

// "must be finite" or "must be >= 0" for a value that breaks the rule, else null.
const char* value_fault(double v) {
    if (!std::isfinite(v)) return "must be finite";
    if (v < 0.0) return "must be >= 0";
    return nullptr;
}

}  // namespace

size_t ShapedValues::size() const {
    size_t n = 1;
    for (size_t s : shape) n *= s;
    return n;
}

void check_spectrum(const std::string& name, const ShapedValues& wavelength_nm, const ShapedValues& values) {
    const std::string where = "spectrum '" + name + "': ";
    check_wavelengths(where, "wavelength_nm", wavelength_nm, 2);
    if (values.shape.size() != 1)
        throw std::invalid_argument(where + "values must be 1-D, got shape " + shape_text(values.shape));
    const size_t n = wavelength_nm.size();
    if (values.size() != n)
        throw std::invalid_argument(where + "wavelength_nm has " + std::to_string(n) + " entries but values has " +
                                    std::to_string(values.size()) + "; they must have the same length");
    for (size_t i = 0; i < n; ++i)
        if (const char* fault = value_fault(values.data[i]))
            throw std::invalid_argument(where + "values[" + std::to_string(i) + "] = " + fmt(values.data[i]) + " " +
                                        fault);
}

void check_eem(const std::string& name, const ShapedValues& excitation_nm, const ShapedValues& emission_nm,
               const ShapedValues& values) {
    if (name.empty()) throw std::invalid_argument("eem: name must not be empty");
    const std::string where = "eem '" + name + "': ";
    check_wavelengths(where, "excitation_nm", excitation_nm, 1);
    check_wavelengths(where, "emission_nm", emission_nm, 2);
    const size_t n_ex = excitation_nm.size(), n_em = emission_nm.size();
    const std::string grid = std::to_string(n_ex) + " x " + std::to_string(n_em);
    if (values.size() != n_ex * n_em)
        throw std::invalid_argument(where + "values has " + std::to_string(values.size()) + " entries, expected " +
                                    grid + " = " + std::to_string(n_ex * n_em));
    if (values.shape != std::vector<size_t>{n_ex, n_em})
        throw std::invalid_argument(where + "values has shape " + shape_text(values.shape) + ", expected " + grid +
                                    " (n_ex x n_em)");
    bool any_positive = false;
    for (size_t i = 0; i < n_ex; ++i)
        for (size_t j = 0; j < n_em; ++j) {
            const double v = values.data[i * n_em + j];
            if (const char* fault = value_fault(v))
                throw std::invalid_argument(where + "values[" + std::to_string(i) + "][" + std::to_string(j) +
                                            "] (ex " + fmt(excitation_nm.data[i]) + " nm, em " +
                                            fmt(emission_nm.data[j]) + " nm) = " + fmt(v) + " " + fault);
            any_positive = any_positive || v > 0.0;
        }
    if (!any_positive) throw std::invalid_argument(where + "values are all 0; at least one must be positive");
}

}  // namespace ep
