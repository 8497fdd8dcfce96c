// Dielectric boundary: Snell's law and the unpolarised Fresnel reflectance,
// with total internal reflection handled explicitly (pbrt-v4 style).
#pragma once
#include <cmath>

#include "vecmath.h"

namespace ep {

// Reflectance for light going from index n1 into n2 with incidence cosine
// cos_i in [0, 1]. Writes the transmitted cosine to *cos_t (0 under TIR).
// R = (rs^2 + rp^2) / 2 with rs = (n1 ci - n2 ct)/(n1 ci + n2 ct) and
// rp = (n2 ci - n1 ct)/(n2 ci + n1 ct); this equals the oracle's
// 1/2 [sin^2(i-t)/sin^2(i+t) + tan^2(i-t)/tan^2(i+t)] but stays finite at
// normal incidence, where the sine form is 0/0.
inline Float fresnel_dielectric(Float cos_i, Float n1, Float n2, Float* cos_t) {
    cos_i = std::clamp(cos_i, Float(0), Float(1));
    const Float eta = n1 / n2;
    const Float sin2_t = eta * eta * std::max(Float(0), 1 - cos_i * cos_i);
    if (sin2_t >= 1) {  // total internal reflection beyond asin(n2/n1)
        *cos_t = 0;
        return 1;
    }
    const Float ct = std::sqrt(1 - sin2_t);
    *cos_t = ct;
    if (cos_i == 0) return 1;  // grazing incidence reflects everything
    const Float rs = (n1 * cos_i - n2 * ct) / (n1 * cos_i + n2 * ct);
    const Float rp = (n2 * cos_i - n1 * ct) / (n2 * cos_i + n1 * ct);
    return Float(0.5) * (rs * rs + rp * rp);
}

// Mirror direction d about the unit normal n.
inline Vec3 reflect(const Vec3& d, const Vec3& n) { return d - n * (2 * dot(d, n)); }

// Refracted direction for unit d hitting a surface whose unit normal n faces
// the incident side (dot(d, n) = -cos_i < 0); eta = n1/n2 (Snell: n1 sin i = n2 sin t).
inline Vec3 refract(const Vec3& d, const Vec3& n, Float eta, Float cos_i, Float cos_t) {
    Vec3 t = d * eta + n * (eta * cos_i - cos_t);
    return t / length(t);
}

}  // namespace ep
