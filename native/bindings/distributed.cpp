// The native half of a run split across processes (python/endophoton/distributed.py):
// unit_plan (how the request is cut into units), trace_units (a worker's task:
// a unit range as bytes) and UnitReducer (the client: merges the bytes in unit
// order through the engine's own reducer). No physics here.
#include <memory>
#include <string>

#include "common.h"
#include "engine.h"
#include "unit_io.h"
#include "voxel_grid.h"

namespace ep::bind {

namespace {

// Keeps the scene alive as long as the reducer that refers to it.
struct PyUnitReducer {
    std::shared_ptr<Scene> scene;
    std::shared_ptr<Source> source;
    RunConfig config;
    std::unique_ptr<UnitReducer> reducer;
    bool finished = false;

    PyUnitReducer(std::shared_ptr<Scene> sc, std::shared_ptr<Source> so, const RunConfig& opts)
        : scene(std::move(sc)),
          source(std::move(so)),
          config(opts),
          reducer(std::make_unique<UnitReducer>(*scene, *source, config)) {}
    UnitReducer& live() {
        if (finished) throw std::invalid_argument("UnitReducer: the run is already finished");
        return *reducer;
    }
};

}  // namespace

void bind_distributed(py::module_& m) {
    m.def(
        "unit_plan",
        [](std::shared_ptr<Scene> scene, std::shared_ptr<Source> source, const RunConfig& opts) {
            const UnitPlan p = plan_units(prepare_config(*scene, *source, opts, nullptr));
            return py::make_tuple(p.unit_size, p.n_units_max);
        },
        py::arg("scene"), py::arg("source"), py::arg("options"),
        "(unit_size, n_units_max) of a request; validates it like run().");

    m.def(
        "trace_units",
        [](std::shared_ptr<Scene> scene, std::shared_ptr<Source> source, const RunConfig& c, uint64_t first_unit,
           uint64_t count) {
            std::string bytes;
            {
                py::gil_scoped_release release;
                bytes = pack_units(trace_units(*scene, *source, c, first_unit, count, nullptr));
            }
            return py::bytes(bytes);
        },
        py::arg("scene"), py::arg("source"), py::arg("options"), py::arg("first_unit"), py::arg("count"),
        "Traces units first_unit .. first_unit+count-1 (GIL released); returns them as bytes for UnitReducer.add.");

    py::class_<PyUnitReducer>(m, "UnitReducer")
        .def(py::init<std::shared_ptr<Scene>, std::shared_ptr<Source>, const RunConfig&>(), py::arg("scene"),
             py::arg("source"), py::arg("options"))
        .def(
            "add",
            [](PyUnitReducer& r, const py::bytes& data) {
                UnitReducer& red = r.live();
                std::string s = data;
                uint64_t n = 0;
                {
                    py::gil_scoped_release release;
                    UnitBatch b = unpack_units(s, red.config().grid_voxel_size, grids_per_unit(red.config()));
                    n = b.units.size();
                    red.add_batch(std::move(b));
                }
                return py::make_tuple(red.stopped(), n);
            },
            py::arg("batch"), "Takes trace_units bytes; returns (stopped, units in the batch).")
        .def_property_readonly("stopped", [](PyUnitReducer& r) { return r.reducer->stopped(); })
        .def_property_readonly("merged_units", [](PyUnitReducer& r) { return r.reducer->merged_units(); })
        .def_property_readonly("records", [](PyUnitReducer& r) { return r.reducer->records(); })
        .def(
            "finish",
            [](PyUnitReducer& r, int threads) {
                UnitReducer& red = r.live();
                r.finished = true;
                RunResult res;
                {
                    py::gil_scoped_release release;
                    res = red.finish(threads);
                }
                return result_dict(std::move(res), *r.scene, r.config.record_escapes);
            },
            py::arg("threads") = 0,
            "Ends the run exactly as run() does (estimates, grid file); a run not stopped by its rule is cancelled.");
}

}  // namespace ep::bind
