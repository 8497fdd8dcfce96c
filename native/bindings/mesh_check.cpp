// Binding of ep::check_mesh, the one owner of the closed-mesh rule
// (endophoton.meshes.check_closed_mesh calls it).
#include "mesh_check.h"
#include "common.h"

namespace ep::bind {

void bind_mesh_check(py::module_& m) {
    m.def(
        "check_mesh",
        [](const std::string& owner, FloatArray v, IndexArray t) {
            require_rows_of_3(v, owner + ": mesh.vertices");
            require_rows_of_3(t, owner + ": mesh.triangles");
            const MeshReport r = check_mesh(owner, v.data(), size_t(v.shape(0)), t.data(), size_t(t.shape(0)));
            py::dict d;
            d["signed_volume"] = r.signed_volume;
            d["bbox_min"] = py::make_tuple(r.bbox_min[0], r.bbox_min[1], r.bbox_min[2]);
            d["bbox_max"] = py::make_tuple(r.bbox_max[0], r.bbox_max[1], r.bbox_max[2]);
            d["welded_vertices"] = r.welded_vertices;
            return d;
        },
        py::arg("owner"), py::arg("vertices"), py::arg("triangles"),
        "Check that a triangle mesh is closed, consistently and outward oriented, finite and without degenerate "
        "triangles; raises ValueError naming owner, field and value. Returns signed_volume (scene units^3), "
        "bbox_min, bbox_max and welded_vertices.");
}

}  // namespace ep::bind
