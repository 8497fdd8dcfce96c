// Binding of ep::Scene: regions (closed meshes with a medium), fluorophores, commit.
#include "scene.h"
#include "common.h"
#include "eem.h"

namespace ep::bind {

void bind_scene(py::module_& m) {
    py::class_<Scene, std::shared_ptr<Scene>>(m, "Scene")
        .def(py::init<double, double>(), py::arg("unit_cm"), py::arg("ambient_n") = 1.0)
        .def(
            "add_region",
            [](Scene& s, const std::string& name, FloatArray v, IndexArray t, double mua, double mus, double g,
               double n, int priority, py::object mua_table, py::object mus_table) {
                const std::string owner = "region '" + name + "'";
                require_rows_of_3(v, owner + ": mesh.vertices");
                require_rows_of_3(t, owner + ": mesh.triangles");
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
            py::arg("n"), py::arg("priority") = 0, py::arg("mua_table") = py::none(), py::arg("mus_table") = py::none())
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
        .def_property_readonly("cache_store_bytes", &Scene::cache_store_bytes,
                               "Bytes the per-cube triangle caches' store holds (grows on first use of a cube).")
        .def_property("cache_store_cap_bytes", &Scene::cache_store_cap_bytes, &Scene::set_cache_store_cap_bytes,
                      "The store's budget in bytes: past it, cubes not yet cached take the full ray query "
                      "(the same results, more slowly).");
}

}  // namespace ep::bind
