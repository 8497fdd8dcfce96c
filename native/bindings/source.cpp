// Binding of ep::Source: lights given as dicts (position, direction, radius,
// half_angle in radians, optional spectrum table), as endophoton.sources builds them.
#include <array>

#include "common.h"
#include "source.h"

namespace ep::bind {

namespace {

Light light_from_dict(const py::dict& d) {
    Light l;
    auto c = d["position"].cast<std::array<double, 3>>();
    auto a = d["direction"].cast<std::array<double, 3>>();
    l.center = Vec3(c[0], c[1], c[2]);
    l.axis = Vec3(a[0], a[1], a[2]);
    l.radius = d.contains("radius") ? d["radius"].cast<double>() : 0.0;
    l.half_angle = d.contains("half_angle") ? d["half_angle"].cast<double>() : 0.0;
    if (d.contains("spectrum")) l.spectrum = table_or_null(d["spectrum"], "source.spectrum");
    return l;
}

// The rig head (source.h RigBody) from {front, axis, radius, length, camera, camera_radius}.
RigBody rig_body_from_dict(const py::dict& d) {
    auto vec = [&](const char* k) {
        const auto a = d[k].cast<std::array<double, 3>>();
        return Vec3(a[0], a[1], a[2]);
    };
    RigBody b;
    b.front = vec("front");
    b.axis = vec("axis");
    b.camera = vec("camera");
    b.radius = d["radius"].cast<double>();
    b.length = d["length"].cast<double>();
    b.camera_radius = d["camera_radius"].cast<double>();
    return b;
}

}  // namespace

void bind_source(py::module_& m) {
    py::class_<Source, std::shared_ptr<Source>>(m, "Source")
        .def(py::init([](const std::vector<py::dict>& lights, const py::object& body) {
                 std::vector<Light> out;
                 for (const py::dict& d : lights) out.push_back(light_from_dict(d));
                 if (body.is_none()) return std::make_shared<Source>(out);
                 const RigBody b = rig_body_from_dict(body.cast<py::dict>());
                 return std::make_shared<Source>(out, &b);
             }),
             py::arg("lights"), py::arg("body") = py::none());
}

}  // namespace ep::bind
