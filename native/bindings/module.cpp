// endophoton._core: a thin layer over the core library. It converts numpy
// arrays and keyword arguments, releases the GIL for the run, and hands result
// columns back as numpy arrays that own their memory through capsules.
// No physics lives here.
#include <pybind11/functional.h>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <atomic>
#include <memory>

#include "eem.h"
#include "engine.h"
#include "fresnel.h"
#include "phase.h"
#include "rng.h"
#include "scene.h"
#include "source.h"
#include "spectrum.h"
#include "run_binding.h"

namespace py = pybind11;
using namespace ep;

namespace {

// Moves a vector into a numpy array without copying; the capsule frees it.
template <class T>
py::array take(std::vector<T>&& v, std::vector<py::ssize_t> shape) {
    auto* heap = new std::vector<T>(std::move(v));
    py::capsule owner(heap, [](void* p) { delete static_cast<std::vector<T>*>(p); });
    return py::array_t<T>(shape, heap->data(), owner);
}

std::shared_ptr<const Tabulated1D> table_or_null(const py::object& obj, const std::string& field) {
    if (obj.is_none()) return nullptr;
    auto tup = obj.cast<std::pair<std::vector<double>, std::vector<double>>>();
    return std::make_shared<Tabulated1D>(tup.first, tup.second, field);
}

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
    return d;
}

py::dict records_dict(EscapeRecords&& rec) {
    const py::ssize_t n = py::ssize_t(rec.size());
    py::dict d;
    d["position"] = take(std::move(rec.position), {n, 3});
    d["direction"] = take(std::move(rec.direction), {n, 3});
    d["normal"] = take(std::move(rec.normal), {n, 3});
    d["entry"] = take(std::move(rec.entry), {n, 3});
    d["weight"] = take(std::move(rec.weight), {n});
    d["energy"] = take(std::move(rec.energy), {n});
    d["wavelength"] = take(std::move(rec.wavelength), {n});
    d["max_depth"] = take(std::move(rec.max_depth), {n});
    d["fluorescent"] = take(std::move(rec.fluorescent), {n});
    d["light"] = take(std::move(rec.light), {n});
    d["kind"] = take(std::move(rec.kind), {n});
    d["fluorophore"] = take(std::move(rec.fluorophore), {n});
    d["region"] = take(std::move(rec.region), {n});
    d["scatterings"] = take(std::move(rec.scatterings), {n});
    d["packet"] = take(std::move(rec.packet), {n});
    return d;
}

}  // namespace

RunConfig ep::run_config_from_options(const py::dict& opts) {
    RunConfig c;
    for (auto item : opts) {
        const std::string k = item.first.cast<std::string>();
        py::handle v = item.second;
        if (k == "photons") c.photons = v.cast<uint64_t>();
        else if (k == "store") c.store = v.cast<uint64_t>();
        else if (k == "fluorescent_only") c.fluorescent_only = v.cast<bool>();
        else if (k == "record_escapes") c.record_escapes = v.cast<bool>();
        else if (k == "max_records") c.max_records = v.cast<uint64_t>();
        else if (k == "seed") c.seed = v.cast<uint64_t>();
        else if (k == "threads") c.threads = v.cast<int>();
        else if (k == "roulette_threshold") c.roulette_threshold = v.cast<double>();
        else if (k == "roulette_chance") c.roulette_chance = v.cast<double>();
        else if (k == "max_steps") c.max_steps = v.cast<uint64_t>();
        else if (k == "max_path_cm") c.max_path_cm = v.cast<double>();
        else if (k == "fluorescence_rule") {
            const std::string r = v.cast<std::string>();
            if (r == "paper") c.rule = FluorescenceRule::kPaper;
            else if (r == "eem") c.rule = FluorescenceRule::kEEM;
            else throw std::invalid_argument("fluorescence_rule = '" + r + "' must be 'paper' or 'eem'");
        } else if (k == "force_spectral") c.force_spectral = v.cast<bool>();
        else if (k == "grid_voxel_size") c.grid_voxel_size = v.cast<double>();
        else if (k == "grid_per_fluorophore") c.grid_per_fluorophore = v.cast<bool>();
        else if (k == "grid_path") c.grid_path = v.cast<std::string>();
        else if (k == "target_tally") {
            const std::string name = v.cast<std::string>();
            c.target_tally = -1;
            for (int i = 0; i < kScalarTallies; ++i)
                if (name == tally_name(i)) c.target_tally = i;
            if (c.target_tally < 0) throw std::invalid_argument("target tally '" + name + "' is not a tally name");
        } else if (k == "target_rel_error") c.target_rel_error = v.cast<double>();
        else if (k == "time_budget_s") c.time_budget_s = v.cast<double>();
        else if (k == "max_photons") c.max_photons = v.cast<uint64_t>();
        else if (k == "unit_size") c.unit_size = v.cast<uint64_t>();
        else if (k == "batches") c.batches = v.cast<int>();
        else if (k == "safe_distance") c.safe_distance = v.cast<bool>();
        else if (k == "test_cancel_after_units") c.test_cancel_after_units = v.cast<uint64_t>();
        else if (k == "test_fail_thread") c.test_fail_thread = v.cast<int>();
        else throw std::invalid_argument("run option '" + k + "' is unknown");
    }
    return c;
}

py::dict ep::run_result_dict(RunResult& r, const Scene& scene, const RunConfig& c) {
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
    d["unit_size"] = r.unit_size;
    d["threads"] = r.threads;
    d["grid_path"] = r.grid_path.empty() ? py::object(py::none()) : py::object(py::str(r.grid_path));
    d["grid_names"] = r.grid_names;
    d["grid_absorbed_sum"] = r.grid_absorbed_sum;
    d["record_bytes"] = r.peak_record_bytes;
    if (c.record_escapes) d["escapes"] = records_dict(std::move(r.records));
    else d["escapes"] = py::none();
    return d;
}

PYBIND11_MODULE(_core, m) {
    m.doc() = "EndoPhoton native engine (thin binding; use the endophoton package API)";
    m.attr("__version__") = engine_version();
    py::register_exception<std::invalid_argument>(m, "InvalidArgument", PyExc_ValueError);
    m.attr("MAX_REGIONS") = int(Scene::kMaxRegions);
    m.attr("MAX_PACKET_REQUEST") = kMaxPacketRequest;

    py::class_<CancelToken, std::shared_ptr<CancelToken>>(m, "CancelToken")
        .def(py::init<>())
        .def("cancel", [](CancelToken& t) { t.flag.store(true); }, "Ask the running simulation to stop.")
        .def_property_readonly("cancelled", [](const CancelToken& t) { return t.flag.load(); });

    py::class_<Scene, std::shared_ptr<Scene>>(m, "Scene")
        .def(py::init<double, double>(), py::arg("unit_cm"), py::arg("ambient_n") = 1.0)
        .def(
            "add_region",
            [](Scene& s, const std::string& name, py::array_t<float, py::array::c_style | py::array::forcecast> v,
               py::array_t<uint32_t, py::array::c_style | py::array::forcecast> t, double mua, double mus, double g,
               double n, int priority, py::object mua_table, py::object mus_table) {
                const std::string owner = "region '" + name + "'";
                if (v.ndim() != 2 || v.shape(1) != 3)
                    throw std::invalid_argument(owner + ": mesh.vertices must have shape (N, 3), got ndim " +
                                                std::to_string(v.ndim()));
                if (t.ndim() != 2 || t.shape(1) != 3)
                    throw std::invalid_argument(owner + ": mesh.triangles must have shape (M, 3), got ndim " +
                                                std::to_string(t.ndim()));
                Medium med;
                med.mua = mua;
                med.mus = mus;
                med.g = g;
                med.n = n;
                med.mua_table = table_or_null(mua_table, owner + ": medium.mua");
                med.mus_table = table_or_null(mus_table, owner + ": medium.mus");
                return s.add_region(name, v.data(), size_t(v.shape(0)), t.data(), size_t(t.shape(0)), med, priority);
            },
            py::arg("name"), py::arg("vertices"), py::arg("triangles"), py::arg("mua"), py::arg("mus"), py::arg("g"),
            py::arg("n"), py::arg("priority") = 0, py::arg("mua_table") = py::none(),
            py::arg("mus_table") = py::none())
        .def(
            "add_fluorophore",
            [](Scene& s, const std::string& name, std::vector<double> ex, std::vector<double> em,
               std::vector<double> values) {
                return s.add_fluorophore(name, std::make_shared<EEM>(name, ex, em, values));
            },
            py::arg("name"), py::arg("excitation_nm"), py::arg("emission_nm"), py::arg("values"))
        .def(
            "set_region_fluorophores",
            [](Scene& s, int region, const std::vector<std::tuple<int, double, double>>& refs) {
                std::vector<FluorophoreRef> out;
                for (const auto& [id, d, c] : refs) out.push_back(FluorophoreRef{id, d, c});
                s.set_region_fluorophores(region, out);
            },
            py::arg("region"), py::arg("fluorophores"))
        .def("commit", &Scene::commit)
        .def_property_readonly("unit_cm", &Scene::unit_cm)
        .def_property_readonly("extent", &Scene::extent)
        .def_property_readonly("region_count", &Scene::region_count)
        .def("region_signed_volume", [](const Scene& s, int i) { return s.region(size_t(i)).report.signed_volume; })
        .def("distance_to_surface",
             [](const Scene& s, std::array<double, 3> p, double radius) {
                 return s.distance_to_surface(Vec3(p[0], p[1], p[2]), radius);
             })
        .def(
            "intersect_all",
            [](const Scene& s, std::array<double, 3> o, std::array<double, 3> d, double tnear, double tfar) {
                std::vector<Hit> hits;
                s.intersect_all(Vec3(o[0], o[1], o[2]), normalize(Vec3(d[0], d[1], d[2])), tnear, tfar, hits);
                py::list out;
                for (const Hit& h : hits) out.append(py::make_tuple(h.t, h.region, h.prim, h.cos_dn));
                return out;
            },
            "Debug helper: every crossing (t, region, triangle, cos) along a ray.");

    py::class_<Source, std::shared_ptr<Source>>(m, "Source")
        .def(py::init([](const std::vector<py::dict>& lights) {
                 std::vector<Light> out;
                 for (const py::dict& d : lights) {
                     Light l;
                     auto c = d["position"].cast<std::array<double, 3>>();
                     auto a = d["direction"].cast<std::array<double, 3>>();
                     l.center = Vec3(c[0], c[1], c[2]);
                     l.axis = Vec3(a[0], a[1], a[2]);
                     l.radius = d.contains("radius") ? d["radius"].cast<double>() : 0.0;
                     l.half_angle = d.contains("half_angle") ? d["half_angle"].cast<double>() : 0.0;
                     if (d.contains("spectrum")) l.spectrum = table_or_null(d["spectrum"], "source.spectrum");
                     out.push_back(l);
                 }
                 return std::make_shared<Source>(out);
             }),
             py::arg("lights"))
        .def(
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
                return py::make_tuple(take(std::move(pos), {n, 3}), take(std::move(dir), {n, 3}),
                                      take(std::move(wl), {n}), take(std::move(light), {n}));
            },
            py::arg("seed"), py::arg("first"), py::arg("count"), py::arg("spectral") = false,
            "Emission samples of packets first..first+count (positions, directions, wavelengths, light).");

    m.def(
        "run",
        [](std::shared_ptr<Scene> scene, std::shared_ptr<Source> source, const py::dict& opts, py::object progress,
           std::shared_ptr<CancelToken> cancel) {
            const RunConfig c = run_config_from_options(opts);
            std::atomic<bool>* flag = cancel ? &cancel->flag : nullptr;
            // Every watcher tick also runs Python's signal handlers, so Ctrl-C
            // (or a handler that cancels) stops the run within ~0.1 s.
            std::unique_ptr<py::error_already_set> py_error;
            ProgressFn fn = [&](uint64_t done, uint64_t total) {
                py::gil_scoped_acquire gil;
                try {
                    if (PyErr_CheckSignals() != 0) throw py::error_already_set();
                    if (progress.is_none()) return true;
                    py::object r = progress(done, total);
                    return r.is_none() || r.cast<bool>();
                } catch (py::error_already_set& e) {
                    py_error = std::make_unique<py::error_already_set>(std::move(e));
                    return false;
                }
            };
            RunResult r;
            {
                py::gil_scoped_release release;
                r = ep::run(*scene, *source, c, fn, flag);
            }
            // A KeyboardInterrupt (or an error of the callback) is re-raised once
            // the workers have stopped; a cancelled run writes no grid file.
            if (py_error) throw std::move(*py_error);
            return run_result_dict(r, *scene, c);
        },
        py::arg("scene"), py::arg("source"), py::arg("options"), py::arg("progress") = py::none(),
        py::arg("cancel") = nullptr);
    register_distributed(m);

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
}
