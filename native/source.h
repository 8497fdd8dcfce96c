// Light sources. Every source is a set of disk lights emitting into a cone:
// a pencil beam is a disk of radius 0 with a zero cone, a collimated disk has a
// zero cone, the endoscope has two lights. Emission positions, directions and
// wavelengths come from the scrambled Halton sequence indexed by packet number
// (the seed, §4), so the emitted set is deterministic for a seed.
#pragma once
#include <memory>
#include <vector>

#include "halton.h"
#include "vecmath.h"

namespace ep {

class Tabulated1D;

struct Light {
    Vec3 center;                // scene units
    Vec3 axis{0, 0, -1};        // unit emission axis
    Float radius = 0;           // disk radius, scene units; 0 = point
    Float half_angle = 0;       // cone half angle, radians; 0 = collimated
    std::shared_ptr<const Tabulated1D> spectrum;  // relative SPD over nm; null = flat 400-700 nm
};

struct Emission {
    Vec3 position, direction;
    Float wavelength = 0;  // nm; 0 when the run is not spectral
    int light = 0;
};

class Source {
  public:
    explicit Source(std::vector<Light> lights);  // validates (std::invalid_argument naming the field)
    // Packet `index` is emitted by light index % L, from the Halton point index / L,
    // so every light sees a complete low-discrepancy sequence of its own.
    // Inside the cone directions are uniform in solid angle:
    // cos(theta) = 1 - u (1 - cos(half_angle)).
    Emission emit(const Halton& halton, uint64_t index, bool spectral) const;
    const std::vector<Light>& lights() const { return lights_; }

  private:
    std::vector<Light> lights_;
    std::vector<Vec3> u_, v_;  // disk-plane bases
    std::vector<Float> cos_half_;
};

}  // namespace ep
