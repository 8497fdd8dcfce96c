// The life of one photon packet (MCML / the seed's Fig. 1): launch, specular
// loss at the first boundary, steps of -ln(xi)/mu_t carried across boundaries,
// implicit absorption, fluorescence, Henyey-Greenstein scattering, Fresnel
// boundaries, Russian roulette and the caps. A packet that leaves the tissue
// goes on in a straight line through the ambient and lands on the region or
// the rig head it meets; it escapes only when its ray meets nothing (issue 9,
// docs/design.md "Light crosses the lumen"). transport.cpp walks one packet in
// named steps over one PacketState: launch, locate_start, find_crossings,
// cross_interfaces, interact, and leave_tissue / through_ambient.
#pragma once
#include <memory>
#include <vector>

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

// The local triangle cache this thread used last (Scene::cell_cache); the
// geometry is static, so it stays valid from one packet to the next.
struct LocalGeometry {
    bool enabled = false;                 // chosen per scene (Tracer's constructor)
    const TriangleCache* cell = nullptr;  // the cache of the last cached step
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
};

}  // namespace ep
