#include "source.h"

#include <sstream>
#include <stdexcept>

#include "spectrum.h"

namespace ep {

Source::Source(std::vector<Light> lights) : lights_(std::move(lights)) {
    if (lights_.empty()) throw std::invalid_argument("source.lights is empty");
    for (size_t i = 0; i < lights_.size(); ++i) {
        Light& l = lights_[i];
        std::ostringstream pre;
        pre << "source.lights[" << i << "].";
        if (!is_finite(l.center)) throw std::invalid_argument(pre.str() + "position is not finite");
        const Float len = length(l.axis);
        if (!std::isfinite(len) || len < 1e-12) throw std::invalid_argument(pre.str() + "direction has zero length or is not finite");
        l.axis = l.axis / len;
        if (!std::isfinite(l.radius) || l.radius < 0) {
            std::ostringstream os;
            os << pre.str() << "radius = " << l.radius << " must be >= 0";
            throw std::invalid_argument(os.str());
        }
        if (!std::isfinite(l.half_angle) || l.half_angle < 0 || l.half_angle > kPi / 2) {
            std::ostringstream os;
            os << pre.str() << "half_angle = " << l.half_angle << " rad must be in [0, pi/2]";
            throw std::invalid_argument(os.str());
        }
        Vec3 u, v;
        orthonormal_basis(l.axis, &u, &v);
        u_.push_back(u);
        v_.push_back(v);
        cos_half_.push_back(std::cos(l.half_angle));
    }
}

Emission Source::emit(const Halton& h, uint64_t index, bool spectral) const {
    const uint64_t L = lights_.size();
    const size_t li = size_t(index % L);
    const uint64_t k = index / L;
    const Light& l = lights_[li];
    Emission e;
    e.light = int(li);
    e.position = l.center;
    if (l.radius > 0) {
        // Uniform on the disk: r = R sqrt(u) keeps the area density constant.
        const Float r = l.radius * std::sqrt(h.sample(k, 0));
        const Float phi = 2 * kPi * h.sample(k, 1);
        e.position += u_[li] * (r * std::cos(phi)) + v_[li] * (r * std::sin(phi));
    }
    e.direction = l.axis;
    if (l.half_angle > 0) {
        const Float cos_t = 1 - h.sample(k, 2) * (1 - cos_half_[li]);
        const Float phi = 2 * kPi * h.sample(k, 3);
        e.direction = spherical_about(l.axis, cos_t, std::sin(phi), std::cos(phi));
    }
    if (spectral) {
        const Float u = h.sample(k, 4);
        e.wavelength = l.spectrum ? l.spectrum->sample(u) : 400 + 300 * u;
    }
    return e;
}

}  // namespace ep
