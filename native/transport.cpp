#include "transport.h"

#include <algorithm>
#include <cmath>

#include "eem.h"
#include "fresnel.h"
#include "phase.h"
#include "rng.h"
#include "voxel_grid.h"

namespace ep {

namespace {

// Reference wavelength of the energy convention: a 500 nm packet of weight 1
// carries energy 1, so energy = weight * 500 / lambda (photon energy ~ 1/lambda).
constexpr Float kEnergyReferenceNm = 500;

// Ray-origin tolerance scaled to the coordinate's magnitude (pbrt-v4 practice):
// Embree works in float, so a hit is only known to ~1e-7 of |p|. Queries look
// this far *behind* the packet as well (a negative tnear): a crossing that
// rounding put just behind it is still seen, and re-seeing the surface just
// crossed is harmless because region membership updates are idempotent
// (entering sets a bit, leaving clears it).
inline Float ray_offset(const Vec3& p, Float extent) {
    return 4e-7 * (max_abs_component(p) + 1e-3 * extent);
}

// Hits closer than this are one crossing: coincident faces of touching regions,
// or the two triangles of an edge.
inline Float group_tolerance(const Vec3& p, Float t, Float extent) {
    return 2e-6 * (max_abs_component(p) + t) + 1e-7 * extent;
}

struct MediumState {
    int region = -1;
    Float mua = 0, mus = 0, mut = 0, g = 0, n = 1;
};

}  // namespace

Tracer::Tracer(const Scene& scene, const Source& source, const Halton& halton, const RunConfig& cfg)
    : scene_(scene), source_(source), halton_(halton), cfg_(cfg) {
    spectral_ = cfg.force_spectral || scene.has_fluorophores() || scene.has_spectral_media();
    grids_ = cfg.grid_voxel_size > 0;
    hits_.reserve(64);
}

void Tracer::trace(uint64_t index, UnitOutput& out) {
    if (spectral_) {
        if (grids_) trace_impl<true, true>(index, out);
        else trace_impl<true, false>(index, out);
    } else {
        if (grids_) trace_impl<false, true>(index, out);
        else trace_impl<false, false>(index, out);
    }
}

template <bool kSpectral, bool kGrids>
void Tracer::trace_impl(uint64_t index, UnitOutput& out) {
    const Scene& scene = scene_;
    const Float unit_cm = scene.unit_cm();
    const Float extent = scene.extent();
    double* tally = out.tally.scalar;
    double* energy_tally = out.tally.energy;
    out.tally.packets += 1;

    Rng rng(cfg_.seed, index);
    const Emission em = source_.emit(halton_, index, kSpectral);
    const Vec3 source_axis = source_.lights()[size_t(em.light)].axis;
    Vec3 entry_reference = source_axis;
    Vec3 p = em.position, d = em.direction;
    Float W = 1;
    Float lambda = em.wavelength;
    // Photon energy per unit weight at the current wavelength (1 when not spectral).
    Float energy_per_weight = kSpectral && lambda > 0 ? kEnergyReferenceNm / lambda : Float(1);
    // Adds weight w to tally k and, in spectral runs, its energy to the mirror tally.
    auto add = [&](int k, Float w) {
        tally[k] += w;
        if constexpr (kSpectral) energy_tally[k] += w * energy_per_weight;
    };
    if constexpr (kSpectral) energy_tally[kEnergyLaunched] += energy_per_weight;

    // Packet state.
    uint64_t set = 0;
    MediumState med;
    bool entered = false, fluorescent = false;
    int fluorophore = -1;
    Vec3 entry_p = p, entry_in(0, 0, 0);
    Float max_depth = 0, path_cm = 0;
    uint32_t scatterings = 0;
    uint64_t events = 0;
    const uint64_t max_events = cfg_.max_steps > 0 ? std::min<uint64_t>(cfg_.max_steps, kSafetyMaxEvents)
                                                   : kSafetyMaxEvents;

    auto load_medium = [&](int region) {
        med.region = region;
        if (region < 0) {
            med.mua = med.mus = med.mut = med.g = 0;
            med.n = scene.ambient_n();
            return;
        }
        const Medium& m = scene.region(size_t(region)).medium;
        if constexpr (kSpectral) {
            med.mua = m.mua_at(lambda);
            med.mus = m.mus_at(lambda);
        } else {
            med.mua = m.mua;
            med.mus = m.mus;
        }
        // A non-scattering region has no interactions: its absorption is applied
        // exactly along each straight segment (Beer-Lambert), not sampled.
        med.mut = med.mus > 0 ? med.mua + med.mus : 0;
        med.g = m.g;
        med.n = m.n;
    };

    auto escape = [&](int from_region, const Vec3& normal_out) {
        // Reflected = leaving back through the side it came in: against the
        // inward normal at its first entry. (Against the source axis, as MCML
        // puts it for normal incidence, misclassifies oblique beams beyond 45
        // degrees, whose mirror direction still has a positive dot product with
        // the beam.) Packets that started inside use the source axis.
        const bool reflected = dot(d, entry_reference) < 0;
        add(reflected ? kDiffuse : kTransmitted, W);
        const Float energy = W * energy_per_weight;
        tally[kEscapedEnergy] += energy;
        if (fluorescent) tally[kFluorescentEscaped] += W;
        if (cfg_.record_escapes && W > 0 && (!cfg_.fluorescent_only || fluorescent)) {  // no zero-weight records
            EscapeRecord r;
            r.position = p;
            r.direction = d;
            r.normal = normal_out;
            r.entry = entry_p;
            r.weight = W;
            r.energy = energy;
            r.wavelength = lambda;
            r.max_depth_cm = max_depth;
            r.fluorophore = fluorophore;
            r.region = from_region;
            r.scatterings = scatterings;
            r.packet = index;
            r.fluorescent = fluorescent ? 1 : 0;
            r.light = uint8_t(em.light);
            r.kind = reflected ? 0 : 1;
            out.records.push(r);
        }
    };

    auto update_depth = [&]() {
        if (entered) max_depth = std::max(max_depth, dot(p - entry_p, entry_in) * unit_cm);
    };

    // Russian roulette (MCML): below the threshold survive with chance m, and
    // survivors carry W/m, which keeps the estimator unbiased. The weight it
    // destroys (+) or creates (-) is tallied so that the balance stays exact.
    auto survives_roulette = [&]() -> bool {
        if (W >= cfg_.roulette_threshold) return true;
        if (W <= 0) return false;
        if (rng.uniform() < cfg_.roulette_chance) {
            const Float boosted = W / cfg_.roulette_chance;
            add(kRoulette, -(boosted - W));
            W = boosted;
            return true;
        }
        add(kRoulette, W);
        return false;
    };

    // Beer-Lambert along a straight segment of length t (scene units) from p in
    // a region with mus = 0: W -> W exp(-mua t). For grids the segment is cut
    // where it crosses voxel faces (planes at (i + 1/2) h, cell-centred voxels),
    // so every piece lies in one voxel and deposits its exact share there.
    auto attenuate_clear = [&](Float t) {
        if (t <= 0 || W <= 0) return;
        const Float dW = -W * std::expm1(-med.mua * t * unit_cm);
        if constexpr (kGrids) {
            const Float h = cfg_.grid_voxel_size;
            cuts_.clear();
            cuts_.push_back(0);
            cuts_.push_back(t);
            for (int axis = 0; axis < 3 && cuts_.size() < 300000; ++axis) {
                const Float o = p[axis], v = d[axis];
                if (v == 0) continue;
                const Float a = o / h - Float(0.5), b = (o + v * t) / h - Float(0.5);
                const Float lo = std::min(a, b), hi = std::max(a, b);
                for (Float k = std::floor(lo) + 1; k <= hi && cuts_.size() < 300000; k += 1)
                    cuts_.push_back(((k + Float(0.5)) * h - o) / v);
            }
            std::sort(cuts_.begin(), cuts_.end());
            Float w = W;
            for (size_t k = 0; k + 1 < cuts_.size(); ++k) {
                const Float a = std::clamp(cuts_[k], Float(0), t), b = std::clamp(cuts_[k + 1], Float(0), t);
                if (b <= a) continue;
                const Float piece = -w * std::expm1(-med.mua * (b - a) * unit_cm);
                const Vec3 mid = p + d * (Float(0.5) * (a + b));
                out.absorbed_grid->add(mid.x, mid.y, mid.z, piece * energy_per_weight);
                w -= piece;
            }
        }
        add(kAbsorbed, dW);
        out.tally.absorbed_by_region[size_t(med.region)] += dW;
        W -= dW;
    };

    // ---- where does the packet start? One query to infinity along its
    // direction: a region whose first crossing is an exit contains the start.
    std::vector<Hit>& hits = hits_;
    scene.intersect_all(p, d, 0, kInf, hits);
    {
        uint64_t seen = 0;
        for (const Hit& h : hits) {
            const uint64_t bit = uint64_t(1) << h.region;
            if (seen & bit) continue;
            if (h.cos_dn == 0) continue;  // grazing: undecided, look at the next crossing
            seen |= bit;
            if (h.cos_dn > 0) set |= bit;
        }
    }
    if (set == 0 && hits.empty()) {
        add(kMissed, W);
        return;
    }
    load_medium(scene.top(set));
    if (set != 0) {
        entered = true;  // started inside: depth is measured from the start point
        entry_in = d;
    }
    bool reuse_hits = (set == 0);  // the first query is exactly the first ambient step
    Float tau = 0;                 // remaining dimensionless step (MCML's carried step)
    bool need_tau = true;
    // Safe ball: no surface lies within safe_r of safe_c (from a closest-point
    // query). A step whose end stays inside the ball cannot cross a surface,
    // because the ball is convex; so no ray query is needed for it.
    Vec3 safe_c = p;
    Float safe_r = 0;
    // After a closest-point query that did not cover the step (the packet is
    // near a surface), go straight to ray queries for a few steps instead of
    // paying for both queries every step.
    int point_query_cooldown = 0;
    constexpr int kCooldownSteps = 32;

    while (true) {
        if (need_tau) {
            tau = -std::log(rng.uniform_open_low());  // seed eq. (2): s = -ln(xi)/mu_t
            need_tau = false;
        }
        const Float s = med.mut > 0 ? tau / (med.mut * unit_cm) : kInf;

        // Safe-distance shortcut: no surface within `safe`, so no ray query.
        bool query = true;
        if (!reuse_hits && cfg_.safe_distance && med.region >= 0 && std::isfinite(s)) {
            const Vec3 end = p + d * s;
            const Vec3 off = end - safe_c;
            if (dot(off, off) < safe_r * safe_r) {
                query = false;
            } else if (point_query_cooldown > 0) {
                --point_query_cooldown;
            } else {
                const Float radius = std::min(extent, Float(64) * s);
                const Float dist = scene.distance_to_surface(p, radius) * (1 - 1e-5) - ray_offset(p, extent);
                if (s < dist) {
                    safe_c = p;
                    safe_r = dist;
                    query = false;
                } else {
                    point_query_cooldown = kCooldownSteps;
                }
            }
        }
        if (query) {
            if (!reuse_hits) scene.intersect_all(p, d, -ray_offset(p, extent), s, hits);
            reuse_hits = false;
            safe_r = 0;
        } else {
            hits.clear();
        }

        // ---- boundary crossings before the interaction point, in order.
        bool boundary_event = false;
        size_t i = 0;
        while (i < hits.size() && hits[i].t <= s) {
            const Float t0 = hits[i].t;
            const Float tol = group_tolerance(p, t0, extent);
            size_t j = i;
            uint64_t enter = 0, leave = 0;
            while (j < hits.size() && hits[j].t <= t0 + tol) {
                const uint64_t bit = uint64_t(1) << hits[j].region;
                if (hits[j].cos_dn < 0) enter |= bit;
                else if (hits[j].cos_dn > 0) leave |= bit;
                ++j;
            }
            // A region entered and left at the same point was only touched
            // (an edge or vertex grazed from outside): no change.
            const uint64_t both = enter & leave;
            enter &= ~both;
            leave &= ~both;
            const uint64_t new_set = (set | enter) & ~leave;
            const int new_top = scene.top(new_set);
            if (new_set == set || new_top == med.region) {
                // Not an interface: a spurious re-hit, or a lower-priority surface.
                set = new_set;
                i = j;
                continue;
            }
            // ---- an interface between med.region and new_top at t0.
            if (med.region >= 0 && med.mus == 0 && med.mua > 0) attenuate_clear(t0);
            p += d * t0;
            path_cm += t0 * unit_cm;
            tau = std::max(Float(0), tau - t0 * unit_cm * med.mut);
            ++events;
            update_depth();
            // Normal of the surface that makes the interface: the entered top
            // region's face, or else the face of the region being left.
            const int face_region = (enter >> new_top) & 1 ? new_top : med.region;
            Vec3 n_out(0, 0, 1);
            for (size_t k = i; k < j; ++k)
                if (int(hits[k].region) == face_region) {
                    n_out = scene.region(size_t(face_region)).normals[hits[k].prim];
                    break;
                }
            // Normal facing the incident side, and the incidence cosine.
            const Vec3 n_inc = dot(d, n_out) > 0 ? -n_out : n_out;
            const Float cos_i = std::min(Float(1), std::max(Float(0), -dot(d, n_inc)));
            const Float n1 = med.n;
            const Float n2 = new_top >= 0 ? scene.region(size_t(new_top)).medium.n : scene.ambient_n();
            Float cos_t = cos_i;
            Float R = 0;
            if (n1 != n2) R = fresnel_dielectric(cos_i, n1, n2, &cos_t);

            bool transmit;
            if (!entered && med.region < 0) {
                // First boundary from the ambient: the specular part leaves
                // deterministically (MCML's Rsp; seed eq. 1), the rest enters.
                add(kSpecular, W * R);
                W -= W * R;
                transmit = W > 0;
                if (!transmit) return;
            } else {
                transmit = R < 1 && (R == 0 || rng.uniform() >= R);
            }
            if (transmit) {
                if (n1 != n2) d = refract(d, n_inc, n1 / n2, cos_i, cos_t);
                set = new_set;
                if (new_top < 0) {
                    escape(med.region, -n_inc);  // n_inc faces the inside: outward is -n_inc
                    return;
                }
                if (!entered) {
                    entered = true;
                    entry_p = p;
                    entry_in = -n_inc;  // n_inc faces the ambient, so -n_inc points into the tissue
                    entry_reference = entry_in;
                }
                load_medium(new_top);
            } else {
                d = reflect(d, n_inc);
            }
            boundary_event = true;
            break;
        }
        if (events >= max_events || (cfg_.max_path_cm > 0 && path_cm >= cfg_.max_path_cm)) {
            add(kCut, W);
            return;
        }
        if (boundary_event) {
            // Clear absorbing regions lose weight at boundaries only.
            if (!survives_roulette()) return;
            continue;
        }

        if (!std::isfinite(s)) {
            // Travelling through the ambient or a clear region to infinity.
            if (med.region < 0) {
                // Outside every region with nothing ahead: it never entered
                // (escapes end the packet earlier), so it missed.
                add(kMissed, W);
            } else {
                // A clear, non-absorbing region extends to infinity along the ray:
                // impossible for a closed mesh; count it as cut, never lose it.
                add(kCut, W);
            }
            return;
        }

        // ---- interaction inside med.region.
        tally[kInteractions] += 1;
        p += d * s;
        path_cm += s * unit_cm;
        need_tau = true;
        ++events;
        update_depth();

        // Implicit capture, seed eq. (3): W -= W mua/(mua+mus).
        const Float dW = W * (med.mua / med.mut);
        W -= dW;
        add(kAbsorbed, dW);
        out.tally.absorbed_by_region[size_t(med.region)] += dW;
        if constexpr (kGrids) {
            // The absorbed grid holds energy (= weight when the run is not spectral).
            out.absorbed_grid->add(p.x, p.y, p.z, dW * energy_per_weight);
            if (fluorescent) {
                out.fluorescence_grid->add(p.x, p.y, p.z, W);
                if (!out.per_fluorophore.empty()) out.per_fluorophore[size_t(fluorophore)]->add(p.x, p.y, p.z, W);
            }
        }

        if constexpr (kSpectral) {
            // Fluorescence decision (seed §4): two random numbers per fluorophore,
            // against d and c (rule "paper"), or d scaled by the EEM's relative
            // excitation efficiency at the packet's wavelength (rule "eem").
            const auto& fl = scene.region(size_t(med.region)).fluorophores;
            const bool may = cfg_.rule == FluorescenceRule::kEEM || !fluorescent;
            if (may && W > 0) {
                for (const FluorophoreRef& f : fl) {
                    tally[kFluorescenceTrials] += 1;
                    const Float u1 = rng.uniform(), u2 = rng.uniform();
                    Float d_eff = f.d;
                    if (cfg_.rule == FluorescenceRule::kEEM) d_eff *= scene.eem(f.id).efficiency(lambda);
                    if (u1 < d_eff && u2 < f.c) {
                        lambda = scene.eem(f.id).sample_emission(lambda, rng.uniform(), rng.uniform());
                        // Stokes loss: the weight (photon count) is kept, the energy per
                        // photon drops from 500/lambda_ex to 500/lambda_em.
                        const Float new_epw = kEnergyReferenceNm / lambda;
                        energy_tally[kEnergyStokes] += W * (energy_per_weight - new_epw);
                        energy_per_weight = new_epw;
                        fluorescent = true;
                        fluorophore = f.id;
                        tally[kFluorescenceEvents] += 1;
                        load_medium(med.region);  // coefficients at the new wavelength
                        break;
                    }
                }
            }
        }

        // Scattering (seed §4): HG cosine, uniform azimuth.
        if (med.mus > 0 && W > 0) {
            const HenyeyGreenstein hg(med.g);
            const Float u1 = rng.uniform(), u2 = rng.uniform();
            d = hg.sample_p(d, u1, u2);
            ++scatterings;
        }

        if (!survives_roulette()) return;
        if (events >= max_events || (cfg_.max_path_cm > 0 && path_cm >= cfg_.max_path_cm)) {
            add(kCut, W);
            return;
        }
    }
}

}  // namespace ep
