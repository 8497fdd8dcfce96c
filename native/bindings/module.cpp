// endophoton._core: a thin layer over the core library. It converts numpy
// arrays and keyword arguments, releases the GIL for the run, and hands result
// columns back as numpy arrays that own their memory through capsules.
// No physics lives here. One file per bound interface (Mitsuba 3 style):
// scene.cpp, source.cpp, run.cpp, mesh_check.cpp, spectrum_check.cpp,
// surface_hits.cpp, exit_gather.cpp, distributed.cpp, det_math.cpp; hooks that only tests use
// live in the submodule endophoton._core._testing (testing.cpp).
#include <stdexcept>

#include "common.h"
#include "engine.h"
#include "spectrum.h"
#include "tally.h"

namespace ep::bind {

std::shared_ptr<const Tabulated1D> table_or_null(const py::object& obj, const std::string& field) {
    if (obj.is_none()) return nullptr;
    auto tup = obj.cast<std::pair<std::vector<double>, std::vector<double>>>();
    return std::make_shared<Tabulated1D>(tup.first, tup.second, field);
}

void require_rows_of_3(const py::array& a, const std::string& what) {
    if (a.ndim() != 2 || a.shape(1) != 3)
        throw std::invalid_argument(what + " must have shape (N, 3), got ndim " + std::to_string(a.ndim()));
}

}  // namespace ep::bind

PYBIND11_MODULE(_core, m) {
    namespace py = pybind11;
    m.doc() = "EndoPhoton native engine (thin binding; use the endophoton package API)";
    m.attr("__version__") = ep::engine_version();
    py::register_exception<std::invalid_argument>(m, "InvalidArgument", PyExc_ValueError);
    m.attr("MAX_REGIONS") = int(ep::Scene::kMaxRegions);
    m.attr("MAX_PACKET_REQUEST") = ep::kMaxPacketRequest;
    m.attr("DEFAULT_TARGET_MAX_PACKETS") = ep::kDefaultTargetMaxPackets;
    m.attr("DEFAULT_CACHE_STORE_BYTES") = ep::Scene::kDefaultStoreCapBytes;
    // The wavelength range (nm) of native/spectrum.h, which endophoton.spectra checks with.
    m.attr("MIN_WAVELENGTH_NM") = ep::kMinWavelengthNm;
    m.attr("MAX_WAVELENGTH_NM") = ep::kMaxWavelengthNm;
    // Read-only: the names of the balance tallies (native/tally.h), for the package's tests.
    py::tuple balance(ep::kBalanceTallies);
    for (int i = 0; i < ep::kBalanceTallies; ++i) balance[i] = ep::tally_name(i);
    m.attr("BALANCE_TALLIES") = balance;
    ep::bind::bind_scene(m);
    ep::bind::bind_source(m);
    ep::bind::bind_camera_view(m);  // before bind_run: RunConfig.camera_view takes a CameraView
    ep::bind::bind_run(m);
    ep::bind::bind_mesh_check(m);
    ep::bind::bind_spectrum_check(m);
    ep::bind::bind_surface_hits(m);
    ep::bind::bind_exit_gather(m);
    ep::bind::bind_distributed(m);
    ep::bind::bind_det_math(m);
    py::module_ testing = m.def_submodule("_testing", "Test-only hooks into the engine's samplers and scene queries");
    ep::bind::bind_testing(testing);
}
