// The life of one photon packet (MCML / the seed's Fig. 1): launch, specular
// loss at the first boundary, steps of -ln(xi)/mu_t carried across boundaries,
// implicit absorption, fluorescence, Henyey-Greenstein scattering, Fresnel
// boundaries, Russian roulette and the caps. A packet that leaves the tissue
// goes on in a straight line through the ambient and lands on the region or
// the rig head it meets; it escapes only when its ray meets nothing (issue 9,
// docs/design.md "Light crosses the lumen"). transport.cpp walks one packet in
// named steps over one PacketState: launch, locate_start, find_crossings,
// cross_interfaces, interact, and leave_tissue / through_ambient; deep in a
// scattering region, interior_steps runs the same steps in a tight loop.
#pragma once
#include <cstring>
#include <functional>
#include <memory>
#include <vector>

#include "camera_tally.h"
#include "entry_planes.h"
#include "halton.h"
#include "lane_block.h"
#include "records.h"
#include "run_config.h"
#include "scene.h"
#include "source.h"
#include "stats.h"
#include "tally.h"
#include "triangle_cache.h"
#include "voxel_grid.h"

namespace ep {

// Everything one work unit produces. Its tallies and records are merged in
// unit order by the engine; its grid deposits go to the grids the engine
// points it at (engine.cpp, grids_per_unit): the staging set of the worker
// thread or Dask chunk that traces it, added after the unit to the run's
// shared grids (SharedGridSet) or the chunk's, exactly and in any order; or
// the unit's own grids when the run's stop rule may discard it.
struct UnitOutput {
    UnitTally tally;
    EscapeRecords records;
    CameraScores camera;       // next-event scores (runs with a camera_view only)
    GridSet* grids = nullptr;  // where the deposits go; null without grids
    // Members of *grids, kept as pointers for the deposit calls of transport.cpp.
    VoxelAccumulator* absorbed_grid = nullptr;      // absorbed weight
    VoxelAccumulator* fluorescence_grid = nullptr;  // fluorescent packet weight at every step
    std::vector<VoxelAccumulator*> per_fluorophore;
    std::unique_ptr<GridSet> own_grids;  // set when the unit keeps its own grids
    uint64_t first_packet = 0;
    EngineStats stats;  // the unit's counters (runs with RunConfig::stats)

    // Sends the deposits to `g` (null: no grids).
    void deposit_into(GridSet* g) {
        grids = g;
        absorbed_grid = g ? &g->absorbed : nullptr;
        fluorescence_grid = g ? &g->fluorescence : nullptr;
        per_fluorophore.clear();
        if (g)
            for (VoxelAccumulator& a : g->per_fluorophore) per_fluorophore.push_back(&a);
    }
};

// A lane slot's own caches (Tracer::trace_lanes). Where the full cube store
// keeps no cache for a cube, a walk in the lanes gathers that cube into one
// of these (Scene::cube_cache) instead of taking the full query: a packet
// enters the lanes where a cube's cache gives it a zone, so what it meets
// must never depend on which cubes the store took first (the threads'
// timing). Three: the one the walk holds (LocalGeometry::cell) and a pair of
// candidates (cached_crossings' and hop_zone's).
struct SlotCaches {
    TriangleCacheBuilder cache[3];
    // One that is neither a nor b.
    TriangleCacheBuilder& spare(const TriangleCache* a, const TriangleCache* b) {
        for (TriangleCacheBuilder& c : cache)
            if (&c != a && &c != b) return c;
        return cache[0];  // unreachable: three caches, two excluded
    }
};

// The local triangle cache this thread used last (Scene::cell_cache); the
// geometry is static, so it stays valid from one packet to the next.
struct LocalGeometry {
    bool enabled = false;                 // chosen per scene (Tracer's constructor)
    const TriangleCache* cell = nullptr;  // the cache of the last cached step
    SlotCaches* own = nullptr;            // the lanes' slot's own caches (trace_lanes), else none
};

// A light without disk or cone (a pencil beam) emits every packet along the
// same ray, so the ray queries of its packets' first steps -- locate_start's
// query to infinity and the first boundary's mirror ray -- are the same too:
// each is kept here, keyed by the exact bits of the ray (issue 11: ~1.6k
// instructions per query; a memo of a deterministic query is exact).
struct RayMemo {
    bool valid = false;
    Vec3 p, d;
    std::vector<Hit> hits;
    NextHit next = kNextAway;  // the mirror ray's landing
    // Exact bits, not ==: the memo answers only for the very ray it saw (0 and
    // -0 compare equal but are different inputs).
    bool matches(const Vec3& p_, const Vec3& d_) const {
        return valid && std::memcmp(&p, &p_, sizeof(Vec3)) == 0 && std::memcmp(&d, &d_, sizeof(Vec3)) == 0;
    }
    void store(const Vec3& p_, const Vec3& d_, const std::vector<Hit>& hits_, NextHit next_ = kNextAway);
};
struct LaunchMemo {
    bool fixed_ray = false;  // the light emits one ray only
    // Every point the light emits from lies in the ambient, apart from every
    // surface (Tracer's constructor): locate_start then needs no all-hits query.
    bool in_ambient = false;
    RayMemo start, mirror;
};

// Ray queries a thread answers without Embree (issue 11: the fixed cost per packet).
struct RayShortcuts {
    std::vector<LaunchMemo> launch;  // per light
    EntryPlanes entry_planes;        // exits that enter nothing (small scenes)
};

// Whether a run of `scene` under `config` is spectral (packets carry a
// wavelength): forced, or a fluorophore or a spectral medium in the scene.
bool spectral_run(const Scene& scene, const RunConfig& config);
// Whether the run's walk deposits into grids at its interactions: the
// absorbed or fluorescent-light grid (emission grids alone cost nothing a step).
bool deposits_grids(const RunConfig& config);
// Whether the float32 lanes serve a run under `config` (Tracer::lanes):
// RunConfig::lanes, no grids taking a deposit at every interaction (the
// emission grids alone are served), no camera tally, no path cap, the local
// caches on.
bool lanes_serve(const RunConfig& config);

class Tracer {
  public:
    Tracer(const Scene& scene, const Source& source, const Halton& halton, const RunConfig& config);
    // Called before the first packet of every work unit.
    void begin_unit();
    // Traces packet `index` and adds its contributions to `out`.
    void trace(uint64_t index, UnitOutput& out);
    // Whether trace_lanes serves this run (lanes_serve).
    bool lanes() const { return lanes_; }
    // Traces packets [first, end) with their plain interior steps in float32
    // lanes, 16 packets in flight (lane_block.h), and adds each packet's
    // contributions to `out` in index order, as trace() and record_packet()
    // would packet by packet: a packet's bits depend on its index alone, never
    // on its slot or the lane width. tick(k) is called before packet k
    // starts; false stops the unit (the return is then false).
    bool trace_lanes(uint64_t first, uint64_t end, UnitOutput& out, const std::function<bool(uint64_t)>& tick);
    bool spectral() const { return spectral_; }
    bool grids() const { return grids_; }

  private:
    template <bool kSpectral>
    bool trace_lanes_as(uint64_t first, uint64_t end, UnitOutput& out, const std::function<bool(uint64_t)>& tick);

    const Scene& scene_;
    const Source& source_;
    const Halton& halton_;
    const RunConfig& cfg_;
    bool spectral_, grids_;
    bool lanes_ = false;
    std::unique_ptr<LaneBlock> lane_block_;  // trace_lanes' slots
    std::vector<SlotCaches> slot_caches_;    // and their own caches (LaneBlock::kSlots)
    std::vector<Hit> hits_;
    std::vector<Float> cuts_;
    LocalGeometry local_;  // voxel-face crossings of a clear segment (grids)
    // Per light: its ambient pocket is closed (every probe ray meets a region),
    // so light that leaves the scene went through the tissue: transmitted.
    std::vector<uint8_t> enclosed_;
    RayShortcuts shortcuts_;
};

}  // namespace ep
