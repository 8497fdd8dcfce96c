// The exitance estimate's searches and sums (python/endophoton/view/exitance.py
// gives the estimate): for each pixel's surface point x_p, the escape records of the
// pixel's region within its ball, each weighted by its region's angular table
// at the pixel's view cosine and by the pixel's calibration and area. No
// physics is decided here; the weights come in as tables. It is native because
// it touches every (pixel, record) pair: ~256 records a pixel, 65,536 pixels at
// 256 x 256, two images -- 3 x 10^7 pairs that cost ~10 CPU s as numpy arrays.
#pragma once
#include <atomic>
#include <cstddef>
#include <cstdint>
#include <memory>

namespace ep {

// The records (n of them), row-major arrays.
struct ExitRecords {
    size_t n = 0;
    const double* pos = nullptr;      // (n, 3) exit points, scene units
    const int32_t* region = nullptr;  // (n) region left
    const int32_t* batch = nullptr;   // (n) batch of the packet, [0, batches)
    const int32_t* band = nullptr;    // (n) angular-table band, [0, bands)
    const int32_t* sbin = nullptr;    // (n) spectrum bin, -1 outside [0, spectrum_bins)
    const double* cmf = nullptr;      // (n, 3) CIE x, y, z at the record's wavelength
    const double* cam = nullptr;      // (n, 2) camera R, G responses at it
    const double* energy = nullptr;   // (images, n) energy of the record in each image, >= 0
};

// The pixels (p of them) and the per-image factors of their sums.
struct ExitPixels {
    size_t p = 0;
    const double* pos = nullptr;      // (p, 3) surface point x_p, scene units
    const int32_t* region = nullptr;  // (p) region seen, >= 0
    const double* mu_rows = nullptr;  // (p, terms) Legendre rows P_l(2 mu_p - 1) of the view cosine
    const double* radius = nullptr;   // (images, p) ball radius r_p; not finite: no estimate
    const uint8_t* grown = nullptr;   // (images, p) 1 where the k-th record set r_p (it counts only if strictly inside)
    const double* scale = nullptr;    // (images, p, batches) c_{p,b} / (2 pi mu_p A_p)
    const int64_t* image_index = nullptr;  // (p) the pixel's index in the image, [0, image_size), increasing
    size_t image_size = 0;                 // pixels of the whole image (those that see no surface too)
};

struct ExitTables {
    int images = 0, batches = 0, regions = 0, bands = 0, terms = 0, spectrum_bins = 0;
    const double* coef = nullptr;  // (images, batches, regions, bands, terms) Legendre coefficients of h
};

// The exitance sums (ExitIndex::gather says what each holds).
struct ExitSums {
    double* W = nullptr;
    double* W_half = nullptr;
    double* XYZ = nullptr;
    double* CAM = nullptr;
    double* SPEC = nullptr;
};

// The records of each region that `keep` marks, in one kd-tree per region
// (nanoflann): built once a render, searched for every image's ball radii and
// for the sums. Holds pointers into `rec`'s arrays, which must outlive it.
class ExitIndex {
  public:
    ExitIndex(const ExitRecords& rec, const uint8_t* keep, int regions);
    ~ExitIndex();

    // Per pixel q, the distance from pix.pos[q] to the k-th nearest indexed
    // record of its region among those with use[j] != 0 (k >= 1; the farthest
    // of them where the region has fewer than k, +inf where it has fewer than
    // 2), into dk (p). Reads pix.p, pos and region. Exact whatever the thread
    // count (0 = all cores). Returns false (dk partial) once *cancel is set.
    bool kth_distance(const uint8_t* use, const ExitPixels& pix, int k, int threads, const std::atomic<bool>* cancel,
                      double* dk) const;

    // Sums per image m (arrays of images x ...): for each pair (p, j) with j
    // an indexed record of p's region and |x_j - x_p| <= r_p (strictly <
    // where grown; none where r_p is not finite), the weight
    //   w = e_{m,j} max(0, sum_l coef[m, b_j, g, band_j, l] P_l(mu_p)) scale[m, p, b_j]
    // is added to W (p, batches) at b_j, 4 w to W_half where |x_j - x_p| <
    // r_p / 2, w cmf_j to XYZ (image_size, 3, batches) and w cam_j to CAM
    // (image_size, 2, batches) at the pixel's image index, and w to SPEC (p,
    // spectrum_bins) at sbin_j >= 0; the caller zeroes the sums. `rec` is the
    // index's records with every column. Each pixel's records are added in
    // record order, so the sums are the same bits on any thread count (0 =
    // all cores). Returns false (sums partial) once *cancel is set.
    bool gather(const ExitRecords& rec, const ExitPixels& pix, const ExitTables& tab, int threads,
                const std::atomic<bool>* cancel, const ExitSums& out) const;

  private:
    struct Impl;
    std::unique_ptr<Impl> impl_;
};

}  // namespace ep
