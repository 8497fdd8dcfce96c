// Next-event estimation toward a pinhole camera (issue 34, docs/render.md
// "The next-event estimate"). At every scattering event inside tissue the
// packet scores the light that would leave it, unscattered, through the
// refracting surface into the camera: the exit point x on the local facet
// (Snell's law between the event and the pinhole), the Henyey-Greenstein
// density toward x, Beer-Lambert attenuation along the path inside, Fresnel
// transmission at x, the solid-angle Jacobian of the refraction and an
// occlusion ray from x to the pinhole. The score lands in the pixel x projects
// to, in the images' units: energy of a 500 nm photon per launched packet per
// cm^2 per sr.
//
// The scores of a work unit are kept in the unit's output (CameraScores) and
// added into the run's image (CameraImage) when the engine merges the unit,
// strictly in unit order, so the image is bit-identical on any thread count.
// A run without a CameraView pays one branch per interaction.
#pragma once
#include <cmath>
#include <cstdint>
#include <memory>
#include <vector>

#include "det_math.h"
#include "scene.h"
#include "triangle_cache.h"
#include "vecmath.h"

namespace ep {

// What the camera tally needs: the pinhole, the image, its batches and the
// colour channels every score is split into (tables over wavelength).
struct CameraView {
    Vec3 position, forward, right, up;      // scene units; unit, orthonormal frame
    Float tan_x = 0, tan_y = 0;             // image half-extents at unit depth
    int width = 0, height = 0;              // pixels; row 0 at the top
    std::vector<double> pixel_solid_angle;  // sr, width * height, row-major
    int batches = 20;                       // contiguous packet-index blocks (analysis.batch_index)
    uint64_t packets = 0;                   // packets of the run (the batches' denominator)
    double tau_cut = 3.0;                   // optical depth beyond which scores are thinned by roulette
    // Decide the depth roulette from a lower bound of the optical depth before
    // any ray query where it can (camera_prefilter). false: solve every event's
    // path first (the reference the tests compare the bits against).
    bool depth_bound = true;
    // Look-back next event (docs/render.md "Look-back next event"): an event
    // reached from the last one by a free flight that stays clear of every
    // triangle is scored by a virtual event drawn there instead, from the
    // camera's stream: a direction from the mixture (1 - alpha) p_HG(g) about
    // the packet's direction + alpha p_HG(look_back_g) about the camera's
    // direction, a free path, and the weight ratio p_HG / mixture <= 1/(1 - alpha).
    bool look_back = false;
    double look_back_alpha = 0.5;  // share of the proposal aimed at the camera, [0, 1)
    double look_back_g = 0.9;      // asymmetry of that share's HG lobe, (-1, 1)
    // Tests only: false drops the weight ratio (a deliberately biased image the cross-checks must see).
    bool look_back_ratio = true;
    // Events whose position projects outside the image widened by this share
    // of its half-extents are not scored (their exit lies within a few mean
    // free paths; 6 pixels at 128 x 128; docs/render.md).
    static constexpr Float kViewMargin = 0.1;
    // The look-back arms no virtual event at a scattering whose depth bound
    // (mu_t x clearance) exceeds tau_cut by more than this (docs/render.md).
    static constexpr Float kLookBackDepth = 2;
    // Channel tables on the wavelength grid lambda0_nm + i dlambda_nm (nearest
    // entry; clamped at the ends): channel k of a score is value * table[i K + k],
    // counted for fluorescent packets only where fluorescent_only[k].
    double lambda0_nm = 0, dlambda_nm = 1;
    int channels = 0;
    std::vector<double> table;
    std::vector<uint8_t> fluorescent_only;
    // Per-pixel spectra (no batches): bin of each grid entry (-1: none), and
    // the weight of the fluorescent spectrum (the emission filter).
    int spectrum_bins = 0;
    std::vector<int32_t> spectrum_bin;
    std::vector<double> spectrum_fluorescent_weight;

    size_t pixels() const { return size_t(width) * size_t(height); }
    size_t lambdas() const { return spectrum_bin.size(); }
    // std::invalid_argument naming the field.
    void check() const;
    // Grid entry of wavelength lambda_nm.
    size_t lambda_index(double lambda_nm) const;
    // Batch of packet `index` (batch b holds [floor(b P / B), floor((b + 1) P / B))).
    int batch_of(uint64_t index) const;
    // Pixel the point x projects to through the pinhole, -1 outside the image.
    int64_t pixel_of(const Vec3& x) const;
    // Whether x projects into the image widened by `margin` (a fraction of its half-extents).
    bool near_view(const Vec3& x, Float margin) const;
};

struct CameraScore {
    uint64_t packet;
    uint32_t pixel;
    uint32_t fluorescent;
    double lambda_nm;
    double value;  // energy radiance of the score (per packet, cm^-2 sr^-1)
};

// Counts of what the scattering events did (per unit, summed in the image).
struct CameraCounters {
    uint64_t events = 0;       // scattering events offered to the estimator
    uint64_t thinned = 0;      // dropped by the depth roulette (unbiased)
    uint64_t bounded = 0;      // of those, dropped before any ray query (its lower bound of the depth)
    uint64_t scored = 0;       // scores made
    uint64_t occluded = 0;     // exit point hidden from the pinhole
    uint64_t unresolved = 0;   // path to the exit point not solved (excluded: bias, docs/render.md)
    uint64_t crossing = 0;     // path crosses an interface of another refractive index (excluded)
    uint64_t looked_back = 0;  // virtual events offered (look-back; also counted in events)
    uint64_t covered = 0;      // real events left unscored: a virtual event stands for them
    void add(const CameraCounters& o) {
        events += o.events;
        thinned += o.thinned;
        bounded += o.bounded;
        scored += o.scored;
        occluded += o.occluded;
        unresolved += o.unresolved;
        crossing += o.crossing;
        looked_back += o.looked_back;
        covered += o.covered;
    }
};

struct CameraScores {
    std::vector<CameraScore> scores;
    CameraCounters counters;
};

// One scattering event offered to the estimator.
struct CameraEvent {
    Vec3 p, d;            // position (scene units) and direction before the scattering
    uint64_t set = 0;     // regions containing p
    int region = -1;      // the top one, where the event is
    Float weight_energy;  // packet weight x energy per weight, after the capture
    Float lambda_nm = 0;
    bool fluorescent = false;
    uint64_t packet = 0;
    Float g = 0, n = 1;  // of the event's region
};

// A lower bound (scene units) of the distance from p to every triangle of
// the scene, from a cube's cache (triangle_cache.h), which holds every
// triangle meeting its ball: the smallest of p's distance to the ball's
// surface and to each cached plane less that plane's reach (the farthest its
// triangles lie from it, with the rounding allowance) and one more rounding
// allowance. 0 when p is not inside the ball. Up to 16 planes, no ray query.
Float surface_clearance(const TriangleCache& cache, const Vec3& p);

// Whether the flight from p along the unit w, from -back to s (the
// transport's look-behind `back`), meets no triangle of the scene: by the
// cache of the cube it starts in where the flight stays inside the cache's
// ball (convex, and every triangle meeting it is cached; its crossings by
// TriangleCache::intersect, the same answers as the transport's queries),
// else by the scene's all-hits query (a flight leaving the ball, a cube
// without a cache). A function of (cache, p, w, back, s) alone: the
// look-back decides with it, for the virtual and the real flight alike,
// whether a flight was clear (the same predicate on both sides keeps the
// estimate exact).
bool segment_clear(const Scene& scene, const TriangleCache& cache, const Vec3& p, const Vec3& w, Float back, Float s);

// An approximation of the direction, inside the tissue at p (index ratio
// n = n_tissue / n_ambient), in which light leaves toward the pinhole c:
// the straight direction to c refracted (Snell) through the plane of the
// cache nearest to p, its normal turned toward c; the straight direction
// where the cache has no plane. Only the look-back's proposal uses it, so
// its error costs variance, never bias.
Vec3 camera_axis_inside(const TriangleCache& cache, const Vec3& p, const Vec3& c, Float n);

// A direction from the look-back's mixture q(w) = (1 - alpha) p_HG,g(d.w) +
// alpha p_HG,gb(axis.w) (u0 picks the lobe, u1 its cosine, u2 its azimuth)
// and the weight ratio p_HG,g(d.w) / q(w), at most 1 / (1 - alpha).
struct LookBackDraw {
    Vec3 w;
    Float ratio = 0;
};
LookBackDraw sample_look_back(const Vec3& d, const Vec3& axis, Float g, Float alpha, Float gb, double u0, double u1,
                              double u2);

// The part of an event's estimate that needs no ray query (issue 34): counts
// the event and says whether it may score (then next_event solves it with the
// same u). False when it lies outside the view's margin, or when the depth
// roulette thins it whatever its path: the path to any exit first crosses
// clearance_units of the event's region, so its optical depth is
// tau >= tau_lb = mut_per_unit x clearance_units, and its chance to survive,
// exp(tau_cut - tau) (1 beneath tau_cut), is at most exp(tau_cut - tau_lb).
// u >= that bound is u >= the exact chance: the event is thinned as the solved
// path would thin it, with the same u, so the scores are the same bits. A
// relative 1e-9 off tau_lb covers the rounding of the hits' distances.
// clearance_units is called only for events in view (it reads the planes).
template <class Clearance>
inline bool camera_prefilter(const CameraView& view, const Vec3& p, double u, Float mut_per_unit,
                             Clearance&& clearance_units, CameraCounters& k) {
    ++k.events;
    if (!view.near_view(p, CameraView::kViewMargin)) return false;
    if (!view.depth_bound) return true;
    const Float tau_lb = mut_per_unit * clearance_units() * (1 - 1e-9);
    if (!(tau_lb > view.tau_cut) || u < det_exp(view.tau_cut - tau_lb)) return true;
    ++k.thinned;
    ++k.bounded;
    return false;
}

// Scores `e`, which camera_prefilter passed, into `out`. `u` (uniform in
// [0, 1), from a stream of the camera's own, so the packet's transport does
// not change) decides the depth roulette; `hits` is scratch.
void next_event(const Scene& scene, const CameraView& view, const CameraEvent& e, double u, std::vector<Hit>& hits,
                CameraScores& out);

// The run's image: per pixel, per batch, per channel sums of the scores, and
// per-pixel spectra (white, fluorescent). Units: as the scores, summed (divide
// by the packets).
class CameraImage {
  public:
    explicit CameraImage(std::shared_ptr<const CameraView> view);
    void add(const CameraScores& unit);
    const CameraView& view() const { return *view_; }
    std::vector<double> sums;      // pixels x batches x channels
    std::vector<double> spectrum;  // pixels x 2 x spectrum_bins
    CameraCounters counters;

  private:
    std::shared_ptr<const CameraView> view_;
};

}  // namespace ep
