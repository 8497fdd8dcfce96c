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
    Vec3 center;                                  // scene units
    Vec3 axis{0, 0, -1};                          // unit emission axis
    Float radius = 0;                             // disk radius, scene units; 0 = point
    Float half_angle = 0;                         // cone half angle, radians; 0 = collimated
    std::shared_ptr<const Tabulated1D> spectrum;  // relative SPD over nm; null = flat 400-700 nm
};

// The endoscope head as a body (issue 9): an opaque, black cylinder of the
// rig's diameter whose front face carries the light guides and the camera.
// Light that meets it stops: on the camera's aperture (a disk on the front
// face) it is the camera's signal, anywhere else (side, back, front face,
// light guides) it is absorbed by the head ("occluded").
struct RigBody {
    Vec3 front;               // centre of the front face, scene units
    Vec3 axis{0, 0, -1};      // unit viewing axis, out of the front face
    Float radius = 0;         // head radius, scene units
    Float length = 0;         // extent of the cylinder behind the front face, scene units
    Vec3 camera;              // centre of the camera's aperture, on the front face
    Float camera_radius = 0;  // aperture radius, scene units
};

enum class BodyPart { kNone, kHead, kCamera };

struct BodyHit {
    Float t = kInf;  // ray parameter of the first entering hit
    BodyPart part = BodyPart::kNone;
};

// First point where the ray o + t d (unit d, t > 0) enters the body from
// outside: slab test along the axis intersected with the infinite cylinder.
// A ray that starts inside or on the surface moving out (a light on the
// front face emitting forward) does not hit it.
BodyHit intersect_body(const RigBody& b, const Vec3& o, const Vec3& d);

struct Emission {
    Vec3 position, direction;
    Float wavelength = 0;  // nm; 0 when the run is not spectral
    int light = 0;
};

class Source {
  public:
    // Validates (std::invalid_argument naming the field). `body`: the rig head, if any.
    explicit Source(std::vector<Light> lights, const RigBody* body = nullptr);
    // Packet `index` is emitted by light index % L, from the Halton point index / L,
    // so every light sees a complete low-discrepancy sequence of its own.
    // Inside the cone directions are uniform in solid angle:
    // cos(theta) = 1 - u (1 - cos(half_angle)).
    Emission emit(const Halton& halton, uint64_t index, bool spectral) const;
    const std::vector<Light>& lights() const { return lights_; }
    const RigBody* body() const { return has_body_ ? &body_ : nullptr; }

  private:
    std::vector<Light> lights_;
    std::vector<Vec3> u_, v_;  // disk-plane bases
    std::vector<Float> cos_half_;
    bool has_body_ = false;
    RigBody body_;
};

}  // namespace ep
