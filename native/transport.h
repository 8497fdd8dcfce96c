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
#include <memory>
#include <vector>

#include "entry_planes.h"
#include "halton.h"
#include "records.h"
#include "run_config.h"
#include "scene.h"
#include "source.h"
#include "tally.h"
#include "triangle_cache.h"

namespace ep {

class VoxelAccumulator;

// Everything one work unit produces; merged in unit order by the engine.
struct UnitOutput {
    UnitTally tally;
    EscapeRecords records;
    std::unique_ptr<VoxelAccumulator> absorbed_grid;      // absorbed weight
    std::unique_ptr<VoxelAccumulator> fluorescence_grid;  // fluorescent packet weight at every step
    std::vector<std::unique_ptr<VoxelAccumulator>> per_fluorophore;
    uint64_t first_packet = 0;
};

// The triangles near the last packet of this thread (triangle_cache.h); the
// geometry is static, so the cache stays valid from one packet to the next.
struct LocalGeometry {
    bool enabled = false;  // chosen per scene (Tracer's constructor)
    TriangleCache cache;
    int cooldown = 0;                        // steps before the next gather after one that failed
    double fraction = 1;                     // of the ball radius in free paths (transport.cpp)
    uint64_t gathers = 0, cached_steps = 0;  // in this work unit
    bool unit_off = false;                   // the cache did not pay in this unit
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
    RayMemo start, mirror;
};

// Ray queries a thread answers without Embree (issue 11: the fixed cost per packet).
struct RayShortcuts {
    std::vector<LaunchMemo> launch;  // per light
    EntryPlanes entry_planes;        // exits that enter nothing (small scenes)
};

class Tracer {
  public:
    Tracer(const Scene& scene, const Source& source, const Halton& halton, const RunConfig& config);
    // Called before the first packet of every work unit.
    void begin_unit();
    // Traces packet `index` and adds its contributions to `out`.
    void trace(uint64_t index, UnitOutput& out);
    bool spectral() const { return spectral_; }
    bool grids() const { return grids_; }

  private:
    const Scene& scene_;
    const Source& source_;
    const Halton& halton_;
    const RunConfig& cfg_;
    bool spectral_, grids_;
    std::vector<Hit> hits_;
    std::vector<Float> cuts_;
    LocalGeometry local_;  // voxel-face crossings of a clear segment (grids)
    // Per light: its ambient pocket is closed (every probe ray meets a region),
    // so light that leaves the scene went through the tissue: transmitted.
    std::vector<uint8_t> enclosed_;
    RayShortcuts shortcuts_;
};

}  // namespace ep
