// Binding of a run: CancelToken, RunConfig (native/run_config.h, one attribute
// per field; keyword construction RunConfig(photons=..., seed=...)), run(),
// which releases the GIL and returns the estimates and records as a dict, and
// check_run(), run()'s validation alone.
#include <stdexcept>

#include "common.h"
#include "engine.h"

namespace ep::bind {

namespace {

py::dict estimates_dict(const RunResult& r, const Scene& scene) {
    py::dict d;
    for (int k = 0; k < kScalarTallies; ++k) {
        d[tally_name(k)] = r.scalar[k].mean;
        d[(std::string(tally_name(k)) + "_stderr").c_str()] = r.scalar[k].stderr_;
    }
    py::dict reg, reg_se;
    for (size_t i = 0; i < r.absorbed_by_region.size(); ++i) {
        reg[scene.region(i).name.c_str()] = r.absorbed_by_region[i].mean;
        reg_se[scene.region(i).name.c_str()] = r.absorbed_by_region[i].stderr_;
    }
    if (r.spectral) {
        for (int k = 0; k < kEnergyTallies; ++k) {
            d[energy_tally_name(k)] = r.energy[k].mean;
            d[(std::string(energy_tally_name(k)) + "_stderr").c_str()] = r.energy[k].stderr_;
        }
    }
    d["absorbed_by_region"] = reg;
    d["absorbed_by_region_stderr"] = reg_se;
    py::dict em, em_se;  // by fluorophore name (names are unique in a scene)
    for (size_t f = 0; f < r.emitted_by_fluorophore.size(); ++f) {
        em[scene.fluorophore_name(int(f)).c_str()] = r.emitted_by_fluorophore[f].mean;
        em_se[scene.fluorophore_name(int(f)).c_str()] = r.emitted_by_fluorophore[f].stderr_;
    }
    d["emitted_by_fluorophore"] = em;
    d["emitted_by_fluorophore_stderr"] = em_se;
    return d;
}

// One numpy array per column of EP_RECORD_COLUMNS (native/records.h), named
// as there: shape (N, 3) for vectors, (N,) otherwise; the columns move, uncopied.
py::dict records_dict(EscapeRecords&& rec) {
    const py::ssize_t n = py::ssize_t(rec.size());
    py::dict d;
    EscapeRecords::for_each_column(rec, [&](auto& column, RecordColumn c) {
        d[c.name] = take(std::move(column), c.width == 1 ? std::vector<py::ssize_t>{n}
                                                         : std::vector<py::ssize_t>{n, py::ssize_t(c.width)});
    });
    return d;
}

std::string rule_name(FluorescenceRule r) { return r == FluorescenceRule::kEEM ? "eem" : "paper"; }

FluorescenceRule rule_from_name(const std::string& r) {
    if (r == "paper") return FluorescenceRule::kPaper;
    if (r == "eem") return FluorescenceRule::kEEM;
    throw std::invalid_argument("fluorescence_rule = '" + r + "' must be 'paper' or 'eem'");
}

int tally_from_name(const std::string& name) {
    if (name.empty()) return -1;
    for (int i = 0; i < kScalarTallies; ++i)
        if (name == tally_name(i)) return i;
    throw std::invalid_argument("target tally '" + name + "' is not a tally name");
}

// The progress callback's answer (the rule of python/endophoton/callbacks.py): None or True go
// on, False stops; any other value raises TypeError here, in Python, instead of a cast error
// thrown on a worker's watcher (which ended the process with std::terminate).
bool progress_goes_on(const py::object& r) {
    if (r.is_none()) return true;
    if (PyBool_Check(r.ptr())) return r.ptr() == Py_True;
    const std::string kind = py::str(py::type::of(r).attr("__name__"));
    PyErr_SetString(PyExc_TypeError, ("progress returned " + kind +
                                      ": a progress callback must return None or True (go on) or False (stop)")
                                         .c_str());
    throw py::error_already_set();
}

void bind_config(py::module_& m) {
    py::class_<RunConfig> cls(m, "RunConfig", "Options of one run (native/run_config.h); lengths in scene units.");
    cls.def(py::init<>())
        .def(py::init([](const py::kwargs& kwargs) {
            // Keyword construction: every key must name an attribute (a field of RunConfig).
            py::object self = py::cast(RunConfig{});
            for (auto item : kwargs) {
                const std::string key = item.first.cast<std::string>();
                if (key.rfind("__", 0) == 0 || !py::hasattr(self, key.c_str()))
                    throw std::invalid_argument("run option '" + key + "' is unknown");
                py::setattr(self, key.c_str(), item.second);
            }
            return self.cast<RunConfig>();
        }))
        .def_readwrite("photons", &RunConfig::photons)
        .def_readwrite("store", &RunConfig::store)
        .def_readwrite("fluorescent_only", &RunConfig::fluorescent_only)
        .def_readwrite("record_escapes", &RunConfig::record_escapes)
        .def_readwrite("max_records", &RunConfig::max_records)
        .def_readwrite("seed", &RunConfig::seed)
        .def_readwrite("threads", &RunConfig::threads)
        .def_readwrite("roulette_threshold", &RunConfig::roulette_threshold)
        .def_readwrite("roulette_chance", &RunConfig::roulette_chance)
        .def_readwrite("max_steps", &RunConfig::max_steps)
        .def_readwrite("max_path_cm", &RunConfig::max_path_cm)
        .def_readwrite("force_spectral", &RunConfig::force_spectral)
        .def_readwrite("grid_voxel_size", &RunConfig::grid_voxel_size)
        .def_readwrite("grid_per_fluorophore", &RunConfig::grid_per_fluorophore)
        .def_readwrite("grid_absorbed", &RunConfig::grid_absorbed)
        .def_readwrite("grid_fluorescent_light", &RunConfig::grid_fluorescent_light)
        .def_readwrite("grid_emission", &RunConfig::grid_emission)
        .def_readwrite("grid_path", &RunConfig::grid_path)
        .def_readwrite("grid_max_tree_bytes", &RunConfig::grid_max_tree_bytes)
        .def_readwrite("target_rel_error", &RunConfig::target_rel_error)
        .def_readwrite("time_budget_s", &RunConfig::time_budget_s)
        .def_readwrite("max_photons", &RunConfig::max_photons)
        .def_readwrite("unit_size", &RunConfig::unit_size)
        .def_readwrite("batches", &RunConfig::batches)
        .def_readwrite("safe_distance", &RunConfig::safe_distance)
        .def_readwrite("lanes", &RunConfig::lanes)
        .def_readwrite("lumen", &RunConfig::lumen)
        .def_readwrite("stats", &RunConfig::stats)
        .def_property(
            "camera_view", [](const RunConfig& c) { return std::const_pointer_cast<CameraView>(c.camera_view); },
            [](RunConfig& c, std::shared_ptr<CameraView> v) { c.camera_view = std::move(v); },
            "the camera tally's request (a CameraView) or None")
        .def_readwrite("test_cancel_after_units", &RunConfig::test_cancel_after_units)
        .def_readwrite("test_cancel_at_packet", &RunConfig::test_cancel_at_packet)
        .def_readwrite("test_fail_thread", &RunConfig::test_fail_thread)
        .def_property(
            "fluorescence_rule", [](const RunConfig& c) { return rule_name(c.rule); },
            [](RunConfig& c, const std::string& r) { c.rule = rule_from_name(r); }, "'paper' or 'eem'")
        .def_property(
            "target_tally",
            [](const RunConfig& c) { return c.target_tally < 0 ? std::string() : tally_name(c.target_tally); },
            [](RunConfig& c, const std::string& name) { c.target_tally = tally_from_name(name); },
            "name of the tally a target-accuracy run aims at, '' for none");
}

}  // namespace

// The engine counters of a run with RunConfig::stats: totals and per merged unit.
static py::dict stats_dict(const std::vector<EngineStats>& units) {
    using Field = uint64_t EngineStats::*;
    const std::pair<const char*, Field> fields[] = {{"interactions", &EngineStats::interactions},
                                                    {"crossings", &EngineStats::crossings},
                                                    {"cache_hits", &EngineStats::cache_hits},
                                                    {"cache_misses", &EngineStats::cache_misses},
                                                    {"full_queries", &EngineStats::full_queries}};
    py::dict d, per_unit;
    d["units"] = units.size();
    for (const auto& [name, field] : fields) {
        std::vector<uint64_t> column;
        column.reserve(units.size());
        for (const EngineStats& u : units) column.push_back(u.*field);
        uint64_t total = 0;
        for (uint64_t v : column) total += v;
        d[name] = total;
        per_unit[name] = column;
    }
    d["per_unit"] = per_unit;
    return d;
}

py::dict result_dict(RunResult&& r, const Scene& scene, bool with_records) {
    py::dict d = estimates_dict(r, scene);
    d["photons"] = r.packets;
    d["packets_traced"] = r.packets_traced;
    d["cancelled"] = r.cancelled;
    d["target_reached"] = r.target_reached;
    d["store_reached"] = r.store_reached;
    d["stop_reason"] = stop_reason_name(r.stop);
    d["capped_packets"] = r.capped_packets;
    d["warnings"] = r.warnings;
    d["seconds"] = r.seconds;
    d["spectral"] = r.spectral;
    d["lanes"] = r.lanes.empty() ? py::object(py::none()) : py::object(py::str(r.lanes));
    d["unit_size"] = r.unit_size;
    d["threads"] = r.threads;
    if (!r.unit_stats.empty()) d["stats"] = stats_dict(r.unit_stats);
    d["grid_path"] = r.grid_path.empty() ? py::object(py::none()) : py::object(py::str(r.grid_path));
    d["grid_names"] = r.grid_names;
    d["grid_absorbed_sum"] = r.grid_absorbed_sum;
    d["record_bytes"] = r.peak_record_bytes;
    d["camera_view"] = camera_image_dict(r.camera_image);
    if (with_records)
        d["escapes"] = records_dict(std::move(r.records));
    else
        d["escapes"] = py::none();
    return d;
}

void bind_run(py::module_& m) {
    py::class_<CancelToken, std::shared_ptr<CancelToken>>(m, "CancelToken")
        .def(py::init<>())
        .def(
            "cancel", [](CancelToken& t) { t.flag.store(true); }, "Ask the running simulation to stop.")
        .def_property_readonly("cancelled", [](const CancelToken& t) { return t.flag.load(); });
    bind_config(m);
    m.def(
        "run",
        [](std::shared_ptr<Scene> scene, std::shared_ptr<Source> source, const RunConfig& config, py::object progress,
           std::shared_ptr<CancelToken> cancel) {
            std::atomic<bool>* flag = cancel ? &cancel->flag : nullptr;
            // Every watcher tick also runs Python's signal handlers, so Ctrl-C
            // (or a handler that cancels) stops the run within ~0.1 s.
            std::unique_ptr<py::error_already_set> py_error;
            ProgressFn fn = [&](uint64_t done, uint64_t total) {
                py::gil_scoped_acquire gil;
                try {
                    if (PyErr_CheckSignals() != 0) throw py::error_already_set();
                    if (progress.is_none()) return true;
                    return progress_goes_on(progress(done, total));
                } catch (py::error_already_set& e) {
                    py_error = std::make_unique<py::error_already_set>(std::move(e));
                    return false;
                } catch (const std::exception& e) {  // nothing may leave the watcher (std::terminate)
                    PyErr_SetString(PyExc_RuntimeError, (std::string("progress: ") + e.what()).c_str());
                    py_error = std::make_unique<py::error_already_set>();
                    return false;
                }
            };
            RunResult r;
            {
                py::gil_scoped_release release;
                r = ep::run(*scene, *source, config, fn, flag);
            }
            // A KeyboardInterrupt (or an error of the callback) is re-raised once
            // the workers have stopped; a cancelled run writes no grid file.
            if (py_error) throw std::move(*py_error);
            return result_dict(std::move(r), *scene, config.record_escapes);
        },
        py::arg("scene"), py::arg("source"), py::arg("config"), py::arg("progress") = py::none(),
        py::arg("cancel") = nullptr);
    m.def(
        "check_run",
        [](std::shared_ptr<Scene> scene, std::shared_ptr<Source> source, const RunConfig& config) {
            std::vector<std::string> warnings;
            prepare_config(*scene, *source, config, &warnings);
            return warnings;
        },
        py::arg("scene"), py::arg("source"), py::arg("config"),
        "Validates a request as run() does before it traces a packet (ValueError naming the field), without "
        "tracing; returns the warnings the run would start with.");
}

}  // namespace ep::bind
