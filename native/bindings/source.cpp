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

}  // namespace

void bind_source(py::module_& m) {
    py::class_<Source, std::shared_ptr<Source>>(m, "Source")
        .def(py::init([](const std::vector<py::dict>& lights) {
                 std::vector<Light> out;
                 for (const py::dict& d : lights) out.push_back(light_from_dict(d));
                 return std::make_shared<Source>(out);
             }),
             py::arg("lights"));
}

}  // namespace ep::bind
