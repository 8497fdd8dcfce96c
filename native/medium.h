// Optical properties of a region (MCML's layer parameters, the seed's §3).
// mua and mus are in cm^-1 whatever the scene's length unit; g and n are
// dimensionless. Either coefficient may instead be a table over wavelength.
#pragma once
#include <memory>
#include <string>

#include "vecmath.h"

namespace ep {

class Tabulated1D;

struct Medium {
    Float mua = 0;                                 // absorption coefficient, cm^-1 (used when mua_table is null)
    Float mus = 0;                                 // scattering coefficient, cm^-1
    Float g = 0;                                   // HG anisotropy, [-1, 1]
    Float n = 1;                                   // refractive index, >= 1
    std::shared_ptr<const Tabulated1D> mua_table;  // optional, over wavelength in nm
    std::shared_ptr<const Tabulated1D> mus_table;

    bool spectral() const { return mua_table || mus_table; }
    // Coefficients at wavelength lambda_nm (tables are evaluated, constants returned).
    Float mua_at(Float lambda_nm) const;
    Float mus_at(Float lambda_nm) const;
    // Throws std::invalid_argument naming `owner` (e.g. "region 'tissue'"), the field and the value.
    void validate(const std::string& owner) const;
};

}  // namespace ep
