// endophoton._core._testing: hooks that only the tests use, to check the
// engine's samplers and scene queries against references (not part of the API).
#include <array>
#include <cmath>
#include <stdexcept>

#include "common.h"
#include "fresnel.h"
#include "halton.h"
#include "phase.h"
#include "rng.h"
#include "scene.h"
#include "source.h"

namespace ep::bind {

void bind_testing(py::module_& m) {
    m.def(
        "sample_hg_cos",
        [](double g, uint64_t n, uint64_t seed) {
            if (!std::isfinite(g) || g < -1 || g > 1)
                throw std::invalid_argument("g = " + std::to_string(g) + " must be in [-1, 1]");
            std::vector<double> out(n);
            {
                py::gil_scoped_release release;
                const HenyeyGreenstein hg(g);
                Rng rng(seed, 0);
                for (uint64_t i = 0; i < n; ++i) out[i] = hg.sample_cos(rng.uniform());
            }
            return take(std::move(out), {py::ssize_t(n)});
        },
        py::arg("g"), py::arg("n"), py::arg("seed") = 1, "n samples of cos(theta) from the engine's HG sampler.");
    m.def(
        "fresnel",
        [](double cos_i, double n1, double n2) {
            double ct;
            return fresnel_dielectric(cos_i, n1, n2, &ct);
        },
        py::arg("cos_i"), py::arg("n1"), py::arg("n2"), "Unpolarised Fresnel reflectance (1 under TIR).");
    m.def(
        "emit",
        [](const Source& s, uint64_t seed, uint64_t first, uint64_t count, bool spectral) {
            const Halton h(seed);
            std::vector<double> pos, dir, wl;
            std::vector<int32_t> light;
            for (uint64_t k = first; k < first + count; ++k) {
                const Emission e = s.emit(h, k, spectral);
                pos.insert(pos.end(), {e.position.x, e.position.y, e.position.z});
                dir.insert(dir.end(), {e.direction.x, e.direction.y, e.direction.z});
                wl.push_back(e.wavelength);
                light.push_back(e.light);
            }
            const py::ssize_t n = py::ssize_t(count);
            return py::make_tuple(take(std::move(pos), {n, 3}), take(std::move(dir), {n, 3}), take(std::move(wl), {n}),
                                  take(std::move(light), {n}));
        },
        py::arg("source"), py::arg("seed"), py::arg("first"), py::arg("count"), py::arg("spectral") = false,
        "Emission samples of packets first..first+count (positions, directions, wavelengths, light).");
    m.def(
        "intersect_all",
        [](const Scene& s, std::array<double, 3> o, std::array<double, 3> d, double tnear, double tfar) {
            std::vector<Hit> hits;
            s.intersect_all(Vec3(o[0], o[1], o[2]), normalize(Vec3(d[0], d[1], d[2])), tnear, tfar, hits);
            py::list out;
            for (const Hit& h : hits) out.append(py::make_tuple(h.t, h.region, h.prim, h.cos_dn));
            return out;
        },
        py::arg("scene"), py::arg("origin"), py::arg("direction"), py::arg("tnear"), py::arg("tfar"),
        "Every crossing (t, region, triangle, cos) along a ray.");
    m.def(
        "distance_to_surface",
        [](const Scene& s, std::array<double, 3> p, double radius) {
            return s.distance_to_surface(Vec3(p[0], p[1], p[2]), radius);
        },
        py::arg("scene"), py::arg("point"), py::arg("radius"), "Distance to the closest surface within radius.");
}

}  // namespace ep::bind
