#include "transport.h"

#include <algorithm>
#include <cmath>
#include <deque>
#include <optional>

#include "det_math.h"
#include "eem.h"
#include "fast_log.h"
#include "fresnel.h"
#include "lane_block.h"
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
inline Float ray_offset(const Vec3& p, Float extent) { return 4e-7 * (max_abs_component(p) + 1e-3 * extent); }

// Hits closer than this are one crossing: coincident faces of touching regions,
// or the two triangles of an edge.
inline Float group_tolerance(const Vec3& p, Float t, Float extent) {
    return 2e-6 * (max_abs_component(p) + t) + 1e-7 * extent;
}

struct MediumState {
    int region = -1;
    Float mua = 0, mus = 0, mut = 0, g = 0, n = 1;
};

// The one state of a packet in flight (MCML/MMC practice: a single struct that
// every step reads and writes).
struct PacketState {
    uint64_t index = 0;
    int light = 0;
    Vec3 p, d;
    DirectionFrame frame;  // scattering frame about d, valid while frame.about(d)
    Float W = 1;
    Float lambda = 0;
    Float energy_per_weight = 1;  // photon energy per unit weight (1 when not spectral)
    uint64_t set = 0;             // regions containing p (bit mask)
    MediumState med;
    bool entered = false, fluorescent = false;
    int fluorophore = -1;
    Vec3 entry_p, entry_in, entry_reference;
    Float max_depth = 0, path_cm = 0;
    uint32_t scatterings = 0;
    uint32_t exits = 0;  // exits into the ambient so far
    // Per-packet sums flushed to the unit tally once (flush_tallies) instead of
    // at every interaction: the interaction count, and the weight absorbed in
    // the current region (flushed when the region changes, load_medium).
    uint64_t interactions = 0;
    Float absorbed = 0;
    uint64_t events = 0;
    Float tau = 0;  // remaining dimensionless step (MCML's carried step)
    bool need_tau = true;
    bool reuse_hits = false;  // the hits in the buffer are this step's (no new query)
    // The look-back (camera_tally.h, docs/render.md "Look-back next event"):
    // armed when the last scattering drew a virtual event for the free flight
    // that follows it, from lb_origin, cleared by the next event and by every
    // boundary; lb_cache is the cube cache segment_clear decided the virtual's
    // flight with, and decides the real one's.
    bool lb_armed = false;
    Vec3 lb_origin;
    const TriangleCache* lb_cache = nullptr;
};

// The local triangle caches (triangle_cache.h) are the scene's, one per small
// cube of space (Scene::cell_cache): a step inside the ball of the cube it
// starts in tests that cube's few triangles (one plane per triangle on a
// curved wall) instead of an Embree query. A packet keeps the last cache it
// used while its steps stay in that ball. (The earlier per-thread cache,
// re-gathered around the packet whenever it left the ball, cost ~6k
// instructions a gather and served ~15 steps on colon_polyp's curved wall,
// so it switched itself off there: callgrind, 117k instructions a packet.)

// What a step through the crossings ahead ended with.
enum class Crossing { kNone, kBoundary, kEnded };

// The first crossing ahead that changes the top region: the hits [i, j) at t0.
struct Interface {
    bool found = false;
    size_t i = 0, j = 0;
    Float t0 = 0;
    uint64_t enter = 0, new_set = 0;
    uint64_t set_before = 0;  // the region set after the skipped (non-interface) crossings
    int new_top = -1;
};

// The named steps of one packet's walk over its PacketState: locate the start,
// find and cross the interfaces ahead, interact. One instance per packet.
template <bool kSpectral, bool kGrids>
class PacketWalk {
  public:
    PacketWalk(const Scene& scene, const Source& source, const Halton& halton, const RunConfig& cfg,
               std::vector<Hit>& hits, std::vector<Float>& cuts, const std::vector<uint8_t>& enclosed,
               LocalGeometry& local, RayShortcuts& shortcuts, UnitOutput& out)
        : scene_(scene),
          source_(source),
          halton_(halton),
          cfg_(cfg),
          hits_(hits),
          cuts_(cuts),
          enclosed_(enclosed),
          local_(local),
          shortcuts_(shortcuts),
          out_(out),
          unit_cm_(scene.unit_cm()),
          extent_(scene.extent()),
          max_events_(cfg.max_steps > 0 ? std::min<uint64_t>(cfg.max_steps, kSafetyMaxEvents) : kSafetyMaxEvents) {}

    void run(uint64_t index);

    // The walk with its plain interior steps in float32 lanes (lane_block.h,
    // Tracer::trace_lanes): it stops where they can go on in the lanes, in
    // `zone`. Walk::kLanes: to_lane() hands the packet over; after the lanes,
    // after_lanes() takes it back and walks on. kEnded: finish() flushes it.
    enum class Walk { kEnded, kLanes };
    Walk begin(uint64_t index, ClearSteps* zone);
    void to_lane(LaneBlock& block, int k, const ClearSteps& zone, bool seed_stream);
    Walk after_lanes(const LaneBlock& block, int k, ClearSteps& zone, bool* hopped);
    void finish();

  private:
    void walk(uint64_t index);
    Walk steps_from_here();
    bool lane_ready();
    void from_lane(const LaneBlock& block, int k, const ClearSteps& zone);
    bool interior_ready() const;
    const TriangleCache& cube_at(const Vec3& x, const TriangleCache* keep);
    const TriangleCache& own_cube(const Vec3& x, const TriangleCache* keep);
    static bool same_cube(const TriangleCache* a, const TriangleCache* b);
    bool interior_steps();
    // How zone_steps ended: the packet ended, its next step needs the general
    // loop, or it fluoresced where the zone holds it clear and goes on there.
    enum class ZoneExit { kEnded, kGeneral, kAgain };
    // kCamera: the run has a camera tally, offered every interaction (spectral runs only).
    template <bool kCamera>
    ZoneExit zone_steps(ClearSteps& zone);
    // fluoresce()'s trials for the interior steps (loop_trials()).
    struct LoopTrials {
        static constexpr size_t kMax = 4;  // fluorophores per region the loop holds
        int n = 0;                         // 0: fluoresce() would not try
        Float d[kMax], c[kMax];
    };
    LoopTrials loop_trials() const;
    // The fluorescence rule's two parts (fluoresce() and loop_trials() both use them).
    bool may_fluoresce() const { return cfg_.rule == FluorescenceRule::kEEM || !st_.fluorescent; }
    Float trial_d(const FluorophoreRef& f) const {
        return cfg_.rule == FluorescenceRule::kEEM ? f.d * scene_.eem(f.id).efficiency(st_.lambda) : f.d;
    }
    bool enter_zone(ClearSteps& zone, const TriangleCache& cache, const Vec3& p) const;
    bool hop_zone(ClearSteps& zone, const Vec3& p, const Vec3& ahead);
    bool start_zone(ClearSteps& zone);
    void flush_absorbed();
    void launch(uint64_t index);
    bool locate_start();
    void find_crossings(Float s);
    bool cached_crossings(Float s);
    void query(Float tnear, Float tfar, uint64_t set, int region);
    Interface next_interface(Float s, uint64_t set, int region) const;
    uint64_t inside_just_ahead(uint64_t regions, Float t) const;
    Crossing cross_interfaces(Float s);
    Crossing cross_interface(const Interface& f);
    bool first_boundary(const Vec3& n_inc, Float R, int* mirror);
    NextHit look_ahead();
    // mirror_lands()'s answer when the mirror ray lands but where is not known.
    static constexpr int kLandsSomewhere = 4;
    static_assert(kLandsSomewhere > kNextCamera, "kLandsSomewhere must differ from every NextHit");
    int mirror_lands();
    NextHit landing() const;
    Crossing leave_tissue(int from_region, const Vec3& normal_out);
    Crossing through_ambient(NextHit next);
    bool interact(Float s);
    void deposit_grids(const Vec3& p, Float dW, Float W);
    bool scatter_and_survive();
    bool fluoresce();
    void fluoresce_with(const FluorophoreRef& f);
    void offer_camera();
    void camera_event(const Vec3& p, const Vec3& d, Float W);
    void look_back_event(const Vec3& p, const Vec3& d, Float W);
    bool look_back_covers(const Vec3& d, Float s);
    Float no_fluorescence_chance() const;
    void escape();
    // The memo of the packet's light when it emits one ray only, else null.
    LaunchMemo* launch_memo() {
        LaunchMemo& m = shortcuts_.launch[size_t(st_.light)];
        return m.fixed_ray ? &m : nullptr;
    }
    // The rig head, when the lumen rule is on and the source has one.
    const RigBody* body() const { return cfg_.lumen ? source_.body() : nullptr; }
    bool reflected() const { return !enclosed_[size_t(st_.light)] && dot(st_.d, st_.entry_reference) < 0; }
    void record_exit(int from_region, const Vec3& normal_out, NextHit next);
    void load_medium(int region);
    void attenuate_clear(Float t);
    bool survives_roulette();
    bool over_caps() const {
        return st_.events >= max_events_ || (cfg_.max_path_cm > 0 && st_.path_cm >= cfg_.max_path_cm);
    }
    // The depth is read by the exit records only.
    void update_depth() {
        if (st_.entered && cfg_.record_escapes)
            st_.max_depth = std::max(st_.max_depth, dot(st_.p - st_.entry_p, st_.entry_in) * unit_cm_);
    }
    // Adds weight w to tally k and, in spectral runs, its energy to the mirror tally.
    void add(int k, Float w) {
        out_.tally.scalar[k] += w;
        if constexpr (kSpectral) out_.tally.energy[k] += w * st_.energy_per_weight;
    }

    const Scene& scene_;
    const Source& source_;
    const Halton& halton_;
    const RunConfig& cfg_;
    std::vector<Hit>& hits_;
    std::vector<Float>& cuts_;
    const std::vector<uint8_t>& enclosed_;
    LocalGeometry& local_;
    RayShortcuts& shortcuts_;
    UnitOutput& out_;
    const Float unit_cm_, extent_;
    const uint64_t max_events_;
    Rng rng_{0, 0};
    Rng camera_rng_{0, 0};  // the camera tally's depth roulette (its own stream)
    PacketState st_;
    mutable std::vector<Hit> probe_hits_;  // inside_just_ahead's own query (rare)
    // The lanes (begin): where the walk stops for them, the next step the
    // general loop's (a step the lanes found blocked), the weight handed over.
    ClearSteps* lane_zone_ = nullptr;
    bool skip_lanes_ = false;
    Float lane_w_in_ = 0;
};

template <bool kSpectral, bool kGrids>
void PacketWalk<kSpectral, kGrids>::run(uint64_t index) {
    walk(index);
    finish();
}

template <bool kSpectral, bool kGrids>
void PacketWalk<kSpectral, kGrids>::finish() {
    flush_absorbed();
    out_.tally.scalar[kInteractions] += Float(st_.interactions);
    EP_STAT_ADD(interactions, st_.interactions);
}

// The weight absorbed in st.med.region since the last flush goes to the tallies.
template <bool kSpectral, bool kGrids>
void PacketWalk<kSpectral, kGrids>::flush_absorbed() {
    if (st_.absorbed == 0) return;
    out_.tally.scalar[kAbsorbed] += st_.absorbed;
    out_.tally.absorbed_by_region[size_t(st_.med.region)] += st_.absorbed;
    st_.absorbed = 0;
}

template <bool kSpectral, bool kGrids>
void PacketWalk<kSpectral, kGrids>::walk(uint64_t index) {
    launch(index);
    if (!locate_start()) return;
    steps_from_here();
}

// walk()'s loop, from the packet's state (st_). With lanes (lane_zone_ set)
// it returns kLanes where the lanes can take the packet's next steps.
template <bool kSpectral, bool kGrids>
typename PacketWalk<kSpectral, kGrids>::Walk PacketWalk<kSpectral, kGrids>::steps_from_here() {
    PacketState& st = st_;
    constexpr Walk kEnded = Walk::kEnded;
    while (true) {
        if (interior_ready()) {
            if (!lane_zone_) {
                if (!interior_steps()) return kEnded;
            } else if (lane_ready()) {
                return Walk::kLanes;
            }
        }
        if (st.need_tau) {
            st.tau = neg_log_lattice(rng_.lattice_open_low());  // seed eq. (2): s = -ln(xi)/mu_t
            st.need_tau = false;
        }
        const Float s = st.med.mut > 0 ? st.tau / (st.med.mut * unit_cm_) : kInf;
        find_crossings(s);
        const Crossing c = cross_interfaces(s);
        if (c == Crossing::kEnded) return kEnded;
        if (over_caps()) {
            add(kCut, st.W);
            return kEnded;
        }
        if (c == Crossing::kBoundary) {
            // Clear absorbing regions lose weight at boundaries only.
            if (!survives_roulette()) return kEnded;
            continue;
        }
        if (!std::isfinite(s)) {
            // Travelling through the ambient or a clear region to infinity.
            if (st.med.region < 0) {
                // Outside every region with nothing ahead: it never entered
                // (every ambient leg after an entry is looked ahead by
                // through_ambient, which ends the packet there), so it missed.
                add(kMissed, st.W);
            } else {
                // A clear, non-absorbing region extends to infinity along the ray:
                // impossible for a closed mesh; count it as cut, never lose it.
                add(kCut, st.W);
            }
            return kEnded;
        }
        if (!interact(s)) return kEnded;
    }
}

// ---- the plain interior steps in float32 lanes (lane_block.h; Tracer::trace_lanes) ----

// Launches packet `index` and walks it to its first stop: the end, or where
// the lanes take it (in `zone`).
template <bool kSpectral, bool kGrids>
typename PacketWalk<kSpectral, kGrids>::Walk PacketWalk<kSpectral, kGrids>::begin(uint64_t index, ClearSteps* zone) {
    lane_zone_ = zone;
    launch(index);
    if (!locate_start()) return Walk::kEnded;
    return steps_from_here();
}

// Where interior_ready() holds, whether the lanes can take the next steps:
// a scattering region of HG with |g| < 1 (|g| = 1 are deltas: the walk's),
// weight within float's range, the packet clear in a zone (interior_steps()'s
// start, hop included), and its free path drawn (as zone_steps draws it).
template <bool kSpectral, bool kGrids>
bool PacketWalk<kSpectral, kGrids>::lane_ready() {
    PacketState& st = st_;
    if (skip_lanes_) {
        skip_lanes_ = false;
        return false;
    }
    if (!(st.med.mus > 0) || !(std::fabs(st.med.g) < 1) || !(st.W >= 1e-30)) return false;
    // Steps of at most 17 / mu_t: finite, and tiny against float's range.
    if (!(st.med.mut * unit_cm_ > 1e-20)) return false;
    if (!start_zone(*lane_zone_)) return false;
    if (st.need_tau) {
        st.tau = neg_log_lattice(rng_.lattice_open_low());  // seed eq. (2), as in walk
        st.need_tau = false;
    }
    return true;
}

// Hands the packet to slot k of the lanes, its position relative to the
// zone's centre. seed_stream: the packet's first time in the lanes; its
// xoshiro128++ stream is keyed by two draws of its own generator (so by
// (seed, packet index), whatever the slot), and kept in the slot after.
// The zone is narrowed for float32's rounding: 4e-6 of the radius (a
// position's rounding is 6e-8 of it, a distance's a few of those), and each
// step pays a slack of 1e-6 of it (docs/numerics.md, "Float32 lanes").
template <bool kSpectral, bool kGrids>
void PacketWalk<kSpectral, kGrids>::to_lane(LaneBlock& B, int k, const ClearSteps& zone, bool seed_stream) {
    const PacketState& st = st_;
    if (seed_stream) {
        const uint64_t a = rng_.next_u64(), b = rng_.next_u64();
        B.s0[k] = uint32_t(a), B.s1[k] = uint32_t(a >> 32), B.s2[k] = uint32_t(b);
        B.s3[k] = uint32_t(b >> 32) | 1u;  // never the all-zero state
        B.count[k] = 0;
    }
    const Vec3 c = zone.center(), q = st.p - c;
    const DirectionFrame f = st.frame.about(st.d) ? st.frame : DirectionFrame(st.d);
    B.qx[k] = float(q.x), B.qy[k] = float(q.y), B.qz[k] = float(q.z);
    B.tx[k] = float(f.t[0]), B.ty[k] = float(f.t[1]), B.tz[k] = float(f.t[2]);
    B.bx[k] = float(f.b[0]), B.by[k] = float(f.b[1]), B.bz[k] = float(f.b[2]);
    B.nx[k] = float(f.n[0]), B.ny[k] = float(f.n[1]), B.nz[k] = float(f.n[2]);
    // The lane's weight is a factor of the weight handed over (exactly 1 at
    // the start), so a step that captures nothing changes no bit of it.
    lane_w_in_ = st.W;
    B.w[k] = 1, B.tau[k] = float(st.tau), B.depth[k] = -1e30f, B.budget[k] = 0;
    B.steps[k] = 0;
    B.room[k] = uint32_t(std::min<uint64_t>(max_events_ - st.events, UINT32_MAX));
    const Float mut_cm = st.med.mut * unit_cm_, g = st.med.g;
    B.inv_mut[k] = float(1 / mut_cm), B.loss[k] = float(st.med.mua / st.med.mut);
    B.small_g[k] = std::fabs(g) < 0.25 ? -1 : 0;
    B.g[k] = float(g), B.hg0[k] = float(1 - g * g), B.hg1[k] = float(1 - g), B.hg2[k] = float(2 * g);
    B.hg3[k] = float(1 + g * g), B.hg_inv2g[k] = B.small_g[k] ? 0.f : float(1 / (2 * g));
    B.threshold[k] = float(cfg_.roulette_threshold / st.W);  // W >= 1e-30 (lane_ready)
    const Float r = zone.inner(), widen = 4e-6 * r + 4e-16 * zone.scale(), inner = std::max(r - widen, Float(0));
    B.inner[k] = float(inner), B.inner_r2[k] = float(inner * inner), B.slack[k] = float(1e-6 * r);
    const int planes = int(zone.plane_count());
    for (int j = 0; j < std::max(planes, B.planes[k]); ++j) {
        const bool used = j < planes;
        const Vec3 n = used ? zone.plane_normal(size_t(j)) : Vec3(0, 0, 0);
        B.pnx[j][k] = float(n.x), B.pny[j][k] = float(n.y), B.pnz[j][k] = float(n.z);
        B.poff[j][k] = used ? float(zone.plane_offset(size_t(j)) - dot(n, c) + widen) : -1e30f;
    }
    B.planes[k] = planes;
    B.n_planes = std::max(B.n_planes, planes);
    const bool depth = st.entered && cfg_.record_escapes;
    const Vec3 e = st.entry_p - c, in = depth ? st.entry_in : Vec3(0, 0, 0);
    B.ex[k] = float(e.x), B.ey[k] = float(e.y), B.ez[k] = float(e.z);
    B.ix[k] = float(in.x), B.iy[k] = float(in.y), B.iz[k] = float(in.z);
    B.trials[k] = 0, B.tried[k] = 0;
    if constexpr (kSpectral) {
        const LoopTrials t = loop_trials();
        static_assert(LoopTrials::kMax == size_t(LaneBlock::kMaxTrials), "the lanes hold the loop's trials");
        for (int j = 0; j < t.n; ++j) B.trial_d[j][k] = float(t.d[j]), B.trial_c[j][k] = float(t.c[j]);
        B.trials[k] = t.n;
        B.max_trials = std::max(B.max_trials, t.n);
    }
    B.active[k] = -1, B.reason[k] = 0;
}

// Takes the packet back from slot k: the position in scene coordinates, the
// direction renormalised in double with a new frame about it, the weight (the
// weight handed over times the lane's factor) and the weight captured (in
// double: the weight handed over less the weight left, so the balance closes
// to double rounding), the steps counted as interactions.
template <bool kSpectral, bool kGrids>
void PacketWalk<kSpectral, kGrids>::from_lane(const LaneBlock& B, int k, const ClearSteps& zone) {
    PacketState& st = st_;
    const uint32_t steps = B.steps[k];
    if (steps == 0) return;  // nothing changed
    // A blocked slot's next step is its drawn free path; a slow one draws anew.
    st.need_tau = B.reason[k] != kLaneBlocked;
    if (!st.need_tau) st.tau = Float(B.tau[k]);
    st.p = zone.center() + Vec3(Float(B.qx[k]), Float(B.qy[k]), Float(B.qz[k]));
    const Vec3 n(Float(B.nx[k]), Float(B.ny[k]), Float(B.nz[k]));
    st.d = n * (1 / std::sqrt(dot(n, n)));
    st.frame = DirectionFrame(st.d);
    st.W = lane_w_in_ * Float(B.w[k]);
    st.absorbed += lane_w_in_ - st.W;
    if constexpr (kSpectral) {
        // The energy captured at the packet's one wavelength in the lanes, and
        // its trials (a sum of ones: exact).
        out_.tally.energy[kEnergyAbsorbed] += (lane_w_in_ - st.W) * st.energy_per_weight;
        out_.tally.scalar[kFluorescenceTrials] += Float(B.tried[k]);
    }
    st.events += steps;
    st.interactions += steps;
    // A slot that fluoresced did not scatter at its last step: the walk does.
    st.scatterings += B.reason[k] == kLaneFluoresced ? steps - 1 : steps;
    if (st.entered && cfg_.record_escapes) st.max_depth = std::max(st.max_depth, Float(B.depth[k]) * unit_cm_);
}

// After the lanes: roulette and the caps where they were due, the hop to
// another cube's zone (at most once a blocked step, as zone_steps hops), else
// the general loop for the blocked step; then the walk goes on.
template <bool kSpectral, bool kGrids>
typename PacketWalk<kSpectral, kGrids>::Walk PacketWalk<kSpectral, kGrids>::after_lanes(const LaneBlock& B, int k,
                                                                                        ClearSteps& zone,
                                                                                        bool* hopped) {
    const bool stepped = B.steps[k] > 0, slow = B.reason[k] == kLaneSlow;
    from_lane(B, k, zone);
    if (stepped) *hopped = false;
    if constexpr (kSpectral) {
        if (B.reason[k] == kLaneFluoresced) {
            // interact()'s rest after an event, as zone_steps finishes it.
            fluoresce_with(scene_.region(size_t(st_.med.region)).fluorophores[size_t(B.fired[k])]);
            if (!scatter_and_survive()) return Walk::kEnded;
            return steps_from_here();
        }
    }
    if (slow) {
        if (!survives_roulette()) return Walk::kEnded;
        if (over_caps()) {
            add(kCut, st_.W);
            return Walk::kEnded;
        }
        return steps_from_here();
    }
    const Float s = st_.tau / (st_.med.mut * unit_cm_);
    const Vec3 b = st_.p + st_.d * s;
    if (!*hopped && zone.beyond_ball(b) && hop_zone(zone, st_.p, b)) {
        *hopped = true;
        return Walk::kLanes;
    }
    *hopped = false;
    skip_lanes_ = true;
    return steps_from_here();
}

// The interior steps (issue 11) run where a packet spends most of its steps:
// deep in one scattering region, the step inside the cached ball and apart
// from every cached plane, so it crosses nothing. They are walk's steps with
// nothing to cross, in a loop over locals (position, direction, weight, the
// generator's state, the counters; the compiler keeps them in registers)
// instead of over st_: the same random draws in the same order and the same
// floating-point expressions, so the tallies are bit-identical to the
// general loop's. Only the geometric test differs: ClearSteps
// (triangle_cache.h), a conservative form of cached_crossings' ball and plane
// tests that answers "nothing to cross" only where they would, and tests a
// step only when the distance budget of the last tested point runs out (a
// subtraction per step otherwise; no hit list). Anything else -- a step that
// may leave the ball or cross a plane, an infinite step -- goes back to the
// general loop with its free path drawn; roulette and the caps are interact()'s.
// Spectral packets take fluoresce()'s trials in the loop too (LoopTrials);
// an actual fluorescence event ends the loop, fluoresce_with() and
// scatter_and_survive() finish that interaction as interact() does, and the
// loop starts again at the new wavelength (ZoneExit::kAgain).
// (callgrind, seed tissue: 668 -> 402 instructions per interaction.)
template <bool kSpectral, bool kGrids>
bool PacketWalk<kSpectral, kGrids>::interior_ready() const {
    const PacketState& st = st_;
    if (!local_.enabled || !local_.cell || st.reuse_hits || st.med.region < 0 || !(st.med.mut > 0)) return false;
    // Spectral: the loop holds at most LoopTrials::kMax fluorophores.
    if constexpr (kSpectral) return scene_.region(size_t(st.med.region)).fluorophores.size() <= LoopTrials::kMax;
    return true;
}

// fluoresce()'s trials as the interior steps take them, fixed for the loop:
// the packet's wavelength, so d under the "eem" rule (d times the EEM's
// efficiency there), and whether fluoresce() tries at all, change only at a
// fluorescence event, which ends the loop. The same draws in the same order
// and the same comparisons, so the same events.
template <bool kSpectral, bool kGrids>
typename PacketWalk<kSpectral, kGrids>::LoopTrials PacketWalk<kSpectral, kGrids>::loop_trials() const {
    LoopTrials t;
    const PacketState& st = st_;
    if (!may_fluoresce()) return t;
    for (const FluorophoreRef& f : scene_.region(size_t(st.med.region)).fluorophores) {
        t.d[t.n] = trial_d(f);
        t.c[t.n] = f.c;
        ++t.n;
    }
    return t;
}

// Starts the interior steps' zone at p in `cache`; false when p is not clear there.
template <bool kSpectral, bool kGrids>
inline __attribute__((always_inline)) bool PacketWalk<kSpectral, kGrids>::enter_zone(ClearSteps& zone,
                                                                                     const TriangleCache& cache,
                                                                                     const Vec3& p) const {
    // The look-behind ray_offset(x) of any x in the ball is at most this
    // (|x|_max <= |center|_max + radius; the factor covers the rounding).
    const Float max_back =
        ray_offset(Vec3(max_abs_component(cache.center()) + cache.radius(), 0, 0), extent_) * 1.000001;
    return zone.start(cache, p, max_back);
}

// The zone of the packet's position in its last cube's cache, or else (the
// position outside that ball) in the cache of the cube it is in; false when
// neither holds it clear.
template <bool kSpectral, bool kGrids>
bool PacketWalk<kSpectral, kGrids>::start_zone(ClearSteps& zone) {
    return enter_zone(zone, *local_.cell, st_.p) || (zone.beyond_ball(st_.p) && hop_zone(zone, st_.p, st_.p));
}

// Moves the zone, starting at p, to the cache of the cube `ahead` is in (the
// end of the step that left the ball: the packet heads that way, so the
// zone lasts longer there than in p's cube; callgrind, colon_polyp: 72.5k ->
// 71.0k instructions a packet), or else of the cube p is in (the one
// cached_crossings turns to), and makes it the thread's last cache; false
// when neither is new and has p clear. Any cache whose ball holds the step
// answers it alike, so the choice changes no result. (~11 of the loop's ~19
// exits a packet on colon_polyp were steps that left the ball.) Not inlined:
// zone_steps' loop calls it on a branch marked unlikely.
template <bool kSpectral, bool kGrids>
__attribute__((noinline)) bool PacketWalk<kSpectral, kGrids>::hop_zone(ClearSteps& zone, const Vec3& p,
                                                                       const Vec3& ahead) {
    // The lookups inline (built_cell_cache), cell_cache's call only to build
    // (callgrind, colon_polyp at 30,000 packets: 48.6k -> 48.3k instructions
    // a packet; cell_cache itself inline cost the other scenes ~1%).
    const TriangleCache* own = &cube_at(ahead, nullptr);
    if (same_cube(own, local_.cell) || !enter_zone(zone, *own, p)) {
        const TriangleCache* first = own;  // tried already (p's cube when `ahead` is in it)
        own = &cube_at(p, first);
        if (same_cube(own, local_.cell) || same_cube(own, first) || !enter_zone(zone, *own, p)) return false;
    }
    local_.cell = own;
    return true;
}

// The cache of the cube x is in (the store's, built if need be). In the
// lanes, a cube the full store does not keep is gathered into one of the
// slot's own caches (SlotCaches), not the one the walk holds nor `keep`.
template <bool kSpectral, bool kGrids>
inline const TriangleCache& PacketWalk<kSpectral, kGrids>::cube_at(const Vec3& x, const TriangleCache* keep) {
    if (const TriangleCache* c = scene_.built_cell_cache(x)) return *c;
    if (!local_.own) return scene_.cell_cache(x);
    return own_cube(x, keep);
}

// cube_at's gather into the slot's own caches, out of line (the walks
// without lanes never call it).
template <bool kSpectral, bool kGrids>
__attribute__((noinline)) const TriangleCache& PacketWalk<kSpectral, kGrids>::own_cube(const Vec3& x,
                                                                                       const TriangleCache* keep) {
    // The gather's mailbox (a stamp per scene triangle) is the thread's; the
    // slot keeps a copy of the content.
    thread_local TriangleCacheBuilder gather;
    const TriangleCache& c = scene_.cube_cache(x, gather);
    if (&c != &gather) return c;  // the store's, or none (x outside the grid)
    TriangleCacheBuilder& mine = local_.own->spare(local_.cell, keep);
    mine = gather;
    return mine;
}

// Whether two caches are one cube's: the same cache, or (a slot's own caches)
// the same centre (a cube's centre is its own; a cache that covers nothing
// has radius 0).
template <bool kSpectral, bool kGrids>
inline bool PacketWalk<kSpectral, kGrids>::same_cube(const TriangleCache* a, const TriangleCache* b) {
    if (a == b) return true;
    if (!a || !b || !(a->radius() > 0) || !(b->radius() > 0)) return false;
    const Vec3 ca = a->center(), cb = b->center();
    return ca.x == cb.x && ca.y == cb.y && ca.z == cb.z;
}

// The interior steps from the cube the packet is in; false when the packet
// ended (roulette, caps).
template <bool kSpectral, bool kGrids>
bool PacketWalk<kSpectral, kGrids>::interior_steps() {
    ClearSteps zone;
    if (!start_zone(zone)) return true;
    ZoneExit exit;
    // The camera tally's loop is a copy of its own: runs without one keep
    // the loop as it was.
    if constexpr (kSpectral) {
        if (cfg_.camera_view) {
            do exit = zone_steps<true>(zone);
            while (exit == ZoneExit::kAgain);
            return exit == ZoneExit::kGeneral;
        }
    }
    do exit = zone_steps<false>(zone);
    while (exit == ZoneExit::kAgain);
    return exit == ZoneExit::kGeneral;
}

// The loop of the steps the zone clears, zone after zone: a step that leaves
// the ball goes on in the cache of another cube (hop_zone), as
// cached_crossings would answer it, at most once a step (`hopped`: no
// hopping back and forth); if that cube cannot clear it either, the general
// loop takes it. The hop is called on a branch marked unlikely: a call on a
// branch the compiler deems common makes it keep the loop's state in memory
// (callgrind, seed tissue: 316 against 267 instructions per interaction),
// and a hop made by the caller, out of the loop, cost a store and set-up of
// that state per hop (colon_polyp at 30,000 packets: 54.2k against 49.5k
// instructions a packet). Not inlined into walk(): on its own the loop gets
// the registers (seed tissue: 418 against 428 instructions per interaction
// inlined).
template <bool kSpectral, bool kGrids>
template <bool kCamera>
__attribute__((noinline)) typename PacketWalk<kSpectral, kGrids>::ZoneExit PacketWalk<kSpectral, kGrids>::zone_steps(
    ClearSteps& zone) {
    static_assert(kSpectral || !kCamera, "the camera tally needs a spectral run");
    PacketState& st = st_;
    const Float mut_cm = st.med.mut * unit_cm_, loss = st.med.mua / st.med.mut;
    const HenyeyGreenstein hg(st.med.g);
    const bool depth = st.entered && cfg_.record_escapes;
    const Vec3 entry_p = st.entry_p, entry_in = st.entry_in;
    const Float unit_cm = unit_cm_, threshold = cfg_.roulette_threshold;
    // W >= fast_min means W > 0 and W >= threshold: scatter, no roulette.
    const Float fast_min = threshold > 0 ? threshold : std::numeric_limits<Float>::min();
    const bool path_cap = cfg_.max_path_cm > 0;
    // The position in lanes, like the frame (p + n s is 3 vector operations);
    // the direction is frame.n, bit for bit.
    Lanes4 p = to_lanes(st.p);
    DirectionFrame frame = st.frame.about(st.d) ? st.frame : DirectionFrame(st.d);
    // path_cm is read by the path cap only (over_caps), and with a cap every
    // step leaves the loop (room = 0), so the loop adds a step's length on its
    // way out, and only then: the same sums as interact()'s where they are read.
    Float W = st.W, tau = st.tau, path_cm = st.path_cm, absorbed = st.absorbed;
    uint32_t scatterings = st.scatterings;
    // Steps taken here (interactions, events and cached steps alike), and
    // how many the event cap leaves (none with a path cap: every step then
    // ends in over_caps(), as in interact()).
    uint64_t steps = 0, room = path_cap ? 0 : max_events_ - st.events;
    bool need_tau = st.need_tau;
    Rng rng = rng_;
    LoopTrials trials;
    uint64_t n_trials = 0;  // fluorescence trials taken here
    bool hopped = false;    // the zone was just entered for this step (hop_zone)
    // Spectral runs: the absorbed-energy tally in a local through the loop
    // (the same running sum, added to in the same order, written back by
    // store(); nothing else adds to it in the loop), and the packet's energy
    // per weight, fixed here (a fluorescence event ends the loop).
    Float energy_absorbed = 0, energy_per_weight = 0;
    const bool look_back = kCamera && cfg_.camera_view->look_back;
    if constexpr (kSpectral) {
        trials = loop_trials();
        energy_absorbed = out_.tally.energy[kEnergyAbsorbed];
        energy_per_weight = st.energy_per_weight;
    }
    auto store = [&] {
        // A sum of ones is exact, so adding the count at once is bit-identical.
        if constexpr (kSpectral) out_.tally.scalar[kFluorescenceTrials] += Float(n_trials);
        if constexpr (kSpectral) out_.tally.energy[kEnergyAbsorbed] = energy_absorbed;
        n_trials = 0;
        st.p = to_vec3(p);
        st.d = frame.dir();
        st.frame = frame;
        st.W = W;
        st.tau = tau;
        st.need_tau = need_tau;
        st.path_cm = path_cm;
        st.absorbed = absorbed;
        st.events += steps;
        st.interactions += steps;
        room = path_cap ? 0 : max_events_ - st.events;
        steps = 0;
        st.scatterings = scatterings;
        rng_ = rng;
    };
    // The free path is drawn where walk draws it -- after the scattering and
    // the roulette of the last interaction -- but at the end of each
    // iteration, so that the loop has no branch on need_tau.
    auto draw_tau = [&] {
        tau = neg_log_lattice(rng.lattice_open_low());  // seed eq. (2), as in walk
        need_tau = false;
    };
    if (need_tau) draw_tau();
    // Every free path is at most -ln(2^-53) = 36.7 (the smallest uniform), so
    // when this one and 64 give finite steps, every step in the loop is
    // finite; else walk takes the infinite one.
    if (!(std::max(tau, Float(64)) / mut_cm < kInf)) {
        store();
        return ZoneExit::kGeneral;
    }
    while (true) {
        const Float s = tau / mut_cm;
        const Lanes4 b = p + frame.n * s;
        if (__builtin_expect(!zone.clear(b, s), 0)) {
            if (hopped || !zone.beyond_ball(to_vec3(b)) || !hop_zone(zone, to_vec3(p), to_vec3(b))) break;
            hopped = true;
            continue;
        }
        hopped = false;
        // interact(s), its steps in the same order.
        ++steps;
        // The look-back: whether the virtual event drawn at the last
        // scattering stands for this one (its flight was clear).
        bool covered = false;
        if constexpr (kCamera)
            if (st.lb_armed) covered = look_back_covers(frame.dir(), s);
        p = b;  // = p + d * s, bit for bit
        need_tau = true;
        // The depth goes to st_ directly: a local would hold registers in
        // every run, though only runs with exit records read it.
        if (depth) st.max_depth = std::max(st.max_depth, dot(to_vec3(p) - entry_p, entry_in) * unit_cm);
        const Float dW = W * loss;
        W -= dW;
        absorbed += dW;
        if constexpr (kSpectral) energy_absorbed += dW * energy_per_weight;
        // interact()'s deposits: a fluorescence event, which would change
        // st.fluorescent, ends the loop below.
        if constexpr (kGrids) deposit_grids(to_vec3(p), dW, W);
        if (kSpectral && trials.n > 0 && W > 0) {
            // fluoresce()'s trials: an event ends the loop, and interact()'s
            // rest of this interaction follows it in the general code.
            int k = 0;
            while (k < trials.n) {
                ++n_trials;
                const Float u1 = rng.uniform(), u2 = rng.uniform();
                if (u1 < trials.d[k] && u2 < trials.c[k]) break;
                ++k;
            }
            if (k < trials.n) {
                if (path_cap) path_cm += s * unit_cm;
                store();
                fluoresce_with(scene_.region(size_t(st.med.region)).fluorophores[size_t(k)]);
                // interact()'s order: the camera is offered the event after the fluorescence.
                // A fluorescent event scores itself, covered or not (the virtual
                // stood for the branch without fluorescence only).
                if constexpr (kCamera)
                    if (st.med.mus > 0 && st.W > 0) offer_camera();
                // The packet stays at p, which the zone holds clear, so the
                // steps go on in it at the new wavelength: zone_steps again,
                // with the coefficients fluoresce_with loaded, instead of a
                // step of the general loop that would find the same nothing
                // to cross (~1 a packet on colon_polyp, where nearly every
                // packet fluoresces once).
                const Vec3 d_in = st.d;
                if (!scatter_and_survive()) return ZoneExit::kEnded;
                if (look_back) look_back_event(st.p, d_in, st.W);
                return ZoneExit::kAgain;
            }
        }
        // interact()'s camera offer, after the capture and the fluorescence
        // trials, before the scattering (mus > 0: the zone's region scatters).
        Vec3 d_in;
        if constexpr (kCamera) {
            d_in = frame.dir();
            if (W > 0) {
                if (covered)
                    ++out_.camera.counters.covered;
                else
                    camera_event(to_vec3(p), d_in, W);
            }
        }
        // The common case, laid out on the straight path to the next step.
        if (__builtin_expect(W >= fast_min && steps < room, 1)) {
            hg.scatter(rng.next_u64(), ++scatterings, &frame);
        } else {
            if (W > 0) hg.scatter(rng.next_u64(), ++scatterings, &frame);
            if (W < threshold || steps >= room) {
                // Roulette and the caps as interact() ends with them (the caps
                // can only hold here: see `room`).
                if (path_cap) path_cm += s * unit_cm;
                store();
                if (!survives_roulette()) return ZoneExit::kEnded;
                if (over_caps()) {
                    add(kCut, st.W);
                    return ZoneExit::kEnded;
                }
                W = st.W;
                rng = rng_;
                if constexpr (kSpectral) energy_absorbed = out_.tally.energy[kEnergyAbsorbed];
            }
        }
        // The look-back's virtual event for the flight ahead, from the state
        // the packet goes on with (after the scattering, roulette and caps).
        if constexpr (kCamera)
            if (look_back) look_back_event(to_vec3(p), d_in, W);
        draw_tau();
    }
    store();
    return ZoneExit::kGeneral;
}

template <bool kSpectral, bool kGrids>
void PacketWalk<kSpectral, kGrids>::launch(uint64_t index) {
    out_.tally.packets += 1;
    rng_ = Rng(cfg_.seed, index);
    if (cfg_.camera_view) camera_rng_ = Rng(cfg_.seed ^ 0x6A09E667F3BCC909ULL, index);
    const Emission em = source_.emit(halton_, index, kSpectral);
    PacketState& st = st_;
    st.index = index;
    st.light = em.light;
    st.entry_reference = source_.lights()[size_t(em.light)].axis;
    st.p = em.position;
    st.d = em.direction;
    st.lambda = em.wavelength;
    st.energy_per_weight = kSpectral && st.lambda > 0 ? kEnergyReferenceNm / st.lambda : Float(1);
    if constexpr (kSpectral) out_.tally.energy[kEnergyLaunched] += st.energy_per_weight;
    st.entry_p = st.p;
}

// Where does the packet start? One query to infinity along its direction: a
// region whose first crossing is an exit contains the start. False if the
// packet meets nothing at all (tallied as missed).
template <bool kSpectral, bool kGrids>
bool PacketWalk<kSpectral, kGrids>::locate_start() {
    PacketState& st = st_;
    LaunchMemo* memo = launch_memo();
    if (memo && memo->start.matches(st.p, st.d)) {
        hits_.assign(memo->start.hits.begin(), memo->start.hits.end());
    } else if (!memo && shortcuts_.launch[size_t(st.light)].in_ambient) {
        // The start is in no region, so the hits are only the first ambient
        // step's, and query() finds what next_interface needs of them: the
        // first crossing, with the same refined distance (tnear = 0, as here).
        // (callgrind, colon_polyp: ~1k instructions a packet.)
        query(0, kInf, 0, -1);
    } else {
        scene_.intersect_all(st.p, st.d, 0, kInf, hits_);
        if (memo) memo->start.store(st.p, st.d, hits_);
    }
    uint64_t seen = 0;
    for (const Hit& h : hits_) {
        const uint64_t bit = uint64_t(1) << h.region;
        if (seen & bit) continue;
        if (h.cos_dn == 0) continue;  // grazing: undecided, look at the next crossing
        seen |= bit;
        if (h.cos_dn > 0) st.set |= bit;
    }
    if (st.set == 0 && hits_.empty()) {
        add(kMissed, st.W);
        return false;
    }
    load_medium(scene_.top(st.set));
    if (st.set != 0) {
        st.entered = true;  // started inside: depth is measured from the start point
        st.entry_in = st.d;
    }
    st.reuse_hits = (st.set == 0);  // the first query is exactly the first ambient step
    if (st.set == 0 && body()) {
        // Started in the ambient: the rig head may be in the way.
        const NextHit next = landing();
        if (next == kNextHead || next == kNextCamera) return through_ambient(next) != Crossing::kEnded;
    }
    return true;
}

// Fills hits_ with the crossings along a step of length s: from the local
// triangle cache when the step stays inside its ball, else by a full query.
template <bool kSpectral, bool kGrids>
void PacketWalk<kSpectral, kGrids>::find_crossings(Float s) {
    PacketState& st = st_;
    if (st.reuse_hits) {
        st.reuse_hits = false;
        return;
    }
    if (local_.enabled && st.med.region >= 0 && std::isfinite(s) && cached_crossings(s)) return;
    query(-ray_offset(st.p, extent_), s, st.set, st.med.region);
}

// Fills hits_ with the crossings along [tnear, tfar] from st.p for a packet in
// `set` (top region `region`). Embree's single-hit query answers when its one
// crossing decides alone: it changes the top region (an interface, so
// next_interface stops there) and its clearance from the triangle's edges and
// from other surfaces exceeds twice the grouping tolerance, so no other hit of
// the all-hits list could join its group; hits the single-hit query skips
// (re-hits of the surface just crossed, crossings that do not change the set)
// are ones next_interface passes over anyway. Otherwise (a hit at an edge, on
// coincident or nearby faces of touching regions, a lower-priority surface
// inside a higher one) the all-hits query lists every crossing.
template <bool kSpectral, bool kGrids>
void PacketWalk<kSpectral, kGrids>::query(Float tnear, Float tfar, uint64_t set, int region) {
    const PacketState& st = st_;
    EP_STAT(full_queries);
    Hit h;
    const Scene::FirstHit f = scene_.intersect_first(st.p, st.d, tnear, tfar, set, h);
    if (!f.found) {
        hits_.clear();
        return;
    }
    const uint64_t new_set = set ^ (uint64_t(1) << h.region);  // the filter accepts set changes only
    if (f.clearance > 2 * group_tolerance(st.p, std::max(h.t, Float(0)), extent_) && scene_.top(new_set) != region) {
        hits_.assign(1, h);
        return;
    }
    scene_.intersect_all(st.p, st.d, tnear, tfar, hits_);
}

// The crossings of the step [-offset, s] from the cache of the cube the
// packet is in. False when that cache cannot answer (the step leaves its
// ball, or too many triangles meet it): the caller queries Embree.
template <bool kSpectral, bool kGrids>
bool PacketWalk<kSpectral, kGrids>::cached_crossings(Float s) {
    const PacketState& st = st_;
    const Float back = ray_offset(st.p, extent_);
    const Vec3 a = st.p - st.d * back, b = st.p + st.d * s;
    const TriangleCache* cache = local_.cell;
    if (!cache || !cache->covers(a, b)) {
        cache = &cube_at(st.p, nullptr);
        // A step too long for the ball of the cube it starts in may fit in
        // the ball of the cube of its midpoint (any cache that covers a step
        // lists its crossings).
        if (!cache->covers(a, b)) cache = &cube_at((a + b) * Float(0.5), cache);
        if (!cache->covers(a, b)) {
            EP_STAT(cache_misses);
            return false;
        }
        local_.cell = cache;
    }
    EP_STAT(cache_hits);
    cache->intersect(scene_, st.p, st.d, -back, s, hits_);
    return true;
}

// The first crossing before s that changes the top region, for a packet in
// the region set `set` whose top region is `region`: groups of coincident
// hits are one crossing.
template <bool kSpectral, bool kGrids>
Interface PacketWalk<kSpectral, kGrids>::next_interface(Float s, uint64_t set, int region) const {
    const std::vector<Hit>& hits = hits_;
    Interface f;
    // In the ambient, hits at the origin include the surface the packet is on.
    const Float own_surface = region < 0 ? group_tolerance(st_.p, 0, extent_) : -kInf;
    size_t i = 0;
    while (i < hits.size() && hits[i].t <= s) {
        const Float t0 = hits[i].t;
        const Float tol = group_tolerance(st_.p, t0, extent_);
        size_t j = i;
        uint64_t enter = 0, leave = 0;
        while (j < hits.size() && hits[j].t <= t0 + tol) {
            const uint64_t bit = uint64_t(1) << hits[j].region;
            if (hits[j].cos_dn < 0)
                enter |= bit;
            else if (hits[j].cos_dn > 0)
                leave |= bit;
            ++j;
        }
        // A region entered and left at the same point was only touched
        // (an edge or vertex grazed from outside): no change. At the packet's
        // own position in the ambient the two cases look alike -- leaving the
        // surface it is on past a convex vertex, or entering the next face at a
        // concave edge of a cavity -- so a point just ahead decides.
        uint64_t both = enter & leave;
        if (both && t0 <= own_surface) {
            const Float t_next = j < hits.size() ? hits[j].t : t0 + 1e3 * tol;
            const uint64_t entered = inside_just_ahead(both, Float(0.5) * (std::max(t0, Float(0)) + t_next));
            both &= ~entered;
            leave &= ~entered;
        }
        enter &= ~both;
        leave &= ~both;
        const uint64_t new_set = (set | enter) & ~leave;
        const int new_top = scene_.top(new_set);
        if (new_set == set || new_top == region) {
            // Not an interface: a spurious re-hit, or a lower-priority surface.
            set = new_set;
            i = j;
            continue;
        }
        f.found = true;
        f.i = i;
        f.j = j;
        f.t0 = t0;
        f.enter = enter;
        f.new_set = new_set;
        f.new_top = new_top;
        break;
    }
    f.set_before = set;
    return f;
}

// Which of `regions` contain the point st.p + t st.d: along the ray from that
// point, a region whose first crossing is an exit contains it (as in
// locate_start).
template <bool kSpectral, bool kGrids>
uint64_t PacketWalk<kSpectral, kGrids>::inside_just_ahead(uint64_t regions, Float t) const {
    scene_.intersect_all(st_.p + st_.d * t, st_.d, 0, kInf, probe_hits_);
    uint64_t seen = 0, inside = 0;
    for (const Hit& h : probe_hits_) {
        const uint64_t bit = uint64_t(1) << h.region;
        if (!(regions & bit) || (seen & bit) || h.cos_dn == 0) continue;
        seen |= bit;
        if (h.cos_dn > 0) inside |= bit;
    }
    return inside;
}

// Boundary crossings before the interaction point, in order; the first
// interface ends the scan.
template <bool kSpectral, bool kGrids>
Crossing PacketWalk<kSpectral, kGrids>::cross_interfaces(Float s) {
    if (hits_.empty()) return Crossing::kNone;  // most steps in tissue: nothing ahead
    const Interface f = next_interface(s, st_.set, st_.med.region);
    st_.set = f.set_before;
    return f.found ? cross_interface(f) : Crossing::kNone;
}

// An interface between st.med.region and f.new_top: move there, then reflect
// or refract (Fresnel, Snell).
template <bool kSpectral, bool kGrids>
Crossing PacketWalk<kSpectral, kGrids>::cross_interface(const Interface& f) {
    PacketState& st = st_;
    const int new_top = f.new_top;
    st.lb_armed = false;  // the flight met a boundary: the next event scores itself
    if (st.med.region >= 0 && st.med.mus == 0 && st.med.mua > 0) attenuate_clear(f.t0);
    st.p += st.d * f.t0;
    st.path_cm += f.t0 * unit_cm_;
    st.tau = std::max(Float(0), st.tau - f.t0 * unit_cm_ * st.med.mut);
    ++st.events;
    EP_STAT(crossings);
    update_depth();
    // Normal of the surface that makes the interface: the entered top
    // region's face, or else the face of the region being left.
    const int face_region = (f.enter >> new_top) & 1 ? new_top : st.med.region;
    Vec3 n_out(0, 0, 1);
    for (size_t k = f.i; k < f.j; ++k)
        if (int(hits_[k].region) == face_region) {
            n_out = scene_.region(size_t(face_region)).normals[hits_[k].prim];
            break;
        }
    // Normal facing the incident side, and the incidence cosine.
    const Vec3 n_inc = dot(st.d, n_out) > 0 ? -n_out : n_out;
    const Float cos_i = std::min(Float(1), std::max(Float(0), -dot(st.d, n_inc)));
    const Float n1 = st.med.n;
    const Float n2 = new_top >= 0 ? scene_.region(size_t(new_top)).medium.n : scene_.ambient_n();
    Float cos_t = cos_i;
    Float R = 0;
    if (n1 != n2) R = fresnel_dielectric(cos_i, n1, n2, &cos_t);

    bool transmit;
    int mirror = -1;  // where the mirror ray lands, if first_boundary knows (its hits are then in the buffer)
    if (!st.entered && st.med.region < 0) {
        transmit = first_boundary(n_inc, R, &mirror);
        if (st.W <= 0) return Crossing::kEnded;
    } else {
        transmit = R < 1 && (R == 0 || rng_.uniform() >= R);
    }
    if (!transmit) {
        st.d = reflect(st.d, n_inc);
        if (st.med.region >= 0) return Crossing::kBoundary;
        // Reflected on the ambient side: the packet goes on through the ambient.
        const bool known = mirror >= 0 && mirror != kLandsSomewhere;
        return through_ambient(known ? NextHit(mirror) : look_ahead());
    }
    if (n1 != n2) st.d = refract(st.d, n_inc, n1 / n2, cos_i, cos_t);
    st.set = f.new_set;
    if (new_top < 0) return leave_tissue(st.med.region, -n_inc);  // n_inc faces the inside
    if (st.med.region < 0) {
        // Entering from the ambient (first entry or a landing across the lumen):
        // depth and the reflected/transmitted classification refer to this entry.
        st.entered = true;
        st.entry_p = st.p;
        st.entry_in = -n_inc;  // n_inc faces the ambient, so -n_inc points into the tissue
        st.entry_reference = st.entry_in;
        st.max_depth = 0;
    }
    load_medium(new_top);
    return Crossing::kBoundary;
}

// The first boundary from the ambient (docs/design.md, "The first boundary").
// Where the mirror ray meets nothing, the specular part leaves deterministically
// (MCML's Rsp; seed eq. 1) and the rest enters: W -> W (1 - R), transmit. Where
// the mirror ray lands on tissue or the head (a concave scene), the specular
// part is light that goes on, so the boundary makes the same random choice as
// every later one: reflect the whole packet with probability R. Both are
// unbiased; the first keeps convex scenes bit-identical to MCML's estimator.
template <bool kSpectral, bool kGrids>
bool PacketWalk<kSpectral, kGrids>::first_boundary(const Vec3& n_inc, Float R, int* mirror) {
    PacketState& st = st_;
    if (R > 0 && cfg_.lumen) {
        const Vec3 d_in = st.d;
        st.d = reflect(d_in, n_inc);
        // The mirror ray of a one-ray light is the same for every packet: its
        // hits and landing come from the memo after the first packet.
        LaunchMemo* memo = launch_memo();
        int lands;
        if (memo && memo->mirror.matches(st.p, st.d)) {
            hits_.assign(memo->mirror.hits.begin(), memo->mirror.hits.end());
            lands = memo->mirror.next;
        } else if (memo) {
            lands = look_ahead();
            memo->mirror.store(st.p, st.d, hits_, NextHit(lands));
        } else {
            lands = mirror_lands();
        }
        st.d = d_in;
        if (lands != kNextAway) {
            st.reuse_hits = false;
            *mirror = lands;
            return R < 1 && rng_.uniform() >= R;
        }
    }
    add(kSpecular, st.W * R);
    st.W -= st.W * R;
    st.reuse_hits = false;
    return st.W > 0;
}

// Whether the mirror ray st.p, st.d lands (look_ahead() != kNextAway), which
// is all first_boundary needs of it unless the packet reflects: look_ahead()'s
// answer, or kLandsSomewhere (its hits are then not in the buffer, and
// cross_interface looks ahead after the reflection, along the same ray).
// Every packet of a wide beam makes this query and ~99% transmit, so it asks
// Embree's any-hit query whether the ray enters a region at all: a crossing
// that enters one, clear of every other surface by more than twice the
// grouping tolerance (as in query()), is an interface in landing()'s scan
// (the ambient's set stays empty up to the first interface, and no hit of
// that region can join its group to cancel it), so the ray lands on tissue
// or on the rig head before it; no entering crossing at all is look_ahead()'s
// empty hit list, exactly. Otherwise look_ahead() decides.
// (callgrind, colon_polyp at 10,000 packets: a mirror ray cost ~2.6k
// instructions by look_ahead, ~1.4k so; 45.4k -> 44.8k a packet.)
template <bool kSpectral, bool kGrids>
int PacketWalk<kSpectral, kGrids>::mirror_lands() {
    const PacketState& st = st_;
    Hit h;
    const Scene::FirstHit f = scene_.intersect_any(st.p, st.d, -ray_offset(st.p, extent_), kInf, 0, h);
    if (!f.found) {
        hits_.clear();
        return landing();
    }
    if (f.clearance > 2 * group_tolerance(st.p, std::max(h.t, Float(0)), extent_)) return kLandsSomewhere;
    return look_ahead();
}

// One ray query from st.p along st.d to infinity (the hits stay in the buffer
// as the next ambient step), then where it lands.
template <bool kSpectral, bool kGrids>
NextHit PacketWalk<kSpectral, kGrids>::look_ahead() {
    query(-ray_offset(st_.p, extent_), kInf, 0, -1);  // from the ambient (landing's set and region)
    return landing();
}

// Where a packet in the ambient lands, from the hits to infinity in the
// buffer: the first region it enters, unless the rig head is nearer.
template <bool kSpectral, bool kGrids>
NextHit PacketWalk<kSpectral, kGrids>::landing() const {
    const Interface f = next_interface(kInf, 0, -1);
    if (const RigBody* b = body()) {
        const BodyHit h = intersect_body(*b, st_.p, st_.d);
        if (h.part != BodyPart::kNone && (!f.found || h.t < f.t0))
            return h.part == BodyPart::kCamera ? kNextCamera : kNextHead;
    }
    return f.found ? kNextTissue : kNextAway;
}

// The packet left the tissue into the ambient: a surface photon record, then
// it goes on in a straight line (issue 9). One ray query per exit.
template <bool kSpectral, bool kGrids>
Crossing PacketWalk<kSpectral, kGrids>::leave_tissue(int from_region, const Vec3& normal_out) {
    ++st_.exits;
    if (!cfg_.lumen) {  // the rule off: every exit ends the packet
        record_exit(from_region, normal_out, kNextAway);
        escape();
        return Crossing::kEnded;
    }
    NextHit next;
    if (shortcuts_.entry_planes.none_ahead(st_.p, st_.d, ray_offset(st_.p, extent_))) {
        // look_ahead's query would find nothing (entry_planes.h): its answer
        // without Embree, as landing() gives it for no hits.
        hits_.clear();
        next = body() ? landing() : kNextAway;
    } else {
        next = look_ahead();
    }
    load_medium(-1);
    record_exit(from_region, normal_out, next);
    return through_ambient(next);
}

// The packet is in the ambient and the hits to infinity are in the buffer:
// it lands on tissue (the hits are its next step), stops on the head or the
// camera, or leaves the scene for good.
template <bool kSpectral, bool kGrids>
Crossing PacketWalk<kSpectral, kGrids>::through_ambient(NextHit next) {
    switch (next) {
        case kNextTissue:
            st_.reuse_hits = true;
            return Crossing::kBoundary;
        case kNextHead:
            add(kOccluded, st_.W);
            return Crossing::kEnded;
        case kNextCamera:
            add(kCameraCollected, st_.W);
            return Crossing::kEnded;
        case kNextAway:
            break;
    }
    if (st_.entered)
        escape();
    else
        add(kMissed, st_.W);  // never entered any region
    return Crossing::kEnded;
}

// An interaction at distance s inside st.med.region: implicit capture,
// fluorescence, scattering, roulette. False when the packet ends.
template <bool kSpectral, bool kGrids>
bool PacketWalk<kSpectral, kGrids>::interact(Float s) {
    PacketState& st = st_;
    ++st.interactions;
    st.p += st.d * s;
    st.path_cm += s * unit_cm_;
    st.need_tau = true;
    ++st.events;
    update_depth();
    // The look-back: whether the virtual event drawn at the last scattering
    // stands for this one (its flight was clear); lb_armed is set only with a camera.
    bool covered = false;
    if constexpr (kSpectral)
        if (st.lb_armed) covered = look_back_covers(st.d, s);

    // Implicit capture, seed eq. (3): W -= W mua/(mua+mus).
    const Float dW = st.W * (st.med.mua / st.med.mut);
    st.W -= dW;
    st.absorbed += dW;
    if constexpr (kSpectral) out_.tally.energy[kEnergyAbsorbed] += dW * st.energy_per_weight;
    if constexpr (kGrids) deposit_grids(st.p, dW, st.W);
    if constexpr (kSpectral) {
        const bool fluoresced = fluoresce();
        if (cfg_.camera_view) {
            if (st.med.mus > 0 && st.W > 0) {
                if (covered && !fluoresced)  // a fluorescent event scores itself, covered or not
                    ++out_.camera.counters.covered;
                else
                    offer_camera();
            }
            if (cfg_.camera_view->look_back) {
                const Vec3 d_in = st.d;
                if (!scatter_and_survive()) return false;
                look_back_event(st.p, d_in, st.W);
                return true;
            }
        }
    }
    return scatter_and_survive();
}

// The camera tally's next event (camera_tally.h): the packet as it is about
// to scatter (after the capture and any fluorescence), at its wavelength.
// Not inlined: runs without a camera keep interact() as it was.
template <bool kSpectral, bool kGrids>
__attribute__((noinline)) void PacketWalk<kSpectral, kGrids>::offer_camera() {
    camera_event(st_.p, st_.d, st_.W);
}

// An event at p with direction d and weight W (the interior steps hold p, d
// and W in registers; the rest of the packet's state is st_'s). Every event
// draws one number of the camera's stream, in event order, whether or not a
// bound decides it: the interior steps and the general loop, and the bound
// on or off, give each event the same u, so the same scores.
template <bool kSpectral, bool kGrids>
__attribute__((noinline)) void PacketWalk<kSpectral, kGrids>::camera_event(const Vec3& p, const Vec3& d, Float W) {
    thread_local std::vector<Hit> hits;
    const PacketState& st = st_;
    const CameraView& view = *cfg_.camera_view;
    const double u = camera_rng_.uniform();
    // The clearance from the cache of the cube p is in (built if it is not
    // yet, or gathered into a scratch once the store is full): its content
    // is a function of the cube alone, so the bound, and with it the
    // counters, are the same on any thread count (the cache the thread used
    // last would depend on the thread's history, and which cubes a full
    // store kept on the threads' timing).
    auto clearance = [&] {
        thread_local TriangleCacheBuilder scratch;  // a cube the full store does not keep (Scene::cube_cache)
        return surface_clearance(scene_.cube_cache(p, scratch), p);
    };
    if (!camera_prefilter(view, p, u, st.med.mut * unit_cm_, clearance, out_.camera.counters)) return;
    CameraEvent e;
    e.p = p;
    e.d = d;
    e.set = st.set;
    e.region = st.med.region;
    e.weight_energy = W * st.energy_per_weight;
    e.lambda_nm = st.lambda;
    e.fluorescent = st.fluorescent;
    e.packet = st.index;
    e.g = st.med.g;
    e.n = st.med.n;
    next_event(scene_, view, e, u, hits, out_.camera);
}

// The look-back's virtual event (docs/render.md "Look-back next event"), drawn
// after the scattering at p (direction d before it) from the state the packet
// goes on with, weight W: it stands for the next event's score where the
// flight there is clear of every triangle (segment_clear, by the cache of p's
// cube). From the camera's stream: a direction w from the mixture q about d
// and about the camera's direction inside (camera_axis_inside), and a free
// path s ~ mu_t exp(-mu_t s) in the same region. A clear flight scores, at
// p + s w with incoming direction w, the weight the next event would have
// after its capture, W (1 - mu_a / mu_t), times p_HG(d.w) / q(w) and the
// chance of no fluorescence there (a fluorescent event scores itself). Out of
// view (twice the image's margin) or deep nothing is armed: the next event
// scores itself, as without the look-back.
template <bool kSpectral, bool kGrids>
__attribute__((noinline)) void PacketWalk<kSpectral, kGrids>::look_back_event(const Vec3& p, const Vec3& d, Float W) {
    PacketState& st = st_;
    const CameraView& view = *cfg_.camera_view;
    st.lb_armed = false;
    if (!(W > 0) || !view.near_view(p, 2 * CameraView::kViewMargin)) return;
    // The look-back's own scratch (Scene::cube_cache): st.lb_cache points to it
    // until look_back_covers reads it at the next event, and nothing else
    // gathers into it in between (camera_event's clearance has its own).
    thread_local TriangleCacheBuilder scratch;
    const TriangleCache* cache = &scene_.cube_cache(p, scratch);
    // Deep: the flight starts more than kLookBackDepth optical depths beyond
    // tau_cut from every surface, where the next event's score is almost
    // always thinned anyway; not armed, it scores itself (the cheaper way).
    const Float mut_per_unit = st.med.mut * unit_cm_;
    if (mut_per_unit * surface_clearance(*cache, p) > view.tau_cut + CameraView::kLookBackDepth) return;
    const Vec3 axis = camera_axis_inside(*cache, p, view.position, st.med.n / scene_.ambient_n());
    const double u0 = camera_rng_.uniform(), u1 = camera_rng_.uniform(), u2 = camera_rng_.uniform();
    const LookBackDraw v = sample_look_back(d, axis, st.med.g, view.look_back_alpha, view.look_back_g, u0, u1, u2);
    const Float s = neg_log_lattice(camera_rng_.lattice_open_low()) / mut_per_unit;  // seed eq. (2)
    st.lb_armed = true;
    st.lb_origin = p;
    st.lb_cache = cache;
    const Float back = ray_offset(p, extent_);  // the look-behind of the transport's queries
    if (!segment_clear(scene_, *cache, p, v.w, back, s)) return;
    const Float ratio = view.look_back_ratio ? v.ratio : 1;
    const Float w_virtual = W * (1 - st.med.mua / st.med.mut) * ratio * no_fluorescence_chance();
    if (!(w_virtual > 0)) return;
    ++out_.camera.counters.looked_back;
    camera_event(p + v.w * s, v.w, w_virtual);
}

// Whether the armed virtual event stands for this one, reached from
// lb_origin along d after a flight of s: segment_clear of that flight, by the
// same cache and expressions as the virtual's. Disarms.
template <bool kSpectral, bool kGrids>
bool PacketWalk<kSpectral, kGrids>::look_back_covers(const Vec3& d, Float s) {
    PacketState& st = st_;
    st.lb_armed = false;
    const Float back = ray_offset(st.lb_origin, extent_);
    return segment_clear(scene_, *st.lb_cache, st.lb_origin, d, back, s);
}

// The grids' deposits of an interaction at p: the weight dW it absorbed (the
// absorbed grid holds energy, = weight when the run is not spectral) and, for
// a fluorescent packet, its weight W after the capture. interact() and the
// interior steps both deposit here; each voxel's sum is exact (voxel_grid.h),
// so the grids do not depend on which of them took a step. Not inlined:
// inline, the grid runs' loops grew and GCC compiled the other runs' loops
// worse (callgrind: colon with grids 74.5k -> 71.5k instructions a packet,
// but seed tissue 14,802 -> 15,069).
template <bool kSpectral, bool kGrids>
__attribute__((noinline)) void PacketWalk<kSpectral, kGrids>::deposit_grids(const Vec3& p, Float dW, Float W) {
    const PacketState& st = st_;
    out_.grids->deposit(p.x, p.y, p.z, cfg_.grid_absorbed, dW * st.energy_per_weight,
                        st.fluorescent && cfg_.grid_fluorescent_light, size_t(st.fluorophore), W);
}

// The rest of an interaction after capture and fluorescence: scattering,
// then roulette and the caps. False when the packet ends.
template <bool kSpectral, bool kGrids>
inline __attribute__((always_inline)) bool PacketWalk<kSpectral, kGrids>::scatter_and_survive() {
    PacketState& st = st_;
    // Scattering (seed §4): HG cosine, uniform azimuth.
    if (st.med.mus > 0 && st.W > 0) {
        const HenyeyGreenstein hg(st.med.g);
        if (!st.frame.about(st.d)) st.frame = DirectionFrame(st.d);
        hg.scatter(rng_.next_u64(), ++st.scatterings, &st.frame);
        st.d = st.frame.dir();
    }

    if (!survives_roulette()) return false;
    if (over_caps()) {
        add(kCut, st.W);
        return false;
    }
    return true;
}

// Fluorescence decision (seed §4): two random numbers per fluorophore, against
// d and c (rule "paper"), or d scaled by the EEM's relative excitation
// efficiency at the packet's wavelength (rule "eem").
template <bool kSpectral, bool kGrids>
bool PacketWalk<kSpectral, kGrids>::fluoresce() {
    PacketState& st = st_;
    const auto& fl = scene_.region(size_t(st.med.region)).fluorophores;
    if (!may_fluoresce() || st.W <= 0) return false;
    for (const FluorophoreRef& f : fl) {
        out_.tally.scalar[kFluorescenceTrials] += 1;
        const Float u1 = rng_.uniform(), u2 = rng_.uniform();
        if (u1 < trial_d(f) && u2 < f.c) {
            fluoresce_with(f);
            return true;
        }
    }
    return false;
}

// The chance that fluoresce() makes no fluorescence event at the packet's
// present wavelength and region: its trials are independent, fluorophore j
// fires with chance min(d_j, 1) min(c_j, 1) (u1 < d_j and u2 < c_j, u
// uniform in [0, 1)), and none fires with the product of 1 - that. 1 where
// fluoresce() makes no trial.
template <bool kSpectral, bool kGrids>
Float PacketWalk<kSpectral, kGrids>::no_fluorescence_chance() const {
    if (!may_fluoresce()) return 1;
    Float none = 1;
    for (const FluorophoreRef& f : scene_.region(size_t(st_.med.region)).fluorophores)
        none *= 1 - std::clamp(trial_d(f), Float(0), Float(1)) * std::clamp(f.c, Float(0), Float(1));
    return none;
}

// A fluorescence event of fluorophore f: the emission wavelength, the Stokes
// loss, the coefficients at the new wavelength.
template <bool kSpectral, bool kGrids>
void PacketWalk<kSpectral, kGrids>::fluoresce_with(const FluorophoreRef& f) {
    PacketState& st = st_;
    // The weight f converts, where it converts it (tally and emission grid).
    out_.tally.emitted_by_fluorophore[size_t(f.id)] += st.W;
    // In any run with grids, whichever walk it takes: a run that asks for the
    // emission grids alone takes the one without per-interaction deposits
    // (Tracer, grids_).
    if (out_.grids && cfg_.grid_emission) out_.grids->emit(st.p.x, st.p.y, st.p.z, size_t(f.id), st.W);
    st.lambda = scene_.eem(f.id).sample_emission(st.lambda, rng_.uniform(), rng_.uniform());
    // Stokes loss: the weight (photon count) is kept, the energy per
    // photon drops from 500/lambda_ex to 500/lambda_em.
    const Float new_epw = kEnergyReferenceNm / st.lambda;
    out_.tally.energy[kEnergyStokes] += st.W * (st.energy_per_weight - new_epw);
    st.energy_per_weight = new_epw;
    st.fluorescent = true;
    st.fluorophore = f.id;
    out_.tally.scalar[kFluorescenceEvents] += 1;
    load_medium(st.med.region);  // coefficients at the new wavelength
}

// Leaving the scene for good. Reflected (reflected()) = leaving back through
// the side it came in: against the inward normal at its last entry from the
// ambient. (Against the source axis, as MCML puts it for normal incidence,
// misclassifies oblique beams beyond 45 degrees, whose mirror direction still
// has a positive dot product with the beam.) Packets that started inside use
// the source axis. A light in a closed pocket of ambient (a cavity) has no
// side to come back to: whatever reaches infinity went through the tissue.
template <bool kSpectral, bool kGrids>
void PacketWalk<kSpectral, kGrids>::escape() {
    PacketState& st = st_;
    add(reflected() ? kDiffuse : kTransmitted, st.W);
    out_.tally.scalar[kEscapedEnergy] += st.W * st.energy_per_weight;
    if (st.fluorescent) out_.tally.scalar[kFluorescentEscaped] += st.W;
}

// The surface photon record of an exit into the ambient (every exit, any order).
template <bool kSpectral, bool kGrids>
void PacketWalk<kSpectral, kGrids>::record_exit(int from_region, const Vec3& normal_out, NextHit next) {
    const PacketState& st = st_;
    // No zero-weight records: they carry no light and would count towards "store N".
    if (!cfg_.record_escapes || !(st.W > 0) || (cfg_.fluorescent_only && !st.fluorescent)) return;
    EscapeRecord r;
    r.position = st.p;
    r.direction = st.d;
    r.normal = normal_out;
    r.entry = st.entry_p;
    r.weight = st.W;
    r.energy = st.W * st.energy_per_weight;
    r.wavelength = st.lambda;
    r.max_depth_cm = st.max_depth;
    r.fluorophore = st.fluorophore;
    r.region = from_region;
    r.scatterings = st.scatterings;
    r.packet = st.index;
    r.fluorescent = st.fluorescent ? 1 : 0;
    r.light = uint8_t(st.light);
    r.kind = reflected() ? 0 : 1;
    r.exit_order = st.exits;
    r.next_hit = next;
    out_.records.push(r);
}

template <bool kSpectral, bool kGrids>
void PacketWalk<kSpectral, kGrids>::load_medium(int region) {
    if (region != st_.med.region) flush_absorbed();
    MediumState& med = st_.med;
    med.region = region;
    if (region < 0) {
        med.mua = med.mus = med.mut = med.g = 0;
        med.n = scene_.ambient_n();
        return;
    }
    const Medium& m = scene_.region(size_t(region)).medium;
    if constexpr (kSpectral) {
        med.mua = m.mua_at(st_.lambda);
        med.mus = m.mus_at(st_.lambda);
    } else {
        med.mua = m.mua;
        med.mus = m.mus;
    }
    // A non-scattering region has no interactions: its absorption is applied
    // exactly along each straight segment (Beer-Lambert), not sampled.
    med.mut = med.mus > 0 ? med.mua + med.mus : 0;
    med.g = m.g;
    med.n = m.n;
}

// Russian roulette (MCML): below the threshold survive with chance m, and
// survivors carry W/m, which keeps the estimator unbiased. The weight it
// destroys (+) or creates (-) is tallied so that the balance stays exact.
template <bool kSpectral, bool kGrids>
bool PacketWalk<kSpectral, kGrids>::survives_roulette() {
    Float& W = st_.W;
    if (W >= cfg_.roulette_threshold) return true;
    if (W <= 0) return false;
    if (rng_.uniform() < cfg_.roulette_chance) {
        const Float boosted = W / cfg_.roulette_chance;
        add(kRoulette, -(boosted - W));
        W = boosted;
        return true;
    }
    add(kRoulette, W);
    return false;
}

// Beer-Lambert along a straight segment of length t (scene units) from p in
// a region with mus = 0: W -> W exp(-mua t). For grids the segment is cut
// where it crosses voxel faces (planes at (i + 1/2) h, cell-centred voxels),
// so every piece lies in one voxel and deposits its exact share there.
template <bool kSpectral, bool kGrids>
void PacketWalk<kSpectral, kGrids>::attenuate_clear(Float t) {
    PacketState& st = st_;
    if (t <= 0 || st.W <= 0) return;
    const Float dW = -st.W * det_expm1(-st.med.mua * t * unit_cm_);
    if (kGrids && cfg_.grid_absorbed) {
        const Float h = cfg_.grid_voxel_size;
        cuts_.clear();
        cuts_.push_back(0);
        cuts_.push_back(t);
        for (int axis = 0; axis < 3 && cuts_.size() < 300000; ++axis) {
            const Float o = st.p[axis], v = st.d[axis];
            if (v == 0) continue;
            const Float a = o / h - Float(0.5), b = (o + v * t) / h - Float(0.5);
            const Float lo = std::min(a, b), hi = std::max(a, b);
            for (Float k = std::floor(lo) + 1; k <= hi && cuts_.size() < 300000; k += 1)
                cuts_.push_back(((k + Float(0.5)) * h - o) / v);
        }
        std::sort(cuts_.begin(), cuts_.end());
        Float w = st.W;
        for (size_t k = 0; k + 1 < cuts_.size(); ++k) {
            const Float a = std::clamp(cuts_[k], Float(0), t), b = std::clamp(cuts_[k + 1], Float(0), t);
            if (b <= a) continue;
            const Float piece = -w * det_expm1(-st.med.mua * (b - a) * unit_cm_);
            const Vec3 mid = st.p + st.d * (Float(0.5) * (a + b));
            out_.absorbed_grid->add(mid.x, mid.y, mid.z, piece * st.energy_per_weight);
            w -= piece;
        }
    }
    add(kAbsorbed, dW);
    out_.tally.absorbed_by_region[size_t(st.med.region)] += dW;
    st.W -= dW;
}

}  // namespace

void RayMemo::store(const Vec3& p_, const Vec3& d_, const std::vector<Hit>& hits_, NextHit next_) {
    valid = true;
    p = p_;
    d = d_;
    hits.assign(hits_.begin(), hits_.end());
    next = next_;
}

namespace {

// True when some region's first crossing in these hits of a ray (sorted by
// distance) leaves it (`leaving`: the ray starts inside that region,
// locate_start's rule) or enters it (!leaving). Grazing hits (cos_dn = 0)
// decide nothing.
bool some_first_crossing(const std::vector<Hit>& hits, bool leaving) {
    uint64_t seen = 0;
    for (const Hit& h : hits) {
        const uint64_t bit = uint64_t(1) << h.region;
        if ((seen & bit) || h.cos_dn == 0) continue;
        seen |= bit;
        if ((h.cos_dn > 0) == leaving) return true;
    }
    return false;
}

// True when every point light l emits from lies in the ambient, farther from
// every surface than the transport's grouping tolerance (so no crossing lies
// at the start, where next_interface would need the whole hit list): the
// disk's centre is in no region (locate_start's rule, along the axis), and no
// triangle comes within the disk's radius, plus that room, of the centre, so
// the whole disk lies in the same connected piece of space as the centre.
bool emits_in_ambient(const Scene& scene, const Light& l, std::vector<Hit>& hits) {
    const Float room = 1e-5 * (max_abs_component(l.center) + l.radius + scene.extent());
    // The point query reaches twice as far: its float culling cannot lose a
    // triangle within radius + room.
    if (scene.distance_to_surface(l.center, 2 * (l.radius + room)) <= l.radius + room) return false;
    scene.intersect_all(l.center, l.axis, 0, kInf, hits);
    return !some_first_crossing(hits, /*leaving=*/true);
}

// Whether a light sits in a closed pocket (a cavity, such as the lumen
// around an endoscope, filled with ambient or with a region of its own):
// each of 64 probe rays from its centre (a Fibonacci sphere, near-uniform
// directions) enters a region the centre is outside of. A pocket with an
// opening larger than about 1/64 of the sphere is seen as open. A centre
// inside a slab of tissue, or on its surface, is no pocket: the rays that
// leave the slab on the ambient side enter nothing, so such a light keeps
// its source axis for reflected and transmitted (docs/design.md).
bool in_closed_pocket(const Scene& scene, const Light& l, std::vector<Hit>& hits) {
    constexpr int kProbes = 64;
    if (scene.region_count() == 0) return false;
    for (int k = 0; k < kProbes; ++k) {
        const Float z = 1 - (2 * k + 1) / Float(kProbes);
        const Float r = std::sqrt(std::max(Float(0), 1 - z * z));
        Float sin_phi, cos_phi;
        det_sincos(k * kPi * (3 - std::sqrt(Float(5))), &sin_phi, &cos_phi);
        scene.intersect_all(l.center, Vec3(r * cos_phi, r * sin_phi, z), 0, kInf, hits);
        if (!some_first_crossing(hits, /*leaving=*/false)) return false;
    }
    return true;
}

}  // namespace

bool spectral_run(const Scene& scene, const RunConfig& cfg) {
    return cfg.force_spectral || scene.has_fluorophores() || scene.has_spectral_media();
}

bool deposits_grids(const RunConfig& cfg) {
    return cfg.grid_voxel_size > 0 && (cfg.grid_absorbed || cfg.grid_fluorescent_light);
}

bool lanes_serve(const RunConfig& cfg) {
    // local_.enabled is cfg.safe_distance. The lanes make no per-interaction
    // deposit; the emission grids take theirs at fluorescence events, which
    // the walk finishes (after_lanes), into the unit's grids.
    return cfg.lanes && !deposits_grids(cfg) && !cfg.camera_view && !(cfg.max_path_cm > 0) && cfg.safe_distance;
}

Tracer::Tracer(const Scene& scene, const Source& source, const Halton& halton, const RunConfig& cfg)
    : scene_(scene), source_(source), halton_(halton), cfg_(cfg) {
    spectral_ = spectral_run(scene, cfg);
    grids_ = deposits_grids(cfg);
    hits_.reserve(64);
    // The local triangle caches serve every scene: each is gathered once
    // through the uniform grid (triangle_grid.h), O(local) whatever the
    // triangle count.
    local_.enabled = cfg.safe_distance;
    shortcuts_.entry_planes.build(scene);
    lanes_ = lanes_serve(cfg);
    if (lanes_) {
        lane_isa();  // ENDOPHOTON_LANE_ISA checked before any packet
        lane_block_ = std::make_unique<LaneBlock>();
        slot_caches_.resize(LaneBlock::kSlots);
    }
    for (const Light& l : source.lights()) {
        enclosed_.push_back(in_closed_pocket(scene, l, hits_) ? 1 : 0);
        LaunchMemo& memo = shortcuts_.launch.emplace_back();
        memo.fixed_ray = l.radius == 0 && l.half_angle == 0;
        memo.in_ambient = emits_in_ambient(scene, l, hits_);
    }
}

void Tracer::begin_unit() {
    // Units hold the same packets on any number of threads; starting each
    // with no last cache makes which steps a cache answers (and so the
    // order of tied hits) a function of the unit alone, never of the thread
    // that traced the packets before it (the scene's caches themselves are
    // functions of their cube alone).
    local_.cell = nullptr;
}

void Tracer::trace(uint64_t index, UnitOutput& out) {
    auto walk = [&](auto spectral, auto grids) {
        PacketWalk<decltype(spectral)::value, decltype(grids)::value>(scene_, source_, halton_, cfg_, hits_, cuts_,
                                                                      enclosed_, local_, shortcuts_, out)
            .run(index);
    };
    using T = std::true_type;
    using F = std::false_type;
    if (spectral_) {
        if (grids_)
            walk(T{}, T{});
        else
            walk(T{}, F{});
    } else {
        if (grids_)
            walk(F{}, T{});
        else
            walk(F{}, F{});
    }
}

bool Tracer::trace_lanes(uint64_t first, uint64_t end, UnitOutput& out, const std::function<bool(uint64_t)>& tick) {
    return spectral_ ? trace_lanes_as<true>(first, end, out, tick) : trace_lanes_as<false>(first, end, out, tick);
}

template <bool kSpectral>
bool Tracer::trace_lanes_as(uint64_t first, uint64_t end, UnitOutput& out, const std::function<bool(uint64_t)>& tick) {
    using Walk = PacketWalk<kSpectral, false>;
    // A slot's packet: its walk, its zone and last cube (LocalGeometry's, per
    // packet: each starts with none, so which steps a cube answers depends on
    // the packet alone), its output until it is merged in index order (its
    // tallies and records; its deposits go straight to the unit's grids,
    // whose sums are exact in any order).
    struct Slot {
        std::optional<Walk> walk;
        ClearSteps zone;
        const TriangleCache* cell = nullptr;
        std::unique_ptr<UnitOutput> out;
        uint64_t index = 0;
        bool hopped = false, seeded = false;
    };
    LaneBlock& B = *lane_block_;
    for (int k = 0; k < LaneBlock::kSlots; ++k) B.active[k] = 0;
    B.track_depth = cfg_.record_escapes;
    Slot slots[LaneBlock::kSlots];
    // Ended packets' outputs waiting for the packets before them: entry i is
    // packet merge + i's (null while it is in flight).
    std::deque<std::unique_ptr<UnitOutput>> done;
    std::vector<std::unique_ptr<UnitOutput>> spare;
    uint64_t next = first, merge = first;
    auto new_output = [&] {
        if (spare.empty()) {
            auto o = std::make_unique<UnitOutput>();
            o->tally.reset(out.tally.absorbed_by_region.size(), out.tally.emitted_by_fluorophore.size());
            o->deposit_into(out.grids);
            return o;
        }
        auto o = std::move(spare.back());
        spare.pop_back();
        return o;
    };
    auto end_packet = [&](Slot& sl) {
        sl.walk->finish();
        sl.walk.reset();
        const size_t i = size_t(sl.index - merge);
        if (done.size() <= i) done.resize(i + 1);
        done[i] = std::move(sl.out);
        for (; !done.empty() && done.front(); done.pop_front(), ++merge) {
            UnitOutput& o = *done.front();
            out.tally.take_packet(o.tally);
            if (o.records.size()) {
                out.records.append(o.records);
                o.records.clear();
            }
            spare.push_back(std::move(done.front()));
        }
    };
    // Slot k's packet after the lanes (resume), or none: walks it on, and
    // starts the next packets there while they end before reaching the lanes.
    auto serve = [&](int k, bool resume) {
        Slot& sl = slots[k];
        std::optional<typename Walk::Walk> w;
        local_.own = &slot_caches_[size_t(k)];
        if (resume) {
            local_.cell = sl.cell;
            w = sl.walk->after_lanes(B, k, sl.zone, &sl.hopped);
        }
        while (true) {
            if (w) {
                sl.cell = local_.cell;
                if (*w == Walk::Walk::kLanes) {
                    sl.walk->to_lane(B, k, sl.zone, !sl.seeded);
                    sl.seeded = true;
                    return true;
                }
                end_packet(sl);
            }
            if (next == end) return true;
            if (!tick(next)) return false;
            sl.index = next++;
            sl.out = new_output();
            sl.walk.emplace(scene_, source_, halton_, cfg_, hits_, cuts_, enclosed_, local_, shortcuts_, *sl.out);
            sl.hopped = sl.seeded = false;
            local_.cell = nullptr;
            w = sl.walk->begin(sl.index, &sl.zone);
        }
    };
    struct NoOwnCaches {  // the slots' caches serve this call only
        LocalGeometry& local;
        ~NoOwnCaches() { local.own = nullptr; }
    } no_own_caches{local_};
    for (int k = 0; k < LaneBlock::kSlots; ++k)
        if (!serve(k, false)) return false;
    while (uint32_t left = run_lanes(B))
        for (; left; left &= left - 1)
            if (!serve(__builtin_ctz(left), true)) return false;
    return true;
}

}  // namespace ep
