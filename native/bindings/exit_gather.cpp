// Binding of ep::ExitIndex (native/exit_gather.h): the exitance estimate's
// searches and sums, each call with the GIL released. Thin: shape checks, the
// output arrays, and the record arrays kept alive as long as the index.
#include <stdexcept>
#include <string>
#include <vector>

#include "common.h"
#include "exit_gather.h"

namespace ep::bind {

namespace {

template <class T>
using Arr = py::array_t<T, py::array::c_style | py::array::forcecast>;

// Throws unless `a` has exactly the shape `want`; `name` names the argument.
template <class T>
void require_shape(const Arr<T>& a, std::vector<py::ssize_t> want, const char* name) {
    bool ok = a.ndim() == py::ssize_t(want.size());
    for (size_t i = 0; ok && i < want.size(); ++i) ok = a.shape(i) == want[i];
    if (ok) return;
    std::string got, exp;
    for (py::ssize_t i = 0; i < a.ndim(); ++i) got += (i ? ", " : "") + std::to_string(a.shape(i));
    for (size_t i = 0; i < want.size(); ++i) exp += (i ? ", " : "") + std::to_string(want[i]);
    throw std::invalid_argument(std::string(name) + " has shape (" + got + "), expected (" + exp + ")");
}

// The index and the arrays its pointers read.
struct Index {
    Arr<double> pos;
    Arr<int32_t> region;
    int regions;
    std::unique_ptr<ExitIndex> index;

    ExitRecords records() const {
        ExitRecords rec;
        rec.n = size_t(pos.shape(0));
        rec.pos = pos.data();
        rec.region = region.data();
        return rec;
    }
};

std::shared_ptr<Index> make_index(Arr<double> pos, Arr<int32_t> region, Arr<uint8_t> keep, int regions) {
    const py::ssize_t N = pos.shape(0);
    require_shape(pos, {N, 3}, "rec_pos");
    require_shape(region, {N}, "rec_region");
    require_shape(keep, {N}, "keep");
    if (regions < 0) throw std::invalid_argument("regions = " + std::to_string(regions) + " must be >= 0");
    auto ix = std::make_shared<Index>(Index{pos, region, regions, nullptr});
    ExitRecords rec = ix->records();
    py::gil_scoped_release release;
    ix->index = std::make_unique<ExitIndex>(rec, keep.data(), regions);
    return ix;
}

// The pixels' arrays every call reads: (P, 3) points and (P) regions.
ExitPixels pixels(const Arr<double>& px, const Arr<int32_t>& preg) {
    const py::ssize_t P = px.shape(0);
    require_shape(px, {P, 3}, "px");
    require_shape(preg, {P}, "preg");
    ExitPixels pix;
    pix.p = size_t(P);
    pix.pos = px.data();
    pix.region = preg.data();
    return pix;
}

py::object kth_distance(const Index& ix, Arr<uint8_t> use, Arr<double> px, Arr<int32_t> preg, int k, int threads,
                        std::shared_ptr<CancelToken> cancel) {
    require_shape(use, {ix.pos.shape(0)}, "use");
    if (k < 1) throw std::invalid_argument("k = " + std::to_string(k) + " must be >= 1");
    const ExitPixels pix = pixels(px, preg);
    py::array_t<double> dk(py::ssize_t(pix.p));
    double* out = dk.mutable_data();
    bool done;
    {
        py::gil_scoped_release release;
        done = ix.index->kth_distance(use.data(), pix, k, threads, cancel ? &cancel->flag : nullptr, out);
    }
    return done ? py::object(dk) : py::object(py::none());
}

struct GatherArgs {
    Arr<int32_t> batch, band, sbin;
    Arr<double> cmf, cam, energy, coef, px;
    Arr<int32_t> preg;
    Arr<double> mu_rows, radius;
    Arr<uint8_t> grown;
    Arr<double> scale;
    Arr<int64_t> image_index;
    py::ssize_t image_size;
    int spectrum_bins;
};

py::object gather(const Index& ix, const GatherArgs& a, int threads, std::shared_ptr<CancelToken> cancel) {
    if (a.coef.ndim() != 5) throw std::invalid_argument("coef must be (images, batches, regions, bands, terms)");
    const py::ssize_t M = a.coef.shape(0), B = a.coef.shape(1), L = a.coef.shape(4), N = ix.pos.shape(0);
    if (a.spectrum_bins < 1) throw std::invalid_argument("spectrum_bins = " + std::to_string(a.spectrum_bins));
    if (a.image_size < 0) throw std::invalid_argument("image_size = " + std::to_string(a.image_size));
    ExitPixels pix = pixels(a.px, a.preg);
    const py::ssize_t P = py::ssize_t(pix.p);
    for (auto* c : {&a.batch, &a.band, &a.sbin}) require_shape(*c, {N}, "record column");
    require_shape(a.cmf, {N, 3}, "rec_cmf");
    require_shape(a.cam, {N, 2}, "rec_cam");
    require_shape(a.energy, {M, N}, "energy");
    require_shape(a.mu_rows, {P, L}, "mu_rows");
    require_shape(a.radius, {M, P}, "radius");
    require_shape(a.grown, {M, P}, "grown");
    require_shape(a.scale, {M, P, B}, "scale");
    require_shape(a.image_index, {P}, "image_index");
    const int64_t* ii = a.image_index.data();
    for (py::ssize_t q = 0; q < P; ++q) {
        if (ii[q] < 0 || ii[q] >= a.image_size)
            throw std::invalid_argument("image_index[" + std::to_string(q) + "] = " + std::to_string(ii[q]) +
                                        " is outside the image of " + std::to_string(a.image_size) + " pixels");
        // one pixel per image index: the workers write each pixel's colour sums without a lock
        if (q > 0 && ii[q] <= ii[q - 1])
            throw std::invalid_argument("image_index[" + std::to_string(q) + "] = " + std::to_string(ii[q]) +
                                        " must be greater than image_index[" + std::to_string(q - 1) + "]");
    }
    ExitRecords rec = ix.records();
    rec.batch = a.batch.data(), rec.band = a.band.data(), rec.sbin = a.sbin.data();
    rec.cmf = a.cmf.data(), rec.cam = a.cam.data(), rec.energy = a.energy.data();
    ExitTables tab{int(M), int(B), int(a.coef.shape(2)), int(a.coef.shape(3)), int(L), a.spectrum_bins, a.coef.data()};
    if (tab.regions != ix.regions)
        throw std::invalid_argument("coef has " + std::to_string(tab.regions) + " regions, the index " +
                                    std::to_string(ix.regions));
    for (size_t j = 0; j < rec.n; ++j)
        if (rec.batch[j] < 0 || rec.batch[j] >= B || rec.band[j] < 0 || rec.band[j] >= tab.bands)
            throw std::invalid_argument("record " + std::to_string(j) + " has batch " + std::to_string(rec.batch[j]) +
                                        ", band " + std::to_string(rec.band[j]));
    pix.mu_rows = a.mu_rows.data(), pix.radius = a.radius.data(), pix.grown = a.grown.data();
    pix.scale = a.scale.data(), pix.image_index = a.image_index.data(), pix.image_size = size_t(a.image_size);
    py::array_t<double> W({M, P, B}), Wh({M, P, B}), XYZ({M, a.image_size, py::ssize_t(3), B}),
        CAM({M, a.image_size, py::ssize_t(2), B}), SPEC({M, P, py::ssize_t(a.spectrum_bins)});
    for (auto* o : {&W, &Wh, &XYZ, &CAM, &SPEC}) std::fill_n(o->mutable_data(), o->size(), 0.0);
    ExitSums out{W.mutable_data(), Wh.mutable_data(), XYZ.mutable_data(), CAM.mutable_data(), SPEC.mutable_data()};
    bool done;
    {
        py::gil_scoped_release release;
        done = ix.index->gather(rec, pix, tab, threads, cancel ? &cancel->flag : nullptr, out);
    }
    if (!done) return py::none();
    return py::make_tuple(W, Wh, XYZ, CAM, SPEC);
}

}  // namespace

void bind_exit_gather(py::module_& m) {
    py::class_<Index, std::shared_ptr<Index>>(
        m, "ExitIndex",
        "The records of each region that keep marks, one kd-tree per region (native/exit_gather.h): the exitance "
        "estimate's searches and sums. Built with the GIL released.")
        .def(py::init(&make_index), py::arg("rec_pos"), py::arg("rec_region"), py::arg("keep"), py::arg("regions"))
        .def("kth_distance", &kth_distance, py::arg("use"), py::arg("px"), py::arg("preg"), py::arg("k"),
             py::arg("threads") = 0, py::arg("cancel") = nullptr,
             "Per pixel, the distance to the k-th nearest indexed record of its region among those with use != 0 "
             "(the farthest where fewer than k, inf where fewer than 2): (P,) float64, or None once cancel is set.")
        .def(
            "gather",
            [](const Index& ix, Arr<int32_t> rec_batch, Arr<int32_t> rec_band, Arr<int32_t> rec_sbin,
               Arr<double> rec_cmf, Arr<double> rec_cam, Arr<double> energy, Arr<double> coef, Arr<double> px,
               Arr<int32_t> preg, Arr<double> mu_rows, Arr<double> radius, Arr<uint8_t> grown, Arr<double> scale,
               Arr<int64_t> image_index, py::ssize_t image_size, int spectrum_bins, int threads,
               std::shared_ptr<CancelToken> cancel) {
                GatherArgs a{rec_batch, rec_band, rec_sbin, rec_cmf, rec_cam, energy,      coef,       px,
                             preg,      mu_rows,  radius,   grown,   scale,   image_index, image_size, spectrum_bins};
                return gather(ix, a, threads, cancel);
            },
            py::arg("rec_batch"), py::arg("rec_band"), py::arg("rec_sbin"), py::arg("rec_cmf"), py::arg("rec_cam"),
            py::arg("energy"), py::arg("coef"), py::arg("px"), py::arg("preg"), py::arg("mu_rows"), py::arg("radius"),
            py::arg("grown"), py::arg("scale"), py::arg("image_index"), py::arg("image_size"), py::arg("spectrum_bins"),
            py::arg("threads") = 0, py::arg("cancel") = nullptr,
            "The exitance estimate's sums (ExitIndex::gather in native/exit_gather.h): (W, W_half (images, P, B), "
            "XYZ (images, image_size, 3, B), CAM (images, image_size, 2, B), SPEC (images, P, spectrum_bins)), or "
            "None once cancel is set.");
}

}  // namespace ep::bind
