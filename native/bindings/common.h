// Shared pieces of the binding endophoton._core: zero-copy array hand-off and
// the per-concept bind functions module.cpp calls (one file per interface).
#pragma once
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>  // in every binding file: the same casters everywhere (ODR)

#include <atomic>
#include <memory>
#include <string>
#include <vector>

#include "engine.h"
#include "spectrum.h"

namespace ep::bind {

namespace py = pybind11;

// Moves a vector into a numpy array without copying; the capsule frees it.
template <class T>
py::array take(std::vector<T>&& v, std::vector<py::ssize_t> shape) {
    auto* heap = new std::vector<T>(std::move(v));
    py::capsule owner(heap, [](void* p) { delete static_cast<std::vector<T>*>(p); });
    return py::array_t<T>(shape, heap->data(), owner);
}

// None -> nullptr; (x, y) sequences -> a table named `field` in its error messages.
std::shared_ptr<const Tabulated1D> table_or_null(const py::object& obj, const std::string& field);

// A flag Python sets from any thread; the run polls it.
struct CancelToken {
    std::atomic<bool> flag{false};
};

using FloatArray = py::array_t<float, py::array::c_style | py::array::forcecast>;
using IndexArray = py::array_t<uint32_t, py::array::c_style | py::array::forcecast>;

// The result dict of a run (run.cpp); moves the records out of `r`.
py::dict result_dict(RunResult&& r, const Scene& scene, bool with_records);

// Throws std::invalid_argument unless `a` has shape (N, 3); `what` names the field.
void require_rows_of_3(const py::array& a, const std::string& what);

// The camera tally's image of a run (camera_view.cpp), None without one; moves its arrays.
py::object camera_image_dict(const std::shared_ptr<CameraImage>& img);

void bind_camera_view(py::module_& m);     // camera_view.cpp: CameraView
void bind_scene(py::module_& m);           // scene.cpp: Scene
void bind_source(py::module_& m);          // source.cpp: Source
void bind_run(py::module_& m);             // run.cpp: CancelToken, RunConfig, run, check_run
void bind_mesh_check(py::module_& m);      // mesh_check.cpp: check_mesh
void bind_spectrum_check(py::module_& m);  // spectrum_check.cpp: check_spectrum, check_eem
void bind_surface_hits(py::module_& m);    // surface_hits.cpp: first_surfaces (endoscope view rays)
void bind_exit_gather(py::module_& m);      // exit_gather.cpp: ExitIndex (the exitance estimate)
void bind_distributed(py::module_& m);     // distributed.cpp: unit_plan, trace_units, UnitReducer
void bind_det_math(py::module_& m);        // det_math.cpp: det_sin, cos, tan, atan, exp, log, pow
void bind_testing(py::module_& m);         // testing.cpp: the _testing submodule (test-only hooks)

}  // namespace ep::bind
