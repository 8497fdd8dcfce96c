// Binding of the camera tally (native/camera_tally.h): CameraView, built from
// keyword arguments and numpy arrays, which RunConfig.camera_view takes, and
// the image a run hands back. No physics.
#include <stdexcept>

#include "camera_tally.h"
#include "common.h"

namespace ep::bind {

namespace {

Vec3 vec3_of(const py::handle& o, const char* field) {
    auto v = o.cast<std::vector<double>>();
    if (v.size() != 3) throw std::invalid_argument(std::string("camera_view.") + field + " must hold 3 numbers");
    return Vec3(v[0], v[1], v[2]);
}

std::shared_ptr<CameraView> camera_view_from(const py::kwargs& kw) {
    auto v = std::make_shared<CameraView>();
    auto need = [&](const char* k) -> py::handle {
        if (!kw.contains(k)) throw std::invalid_argument(std::string("camera_view: missing '") + k + "'");
        return kw[k];
    };
    v->position = vec3_of(need("position"), "position");
    v->forward = vec3_of(need("forward"), "forward");
    v->right = vec3_of(need("right"), "right");
    v->up = vec3_of(need("up"), "up");
    v->tan_x = need("tan_x").cast<double>();
    v->tan_y = need("tan_y").cast<double>();
    v->width = need("width").cast<int>();
    v->height = need("height").cast<int>();
    v->pixel_solid_angle = need("pixel_solid_angle").cast<std::vector<double>>();
    v->batches = need("batches").cast<int>();
    v->packets = need("packets").cast<uint64_t>();
    if (kw.contains("tau_cut")) v->tau_cut = kw["tau_cut"].cast<double>();
    if (kw.contains("depth_bound")) v->depth_bound = kw["depth_bound"].cast<bool>();
    if (kw.contains("look_back")) v->look_back = kw["look_back"].cast<bool>();
    if (kw.contains("look_back_alpha")) v->look_back_alpha = kw["look_back_alpha"].cast<double>();
    if (kw.contains("look_back_g")) v->look_back_g = kw["look_back_g"].cast<double>();
    v->lambda0_nm = need("lambda0_nm").cast<double>();
    v->dlambda_nm = need("dlambda_nm").cast<double>();
    auto table = need("table").cast<py::array_t<double, py::array::c_style | py::array::forcecast>>();
    if (table.ndim() != 2) throw std::invalid_argument("camera_view.table must be 2-D (wavelengths, channels)");
    v->channels = int(table.shape(1));
    v->table.assign(table.data(), table.data() + table.size());
    v->fluorescent_only = need("fluorescent_only").cast<std::vector<uint8_t>>();
    v->spectrum_bins = need("spectrum_bins").cast<int>();
    v->spectrum_bin = need("spectrum_bin").cast<std::vector<int32_t>>();
    v->spectrum_fluorescent_weight = need("spectrum_fluorescent_weight").cast<std::vector<double>>();
    v->check();
    return v;
}

}  // namespace

py::object camera_image_dict(const std::shared_ptr<CameraImage>& img) {
    if (!img) return py::none();
    const CameraView& v = img->view();
    py::dict d;
    const auto P = py::ssize_t(v.pixels()), B = py::ssize_t(v.batches), K = py::ssize_t(v.channels);
    d["sums"] = take(std::move(img->sums), {P, B, K});
    d["spectrum"] = take(std::move(img->spectrum), {P, 2, py::ssize_t(v.spectrum_bins)});
    const CameraCounters& c = img->counters;
    d["events"] = c.events;
    d["thinned"] = c.thinned;
    d["bounded"] = c.bounded;
    d["scored"] = c.scored;
    d["occluded"] = c.occluded;
    d["unresolved"] = c.unresolved;
    d["crossing"] = c.crossing;
    d["looked_back"] = c.looked_back;
    d["covered"] = c.covered;
    return d;
}

void bind_camera_view(py::module_& m) {
    py::class_<CameraView, std::shared_ptr<CameraView>>(
        m, "CameraView", "The camera tally's request (native/camera_tally.h); built by endophoton.view.nee.")
        .def(py::init(&camera_view_from))
        .def_readonly("width", &CameraView::width)
        .def_readonly("height", &CameraView::height)
        .def_readonly("batches", &CameraView::batches)
        .def_readonly("packets", &CameraView::packets)
        .def_readonly("channels", &CameraView::channels)
        // false: every event's path is solved before its depth roulette (the tests' reference).
        .def_readwrite("depth_bound", &CameraView::depth_bound)
        .def_readonly("look_back", &CameraView::look_back)
        .def_readonly("look_back_alpha", &CameraView::look_back_alpha)
        .def_readonly("look_back_g", &CameraView::look_back_g)
        // false: the look-back drops its weight ratio (a deliberately biased image, for the tests).
        .def_readwrite("look_back_ratio", &CameraView::look_back_ratio);
}

}  // namespace ep::bind
