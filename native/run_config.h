// Options of one run. Defaults follow MCML (roulette at 1e-4 with survival 1/10).
#pragma once
#include <cstdint>
#include <memory>
#include <string>

namespace ep {

struct CameraView;  // camera_tally.h

enum class FluorescenceRule { kPaper, kEEM };

struct RunConfig {
    uint64_t photons = 0;             // fixed-count mode: packets to launch
    uint64_t store = 0;               // "store N" mode: stop once N escape records are stored
    bool fluorescent_only = false;    // store only fluorescent escapes (the seed's surface map)
    bool record_escapes = true;       // keep the surface photon map (records)
    uint64_t max_records = 50000000;  // refuse to grow the map beyond this (memory guard)
    uint64_t seed = 1;
    int threads = 0;  // 0 = all hardware threads
    double roulette_threshold = 1e-4;
    double roulette_chance = 0.1;
    uint64_t max_steps = 0;  // 0 = no user cap; counts interactions and boundary events
    double max_path_cm = 0;  // 0 = no cap
    FluorescenceRule rule = FluorescenceRule::kPaper;
    bool force_spectral = false;  // trace wavelengths even without fluorophores/spectral media
    // Grids (none unless voxel_size > 0).
    double grid_voxel_size = 0;  // scene units
    bool grid_per_fluorophore = false;
    // The grids' quantities (docs/design.md, "Grids"): a run deposits and
    // writes only those asked for, and a run with neither absorbed nor
    // fluorescent_light traces without per-interaction deposits at all.
    bool grid_absorbed = true;           // "absorbed"
    bool grid_fluorescent_light = true;  // "fluorescent_light" (and its per-fluorophore grids)
    bool grid_emission = true;           // "emission_<fluorophore>"
    std::string grid_path;
    // The most the .vdb writer's OpenVDB trees may take (write_vdb); 0: three
    // quarters of the memory available when the file is written.
    uint64_t grid_max_tree_bytes = 0;
    // Target-accuracy mode: stop once stderr/mean of `target_tally` <= target_rel_error.
    int target_tally = -1;  // a TallyIndex, or -1
    double target_rel_error = 0;
    double time_budget_s = 0;  // 0 = none
    uint64_t max_photons = 0;  // upper bound for store/target modes; 0 = unlimited
    uint64_t unit_size = 0;    // packets per work unit; 0 = automatic
    int batches = 50;          // batches for the batch-means standard errors
    // Use the closest-surface distance to skip ray queries deep inside regions.
    bool safe_distance = true;
    // The plain interior steps in float32 lanes, 16 packets at once
    // (lane_block.h; issue 39): runs without grids taking per-interaction
    // deposits (the emission grids alone are served), camera tally or path
    // cap (lanes_serve). Another sample of the same physics, not the scalar
    // walk's bits (docs/numerics.md, "Float32 lanes").
    bool lanes = false;
    // Light crosses the lumen (issue 9): exits go on through the ambient and the
    // rig head is a body. false = every exit ends its packet, as before (benchmarks).
    bool lumen = true;
    // Count the engine's events per unit (stats.h; the CLI's --stats): RunResult::unit_stats.
    bool stats = false;
    // Next-event estimation toward a pinhole camera (camera_tally.h); null =
    // none (the run pays one branch per interaction). Fixed photon counts only.
    std::shared_ptr<const CameraView> camera_view;
    // Test hook: cancel right after this many units are merged (0 = never), so
    // a cancelled partial result can be tested without depending on timing.
    uint64_t test_cancel_after_units = 0;
    // Test hook: cancel as a worker is about to trace this packet index (0 =
    // never), as a cancel() landing in the middle of its unit does.
    uint64_t test_cancel_at_packet = 0;
    // Test hook: thread creation fails from this thread on (0 = never), as it
    // does when the system runs out of threads or memory.
    int test_fail_thread = 0;
};

// Largest packet count any request may name (photons, store, max_photons):
// unit arithmetic (index + unit size) then cannot wrap around 2^64.
constexpr uint64_t kMaxPacketRequest = uint64_t(1) << 62;

// Hard ceiling on events per packet whatever the user cap: a packet trapped by
// total internal reflection in a non-absorbing region would otherwise loop
// forever. Weight removed here is tallied as `cut`; the run counts the packets
// that were cut and warns.
constexpr uint64_t kSafetyMaxEvents = 10000000;

// A region more than this many mean free paths across (mus x largest side)
// cannot be followed by diffusion (~(mus L)^2 events per packet): the run then
// caps packets at kPathologicalMaxEvents events unless the user set max_steps,
// so its cost stays bounded, and says so in the result's warnings.
constexpr double kPathologicalOpticalSize = 1e9;
constexpr uint64_t kPathologicalMaxEvents = 100000;

}  // namespace ep
