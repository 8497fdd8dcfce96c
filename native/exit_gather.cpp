#include "exit_gather.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <memory>
#include <nanoflann.hpp>
#include <thread>
#include <vector>

namespace ep {

namespace {

constexpr double kInfinity = std::numeric_limits<double>::infinity();

// One region's records as nanoflann's dataset: the rows `idx` of the (n, 3) positions.
struct RegionCloud {
    const double* pos;
    std::vector<uint32_t> idx;
    size_t kdtree_get_point_count() const { return idx.size(); }
    double kdtree_get_pt(size_t i, size_t dim) const { return pos[3 * size_t(idx[i]) + dim]; }
    template <class Box>
    bool kdtree_get_bbox(Box&) const {
        return false;
    }
};

using RegionTree =
    nanoflann::KDTreeSingleIndexAdaptor<nanoflann::L2_Simple_Adaptor<double, RegionCloud>, RegionCloud, 3, uint32_t>;

// Runs body(q, scratch) for every pixel on `threads` threads (0 = all cores), blocks of kBlock pixels taken in
// turn, each worker with its own State; false once *cancel is set (checked per block). Each pixel's outputs
// are its own: any split, the same bits.
template <class State, class Body>
bool for_pixels(size_t p, int threads, const std::atomic<bool>* cancel, Body body) {
    constexpr size_t kBlock = 256;
    std::atomic<size_t> next{0};
    std::atomic<bool> stopped{false};
    auto work = [&]() {
        State scratch;
        for (size_t lo; (lo = next.fetch_add(kBlock)) < p;) {
            if (cancel && cancel->load()) {
                stopped = true;
                return;
            }
            for (size_t q = lo; q < std::min(p, lo + kBlock); ++q) body(q, scratch);
        }
    };
    size_t nt = threads > 0 ? size_t(threads) : std::max(1u, std::thread::hardware_concurrency());
    nt = std::max<size_t>(1, std::min(nt, p / kBlock + 1));
    std::vector<std::thread> pool;
    for (size_t w = 1; w < nt; ++w) pool.emplace_back(work);
    work();
    for (auto& th : pool) th.join();
    return !stopped;
}

struct Scratch {
    std::vector<std::pair<uint32_t, double>> hits;
    std::vector<uint32_t> found;
    std::vector<double> d;
    int32_t last_region = -1;  // the k-th distance search's previous pixel: region, point, k-th distance
    double last[3] = {0.0, 0.0, 0.0}, last_dk = 0.0;
};

// The largest finite radius of pixel q over the images: the one search that serves them all (0: none).
double search_radius(const ExitPixels& pix, const ExitTables& tab, size_t q) {
    double r = 0.0;
    for (int m = 0; m < tab.images; ++m) {
        const double rm = pix.radius[size_t(m) * pix.p + q];
        if (std::isfinite(rm)) r = std::max(r, rm);
    }
    return r;
}

// Adds pixel q's pairs with the records `found` (record indices, ascending) into the sums.
void add_pixel(const ExitRecords& rec, const ExitPixels& pix, const ExitTables& tab, const ExitSums& out, size_t q,
               const std::vector<uint32_t>& found) {
    const int B = tab.batches, L = tab.terms;
    const int32_t g = pix.region[q];
    const double* rows = pix.mu_rows + q * size_t(L);
    const double* x = pix.pos + 3 * q;
    for (uint32_t j : found) {
        const double* y = rec.pos + 3 * size_t(j);
        const double dx = y[0] - x[0], dy = y[1] - x[1], dz = y[2] - x[2];
        const double d = std::sqrt(dx * dx + dy * dy + dz * dz);
        const int b = rec.batch[j], band = rec.band[j], sb = rec.sbin[j];
        for (int m = 0; m < tab.images; ++m) {
            const size_t mq = size_t(m) * pix.p + q;
            const double r = pix.radius[mq], e = rec.energy[size_t(m) * rec.n + j];
            // a grown ball (its k-th record at r_p) holds the k - 1 strictly inside: (k - 1) / V is unbiased
            if (e == 0.0 || !std::isfinite(r) || !(d <= r) || (pix.grown[mq] && !(d < r))) continue;
            const double* a = tab.coef + ((((size_t(m) * B + b) * tab.regions + g) * tab.bands + band) * L);
            double h = 0.0;  // the truncated Legendre series can dip below 0: clamped
            for (int l = 0; l < L; ++l) h += a[l] * rows[l];
            const double w = e * std::max(h, 0.0) * pix.scale[mq * B + b];
            const size_t pb = mq * B + b;
            out.W[pb] += w;
            if (d < 0.5 * r) out.W_half[pb] += 4.0 * w;  // the half ball's area is a quarter
            const size_t mi = size_t(m) * pix.image_size + size_t(pix.image_index[q]);
            for (int c = 0; c < 3; ++c) out.XYZ[(mi * 3 + c) * B + b] += w * rec.cmf[3 * size_t(j) + c];
            for (int c = 0; c < 2; ++c) out.CAM[(mi * 2 + c) * B + b] += w * rec.cam[2 * size_t(j) + c];
            if (sb >= 0 && sb < tab.spectrum_bins) out.SPEC[mq * tab.spectrum_bins + sb] += w;
        }
    }
}

}  // namespace

struct ExitIndex::Impl {
    std::vector<RegionCloud> clouds;
    std::vector<std::unique_ptr<RegionTree>> trees;

    // The region's indexed records within r of x (r^2 a hair wider: nanoflann keeps d^2 < its bound), as
    // (place in the region's cloud, d^2).
    void within(int32_t g, const double* x, double r, std::vector<std::pair<uint32_t, double>>& hits) const {
        hits.clear();
        trees[size_t(g)]->radiusSearch(x, r * r * (1.0 + 1e-9), hits, nanoflann::SearchParams(32, 0.0f, false));
    }
};

ExitIndex::ExitIndex(const ExitRecords& rec, const uint8_t* keep, int regions) : impl_(std::make_unique<Impl>()) {
    impl_->clouds.assign(size_t(std::max(regions, 0)), RegionCloud{rec.pos, {}});
    for (size_t j = 0; j < rec.n; ++j) {
        const int32_t g = rec.region[j];
        if (g >= 0 && g < regions && keep[j]) impl_->clouds[size_t(g)].idx.push_back(uint32_t(j));
    }
    impl_->trees.resize(impl_->clouds.size());
    for (size_t g = 0; g < impl_->clouds.size(); ++g) {
        if (impl_->clouds[g].idx.empty()) continue;
        impl_->trees[g] =
            std::make_unique<RegionTree>(3, impl_->clouds[g], nanoflann::KDTreeSingleIndexAdaptorParams(16));
        impl_->trees[g]->buildIndex();
    }
}

ExitIndex::~ExitIndex() = default;

bool ExitIndex::kth_distance(const uint8_t* use, const ExitPixels& pix, int k, int threads,
                             const std::atomic<bool>* cancel, double* dk) const {
    const Impl& ix = *impl_;
    const int regions = int(ix.clouds.size());
    std::vector<size_t> used(ix.clouds.size(), 0);  // per region, the indexed records `use` marks
    for (size_t g = 0; g < ix.clouds.size(); ++g)
        for (uint32_t j : ix.clouds[g].idx) used[g] += use[j] != 0;
    return for_pixels<Scratch>(pix.p, threads, cancel, [&](size_t q, Scratch& s) {
        const int32_t g = pix.region[q];
        const size_t n = (g >= 0 && g < regions) ? used[size_t(g)] : 0;
        dk[q] = kInfinity;
        if (n < 2) return;
        const size_t want = std::min(n, size_t(std::max(k, 1)));
        const double* x = pix.pos + 3 * q;
        const RegionCloud& cloud = ix.clouds[size_t(g)];
        // The first radius: where the worker's previous pixel (of the region) lies close, its k-th distance plus
        // the distance between the two points (an upper bound: that ball holds the other's); else from the nearest
        // record (records lie on surfaces: a ball of radius r holds ~ r^2 of them), doubled until the ball
        // holds `want` records. The k-th distance is then selected exactly: the guess changes the time, never
        // the result.
        double r = 0.0;
        if (s.last_region == g) {
            const double dx = x[0] - s.last[0], dy = x[1] - s.last[1], dz = x[2] - s.last[2];
            const double step = std::sqrt(dx * dx + dy * dy + dz * dz);
            if (step < s.last_dk) r = s.last_dk + step;
        }
        if (!(r > 0.0)) {
            uint32_t i;
            double nearest2;
            nanoflann::KNNResultSet<double, uint32_t> one(1);
            one.init(&i, &nearest2);
            ix.trees[size_t(g)]->findNeighbors(one, x, nanoflann::SearchParams());
            const double floor = 1e-12 * (1.0 + std::max({std::abs(x[0]), std::abs(x[1]), std::abs(x[2])}));
            r = std::max(std::sqrt(nearest2 * double(want)), floor);
        }
        for (;; r *= 2.0) {
            ix.within(g, x, r, s.hits);
            s.d.clear();
            for (const auto& h : s.hits) {  // the gather's distance: |y - x| in double
                const uint32_t j = cloud.idx[h.first];
                if (!use[j]) continue;
                const double* y = cloud.pos + 3 * size_t(j);
                const double dx = y[0] - x[0], dy = y[1] - x[1], dz = y[2] - x[2];
                s.d.push_back(std::sqrt(dx * dx + dy * dy + dz * dz));
            }
            if (s.d.size() >= want) break;
            if (!std::isfinite(4.0 * r * r)) return;  // distances beyond double's range: no estimate (inf)
        }
        std::nth_element(s.d.begin(), s.d.begin() + (want - 1), s.d.end());
        dk[q] = s.d[want - 1];
        s.last_region = g, s.last_dk = dk[q];
        std::copy(x, x + 3, s.last);
    });
}

bool ExitIndex::gather(const ExitRecords& rec, const ExitPixels& pix, const ExitTables& tab, int threads,
                       const std::atomic<bool>* cancel, const ExitSums& out) const {
    const Impl& ix = *impl_;
    return for_pixels<Scratch>(pix.p, threads, cancel, [&](size_t q, Scratch& s) {
        const int32_t g = pix.region[q];
        const double r = search_radius(pix, tab, q);
        if (g < 0 || g >= int(ix.trees.size()) || g >= tab.regions || !ix.trees[size_t(g)] || !(r > 0.0)) return;
        ix.within(g, pix.pos + 3 * q, r, s.hits);
        s.found.resize(s.hits.size());
        for (size_t h = 0; h < s.hits.size(); ++h) s.found[h] = ix.clouds[size_t(g)].idx[s.hits[h].first];
        std::sort(s.found.begin(), s.found.end());  // record order: the same sums on any split
        add_pixel(rec, pix, tab, out, q, s.found);
    });
}

}  // namespace ep
