#include "camera_tally.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

#include "det_math.h"
#include "fresnel.h"
#include "phase.h"
#include "triangle_cache.h"

namespace ep {

void CameraView::check() const {
    auto fail = [](const std::string& what) { throw std::invalid_argument("camera_view." + what); };
    if (!(width > 0 && height > 0)) fail("width/height must be positive");
    if (!(tan_x > 0 && tan_y > 0 && std::isfinite(tan_x) && std::isfinite(tan_y))) fail("tan_x/tan_y must be > 0");
    if (!is_finite(position) || !is_finite(forward) || !is_finite(right) || !is_finite(up))
        fail("position/frame must be finite");
    if (pixel_solid_angle.size() != pixels()) fail("pixel_solid_angle must hold width * height values");
    for (double w : pixel_solid_angle)
        if (!(w > 0 && std::isfinite(w))) fail("pixel_solid_angle must be positive");
    if (batches < 2) fail("batches = " + std::to_string(batches) + " must be >= 2");
    if (packets < uint64_t(batches)) fail("packets must be >= batches (a fixed photon count)");
    if (!(tau_cut >= 0 && std::isfinite(tau_cut))) fail("tau_cut must be a finite number >= 0");
    if (!(look_back_alpha >= 0 && look_back_alpha < 1))
        fail("look_back_alpha = " + std::to_string(look_back_alpha) + " must be a finite number in [0, 1)");
    if (!(look_back_g > -1 && look_back_g < 1))
        fail("look_back_g = " + std::to_string(look_back_g) + " must be a finite number in (-1, 1)");
    if (channels < 1 || spectrum_bin.empty() || table.size() != lambdas() * size_t(channels) ||
        fluorescent_only.size() != size_t(channels) || spectrum_fluorescent_weight.size() != lambdas())
        fail("channel tables have inconsistent sizes");
    if (!(dlambda_nm > 0 && std::isfinite(lambda0_nm))) fail("dlambda_nm must be > 0");
    for (int32_t b : spectrum_bin)
        if (b >= spectrum_bins) fail("spectrum_bin holds a bin >= spectrum_bins");
}

size_t CameraView::lambda_index(double lambda_nm) const {
    const double x = std::round((lambda_nm - lambda0_nm) / dlambda_nm);
    if (!(x > 0)) return 0;
    return std::min(size_t(x), lambdas() - 1);
}

int CameraView::batch_of(uint64_t index) const {
    // The largest b with floor(b P / B) <= index: b = ceil((index + 1) B / P) - 1.
    const unsigned __int128 B = unsigned(batches), P = packets;
    const unsigned __int128 b = ((index + 1) * B + P - 1) / P;
    return int(std::min<unsigned __int128>(b > 0 ? b - 1 : 0, B - 1));
}

int64_t CameraView::pixel_of(const Vec3& x) const {
    // analysis._camera's convention (view/camera.py Camera.project).
    const Vec3 rel = x - position;
    const Float z = dot(rel, forward);
    if (!(z > 0)) return -1;
    const Float u = dot(rel, right) / z / tan_x, v = dot(rel, up) / z / tan_y;
    if (!(std::fabs(u) < 1 && std::fabs(v) < 1)) return -1;
    const int64_t col = std::clamp<int64_t>(int64_t(std::floor((u + 1) / 2 * width)), 0, width - 1);
    const int64_t row = std::clamp<int64_t>(int64_t(std::floor((1 - v) / 2 * height)), 0, height - 1);
    return row * width + col;
}

bool CameraView::near_view(const Vec3& x, Float margin) const {
    const Vec3 rel = x - position;
    const Float z = dot(rel, forward);
    return z > 0 && std::fabs(dot(rel, right)) < (1 + margin) * tan_x * z &&
           std::fabs(dot(rel, up)) < (1 + margin) * tan_y * z;
}

Float surface_clearance(const TriangleCache& cache, const Vec3& p) {
    const Vec3 dp = p - cache.center();
    Float d = cache.radius() - std::sqrt(dot(dp, dp));
    // Every triangle of a plane lies within `reach` of it (triangle_cache.h),
    // so |n.p - off| - reach is at most the distance to each of them; the
    // second rounding allowance covers this expression's own rounding.
    const Float rounding = cache.rounding();
    for (const TriangleCache::Plane& q : cache.planes())
        d = std::min(d, std::fabs(dot(q.n, p) - q.off) - q.reach - rounding);
    return d > 0 ? d : 0;
}

bool segment_clear(const Scene& scene, const TriangleCache& cache, const Vec3& p, const Vec3& w, Float back, Float s) {
    thread_local std::vector<Hit> hits;
    if (cache.covers(p - w * back, p + w * s))
        cache.intersect(scene, p, w, -back, s, hits);
    else
        scene.intersect_all(p, w, -back, s, hits);
    return hits.empty();
}

Vec3 camera_axis_inside(const TriangleCache& cache, const Vec3& p, const Vec3& c, Float n) {
    const Vec3 out = normalize(c - p);
    const TriangleCache::Plane* near = nullptr;
    Float best = kInf;
    for (const TriangleCache::Plane& q : cache.planes()) {
        const Float dist = std::fabs(dot(q.n, p) - q.off);
        if (dist < best) {
            best = dist;
            near = &q;
        }
    }
    if (!near) return out;
    const Vec3 N = dot(near->n, out) >= 0 ? near->n : -near->n;
    // Snell, n sin(t1) = sin(t0): the inside direction whose refraction is `out`
    // (pbrt-v4's refract, run backwards): w = (out - cos0 N) / n + cos1 N.
    const Float cos0 = dot(out, N), sin0_2 = std::max(Float(0), 1 - cos0 * cos0);
    const Float cos1 = std::sqrt(std::max(Float(0), 1 - sin0_2 / (n * n)));
    const Vec3 w = (out - N * cos0) / n + N * cos1;
    const Float len = length(w);
    return len > 0 ? w / len : out;
}

LookBackDraw sample_look_back(const Vec3& d, const Vec3& axis, Float g, Float alpha, Float gb, double u0, double u1,
                              double u2) {
    const HenyeyGreenstein hg(g), hb(gb);
    Float sin_phi, cos_phi;
    det_sincos(2 * kPi * u2, &sin_phi, &cos_phi);
    LookBackDraw out;
    out.w = (u0 < alpha ? hb : hg).sample_p(u0 < alpha ? axis : d, u1, sin_phi, cos_phi);
    // q(w) = (1 - alpha) p_g(d.w) + alpha p_gb(axis.w): the balance heuristic's
    // one-sample mixture (Veach 1997, eq. 9.13), so p_g / q <= 1 / (1 - alpha).
    const Float p = hg.p(dot(d, out.w));
    const Float q = (1 - alpha) * p + alpha * hb.p(dot(axis, out.w));
    out.ratio = q > 0 ? p / q : 0;
    return out;
}

namespace {

// Attenuation coefficient (cm^-1) of unscattered light in region r at lambda_nm.
Float extinction(const Scene& scene, int r, Float lambda_nm) {
    const Medium& m = scene.region(size_t(r)).medium;
    return m.mua_at(lambda_nm) + m.mus_at(lambda_nm);
}

// Where the straight path p + t w (t in [0, tmax]) first leaves every region,
// starting in `set`; the optical depth before it. Crossings closer than a
// tolerance scaled to the coordinates are one (touching faces). A crossing
// into a region of another refractive index than n1 would refract the path:
// `other_n` is set and the walk stops.
struct PathExit {
    bool found = false, other_n = false;
    Float t = 0;
    uint32_t region = 0, prim = 0;
    Float tau = 0;
};

PathExit walk_out(const Scene& scene, const Vec3& p, const Vec3& w, Float tmax, uint64_t set, Float lambda_nm, Float n1,
                  std::vector<Hit>& hits) {
    PathExit out;
    scene.intersect_all(p, w, 0, tmax, hits);
    const Float scale = max_abs_component(p) + scene.extent();
    Float t_prev = 0;
    size_t i = 0;
    while (i < hits.size()) {
        const Float t0 = hits[i].t;
        const Float tol = 1e-6 * (scale + std::fabs(t0));
        if (set) out.tau += extinction(scene, scene.top(set), lambda_nm) * (t0 - t_prev);
        size_t j = i, leaving = i;
        for (; j < hits.size() && hits[j].t - t0 <= tol; ++j) {
            const uint64_t bit = uint64_t(1) << hits[j].region;
            if (hits[j].cos_dn < 0) {
                set |= bit;
            } else {
                set &= ~bit;
                leaving = j;
            }
        }
        if (set == 0) {
            out.found = true;
            out.t = t0;
            out.region = hits[leaving].region;
            out.prim = hits[leaving].prim;
            return out;
        }
        if (scene.region(size_t(scene.top(set))).medium.n != n1) {
            out.other_n = true;
            return out;
        }
        t_prev = t0;
        i = j;
    }
    return out;
}

// The refraction point on the plane through x0 with outward unit normal N:
// the point x where light from p (inside, index n1) refracts toward c (outside,
// index n0), Snell's law n1 sin(t1) = n0 sin(t0). In the plane of incidence,
// with the event at depth h below the plane, the camera at height H above it
// and their feet D apart, the foot distance r of x solves
// f(r) = n r / sqrt(r^2 + h^2) - (D - r) / sqrt((D - r)^2 + H^2) = 0, n = n1/n0,
// increasing on [0, D] from f(0) < 0 to f(D) > 0: Newton's method kept inside
// the bracket (bisection where a step would leave it), from the point where
// the straight line crosses the plane.
struct Refraction {
    bool ok = false;
    Vec3 x;
    Float l1 = 0, l2 = 0, cos1 = 1, cos0 = 1;  // lengths in scene units
};

Refraction refraction_point(const Vec3& p, const Vec3& c, const Vec3& x0, const Vec3& N, Float n) {
    Refraction out;
    const Float h = dot(x0 - p, N), H = dot(c - x0, N);
    if (!(h > 0 && H > 0)) return out;  // the event or the camera on the wrong side of the facet
    const Vec3 pf = p + N * h, cf = c - N * H;
    const Vec3 dv = cf - pf;
    const Float D = length(dv);
    Float r = 0;
    if (D > 1e-12 * (h + H)) {
        Float lo = 0, hi = D;
        r = D * h / (h + H);
        for (int it = 0; it < 60; ++it) {
            const Float a = std::sqrt(r * r + h * h), b = std::sqrt((D - r) * (D - r) + H * H);
            const Float f = n * r / a - (D - r) / b;
            (f < 0 ? lo : hi) = r;
            const Float df = n * h * h / (a * a * a) + H * H / (b * b * b);
            Float next = r - f / df;
            if (!(next > lo && next < hi)) next = 0.5 * (lo + hi);
            const bool done = std::fabs(next - r) <= 1e-13 * D || hi - lo <= 1e-13 * D;
            r = next;
            if (done) break;
        }
    }
    out.x = D > 0 ? pf + dv * (r / D) : pf;
    out.l1 = std::sqrt(r * r + h * h);
    out.l2 = std::sqrt((D - r) * (D - r) + H * H);
    out.cos1 = h / out.l1;
    out.cos0 = H / out.l2;
    out.ok = out.l1 > 0 && out.l2 > 0;
    return out;
}

}  // namespace

void next_event(const Scene& scene, const CameraView& view, const CameraEvent& e, double u, std::vector<Hit>& hits,
                CameraScores& out) {
    CameraCounters& k = out.counters;
    const Vec3& C = view.position;
    const Vec3 v = C - e.p;
    const Float dist = length(v);
    if (!(dist > 0)) return;
    // The facet the straight line to the pinhole leaves the tissue through.
    const PathExit line = walk_out(scene, e.p, v / dist, dist, e.set, e.lambda_nm, e.n, hits);
    if (line.other_n) {
        ++k.crossing;
        return;
    }
    if (!line.found) {
        ++k.unresolved;
        return;
    }
    const Float n0 = scene.ambient_n(), n = e.n / n0, unit_cm = scene.unit_cm();
    Vec3 N = scene.region(line.region).normals[line.prim];
    Vec3 x0 = e.p + v / dist * line.t;
    Refraction rf;
    Float q = 1, tau = 0;
    bool solved = false;
    // Solve on the facet; if the path to x leaves through another facet
    // (a curved wall), solve again on that one.
    for (int iter = 0; iter < 4 && !solved; ++iter) {
        rf = refraction_point(e.p, C, x0, N, n);
        if (!rf.ok) break;
        if (iter == 0 && view.pixel_of(rf.x) < 0) return;  // outside the image: nothing to score
        const Vec3 w = (rf.x - e.p) / rf.l1;
        const Float tol = 1e-6 * (max_abs_component(e.p) + scene.extent()) + 1e-9 * rf.l1;
        // Cast past x: where the wall curves away from the facet x lies inside
        // the tissue, and the exit found beyond it gives the facet to solve on.
        const PathExit pe = walk_out(scene, e.p, w, 2 * rf.l1 + tol, e.set, e.lambda_nm, e.n, hits);
        if (pe.other_n) {
            ++k.crossing;
            return;
        }
        if (!pe.found) break;
        tau = pe.tau * unit_cm;
        const Float gap = std::fabs(pe.t - rf.l1);
        if (gap <= tol + 1e-3 * rf.l1) {
            solved = true;
            break;
        }
        N = scene.region(pe.region).normals[pe.prim];
        x0 = e.p + w * pe.t;
    }
    if (!solved) {
        ++k.unresolved;
        return;
    }
    const int64_t pixel = view.pixel_of(rf.x);
    if (pixel < 0) return;
    // Depth roulette (unbiased): beyond tau_cut a score survives with chance
    // exp(tau_cut - tau) and counts 1/chance, so no score carries more than
    // exp(-tau_cut) of attenuation and adds no heavy tail. (Most deep events
    // never get here: camera_prefilter thins them with the same u.)
    if (tau > view.tau_cut) {
        q = det_exp(view.tau_cut - tau);
        if (!(u < q)) {
            ++k.thinned;
            return;
        }
    }
    // Occlusion: the lumen segment from x to the pinhole must enter no region.
    const Vec3 to_c = (C - rf.x) / rf.l2;
    const Float eps = 1e-6 * (max_abs_component(rf.x) + scene.extent());
    Hit h;
    if (rf.l2 > 2 * eps && scene.intersect_any(rf.x, to_c, eps, rf.l2 - eps, 0, h).found) {
        ++k.occluded;
        return;
    }
    const Vec3 w = (rf.x - e.p) / rf.l1;
    const Float p_hg = HenyeyGreenstein(e.g).p(dot(e.d, w));
    Float cos_t;
    const Float T = 1 - fresnel_dielectric(rf.cos1, e.n, n0, &cos_t);
    // Solid angle inside per area across the ray at the pinhole, cm^-2
    // (docs/render.md): 1 / ((l1 + n l2)(l1 cos0 / cos1 + n l2 cos1 / cos0)).
    const Float L1 = rf.l1 * unit_cm, L2 = rf.l2 * unit_cm;
    const Float G = 1 / ((L1 + n * L2) * (L1 * rf.cos0 / rf.cos1 + n * L2 * rf.cos1 / rf.cos0));
    const Float value = e.weight_energy * p_hg * det_exp(-tau) * T * G / view.pixel_solid_angle[size_t(pixel)] / q;
    if (!(value > 0 && std::isfinite(value))) return;
    out.scores.push_back(CameraScore{e.packet, uint32_t(pixel), e.fluorescent ? 1u : 0u, e.lambda_nm, value});
    ++k.scored;
}

CameraImage::CameraImage(std::shared_ptr<const CameraView> view) : view_(std::move(view)) {
    const CameraView& v = *view_;
    sums.assign(v.pixels() * size_t(v.batches) * size_t(v.channels), 0.0);
    spectrum.assign(v.pixels() * 2 * size_t(v.spectrum_bins), 0.0);
}

void CameraImage::add(const CameraScores& unit) {
    const CameraView& v = *view_;
    const size_t K = size_t(v.channels), B = size_t(v.batches), nb = size_t(v.spectrum_bins);
    for (const CameraScore& s : unit.scores) {
        const size_t li = v.lambda_index(s.lambda_nm);
        double* cell = &sums[(size_t(s.pixel) * B + size_t(v.batch_of(s.packet))) * K];
        const double* row = &v.table[li * K];
        for (size_t c = 0; c < K; ++c)
            if (s.fluorescent || !v.fluorescent_only[c]) cell[c] += s.value * row[c];
        const int32_t bin = v.spectrum_bin[li];
        if (bin >= 0) {
            spectrum[(size_t(s.pixel) * 2) * nb + size_t(bin)] += s.value;
            if (s.fluorescent)
                spectrum[(size_t(s.pixel) * 2 + 1) * nb + size_t(bin)] += s.value * v.spectrum_fluorescent_weight[li];
        }
    }
    counters.add(unit.counters);
}

}  // namespace ep
