#include "source.h"

#include <sstream>
#include <stdexcept>

#include "det_math.h"
#include "spectrum.h"

namespace ep {

namespace {

void check_positive(const char* field, Float v, bool allow_zero) {
    if (std::isfinite(v) && (v > 0 || (allow_zero && v == 0))) return;
    std::ostringstream os;
    os << "source.body." << field << " = " << v << (allow_zero ? " must be >= 0" : " must be > 0");
    throw std::invalid_argument(os.str());
}

RigBody checked_body(RigBody b) {
    if (!is_finite(b.front)) throw std::invalid_argument("source.body.front is not finite");
    if (!is_finite(b.camera)) throw std::invalid_argument("source.body.camera is not finite");
    const Float len = length(b.axis);
    if (!std::isfinite(len) || len < 1e-12)
        throw std::invalid_argument("source.body.axis has zero length or is not finite");
    b.axis = b.axis / len;
    check_positive("radius", b.radius, false);
    check_positive("length", b.length, false);
    check_positive("camera_radius", b.camera_radius, true);
    // The aperture lies on the front face: project its centre onto the face.
    b.camera -= b.axis * dot(b.camera - b.front, b.axis);
    if (length(b.camera - b.front) + b.camera_radius > b.radius * (1 + 1e-9)) {
        std::ostringstream os;
        os << "source.body.camera_radius = " << b.camera_radius << " puts the aperture outside the head (radius "
           << b.radius << ")";
        throw std::invalid_argument(os.str());
    }
    return b;
}

}  // namespace

BodyHit intersect_body(const RigBody& b, const Vec3& o, const Vec3& d) {
    BodyHit hit;
    const Vec3 rel = o - b.front;
    const Float oa = dot(rel, b.axis), da = dot(d, b.axis);
    // Axial slab: -length <= oa + t da <= 0.
    Float t0 = -kInf, t1 = kInf;
    int enter_face = 0;  // which bound entered last: 1 front face, 2 back face, 3 side
    if (da != 0) {
        const Float ta = (-b.length - oa) / da, tb = -oa / da;
        t0 = std::min(ta, tb);
        t1 = std::max(ta, tb);
        enter_face = da < 0 ? 1 : 2;
    } else if (oa > 0 || oa < -b.length) {
        return hit;
    }
    // Infinite cylinder: |r + t dr|^2 <= radius^2 with r, dr perpendicular to the axis.
    const Vec3 r = rel - b.axis * oa, dr = d - b.axis * da;
    const Float A = dot(dr, dr), B = dot(r, dr), C = dot(r, r) - b.radius * b.radius;
    if (A > 0) {
        const Float disc = B * B - A * C;
        if (disc < 0) return hit;
        const Float q = std::sqrt(disc);
        const Float c0 = (-B - q) / A, c1 = (-B + q) / A;
        if (c0 > t0) {
            t0 = c0;
            enter_face = 3;
        }
        t1 = std::min(t1, c1);
    } else if (C > 0) {
        return hit;  // parallel to the axis, outside the radius
    }
    if (!(t0 < t1) || t0 <= 0) return hit;  // missed, or started inside / leaving it
    hit.t = t0;
    hit.part = BodyPart::kHead;
    if (enter_face == 1) {
        const Vec3 q = o + d * t0 - b.camera;
        if (dot(q, q) < b.camera_radius * b.camera_radius) hit.part = BodyPart::kCamera;
    }
    return hit;
}

Source::Source(std::vector<Light> lights, const RigBody* body) : lights_(std::move(lights)) {
    if (body) {
        body_ = checked_body(*body);
        has_body_ = true;
    }
    if (lights_.empty()) throw std::invalid_argument("source.lights is empty");
    for (size_t i = 0; i < lights_.size(); ++i) {
        Light& l = lights_[i];
        std::ostringstream pre;
        pre << "source.lights[" << i << "].";
        if (!is_finite(l.center)) throw std::invalid_argument(pre.str() + "position is not finite");
        const Float len = length(l.axis);
        if (!std::isfinite(len) || len < 1e-12)
            throw std::invalid_argument(pre.str() + "direction has zero length or is not finite");
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
        cos_half_.push_back(det_cos(l.half_angle));
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
        Float sin_phi, cos_phi;
        det_sincos(2 * kPi * h.sample(k, 1), &sin_phi, &cos_phi);
        e.position += u_[li] * (r * cos_phi) + v_[li] * (r * sin_phi);
    }
    e.direction = l.axis;
    if (l.half_angle > 0) {
        const Float cos_t = 1 - h.sample(k, 2) * (1 - cos_half_[li]);
        Float sin_phi, cos_phi;
        det_sincos(2 * kPi * h.sample(k, 3), &sin_phi, &cos_phi);
        e.direction = spherical_about(l.axis, cos_t, sin_phi, cos_phi);
    }
    if (spectral) {
        const Float u = h.sample(k, 4);
        e.wavelength = l.spectrum ? l.spectrum->sample(u) : 400 + 300 * u;
    }
    return e;
}

}  // namespace ep
