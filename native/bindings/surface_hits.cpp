// Binding of ep::first_surfaces (native/surface_hits.h): the surface each ray
// sees, in one batch call with the GIL released. Thin: array checks only.
#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>
#include <vector>

#include "common.h"
#include "scene.h"
#include "surface_hits.h"

namespace ep::bind {

namespace {

using Rows = py::array_t<double, py::array::c_style | py::array::forcecast>;

void check_rows(const Rows& a, const char* name) {
    if (a.ndim() != 2 || a.shape(1) != 3)
        throw std::invalid_argument(std::string(name) + " must have shape (N, 3), got ndim " +
                                    std::to_string(a.ndim()));
}

}  // namespace

void bind_surface_hits(py::module_& m) {
    m.def(
        "first_surfaces",
        [](const ep::Scene& scene, Rows origins, Rows directions, py::object tfar, double tnear, int threads) {
            check_rows(origins, "origins");
            check_rows(directions, "directions");
            const py::ssize_t n = origins.shape(0);
            if (directions.shape(0) != n)
                throw std::invalid_argument("directions has " + std::to_string(directions.shape(0)) +
                                            " rows, origins " + std::to_string(n));
            std::vector<double> tf;
            if (!tfar.is_none()) {
                auto a = py::array_t<double, py::array::c_style | py::array::forcecast>::ensure(tfar);
                if (!a || a.ndim() != 1 || a.shape(0) != n)
                    throw std::invalid_argument("tfar must be None or shape (N,) with N = " + std::to_string(n));
                tf.assign(a.data(), a.data() + n);
            }
            py::array_t<double> t(n);
            py::array_t<int32_t> region(n), prim(n);
            py::array_t<double> normal({n, py::ssize_t(3)});
            double* tp = t.mutable_data();
            int32_t* rp = region.mutable_data();
            int32_t* pp = prim.mutable_data();
            double* np_ = normal.mutable_data();
            {
                py::gil_scoped_release release;
                ep::first_surfaces(scene, origins.data(), directions.data(), tf.empty() ? nullptr : tf.data(),
                                   size_t(n), tnear, threads, tp, rp, pp, np_);
            }
            return py::make_tuple(t, region, prim, normal);
        },
        py::arg("scene"), py::arg("origins"), py::arg("directions"), py::arg("tfar") = py::none(),
        py::arg("tnear") = 0.0, py::arg("threads") = 0,
        "First entry into tissue along each ray o + t d: (t (N,), region (N,) int32 (-1 none, -2 the ray "
        "starts inside a region), triangle (N,) int32, outward normal (N,3)). t is in scene units along "
        "the normalised direction; inf where no surface. Releases the GIL.");
}

}  // namespace ep::bind
