// A run: packets are traced in fixed work units of consecutive indices, each by
// one thread with its own tallies; finished units are merged strictly in unit
// order. Seeds come from (seed, packet index). Together these make the result
// bit-identical for any thread count (MMC/MCX practice). Grid voxels are exact
// fixed-point sums (voxel_grid.h), so grids need no ordered merge: each worker
// thread (each Dask chunk) sums its deposits into its own grids.
#pragma once
#include <atomic>
#include <functional>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include "camera_tally.h"
#include "records.h"
#include "run_config.h"
#include "scene.h"
#include "source.h"
#include "stats.h"
#include "tally.h"

namespace ep {

// Why a run stopped. Every mode ends with one of these; the name is what the
// Python result's `stop_reason` says.
enum class StopReason {
    kNone,               // still running
    kPhotons,            // fixed count reached
    kStore,              // "store N": N escape records stored
    kStoreZero,          // "store N": no record at all after kZeroUnits units (the request is impossible)
    kTarget,             // target accuracy reached
    kTargetZero,         // target tally still exactly 0 after kZeroUnits units (relative error undefined)
    kTime,               // time budget used up
    kMaxPhotons,         // packet cap of a store/target run reached
    kTargetUnreachable,  // target run: the packets it needs, projected from its error so far, exceed the cap
    kCancelled,          // cancel token, progress callback or signal
};
const char* stop_reason_name(StopReason r);

// The packet cap of a target run without max_photons (2^30, ~1.1e9 packets: about an hour at
// the measured 250,000 packets/s of docs/performance.md). Its stop is a named warning.
constexpr uint64_t kDefaultTargetMaxPackets = uint64_t(1) << 30;

// The stop rule of every run, checked after every merged unit (fixed runs:
// the count and the time budget; store and target runs: their goal, the
// "zero" rules, the packet cap and the budget). It never looks at the clock itself: the caller passes the elapsed time,
// so the rule is a pure function of the merged units (testable without timing).
class StopRule {
  public:
    static constexpr size_t kMinTargetUnits = 20;  // units before a target can be met
    static constexpr size_t kZeroUnits = 1000;     // units before "store_zero" / "target_zero"
    // A target run without max_photons projects the units it needs, k (rel/target)^2 by the 1/sqrt(N) law, once it
    // has merged kProjectionUnits units, and stops as "target_unreachable" when they exceed
    // kUnreachableFactor times its cap (the factor absorbs the early error estimate's noise:
    // a factor 2 in the relative error is 4 in the packets).
    static constexpr size_t kProjectionUnits = 100;
    static constexpr double kUnreachableFactor = 10.0;
    StopRule(const RunConfig& cfg, uint64_t n_units_max);
    // `unit` was just merged, making `units_merged` units; `records` are
    // stored so far. Returns kNone to go on.
    StopReason after_merge(const UnitTally& unit, size_t units_merged, uint64_t records, double elapsed_s);
    // The units a target run was projected to need at its last check (0 before the first).
    double projected_units() const { return projected_units_; }

  private:
    const RunConfig& cfg_;
    uint64_t n_units_max_;
    double projected_units_ = 0;
    // Prefix sums of the target tally over merged units: the target test is
    // then O(batches) per unit instead of O(units).
    std::vector<uint64_t> prefix_n_{0};
    std::vector<double> prefix_sum_{0.0};
};

struct RunResult {
    uint64_t packets = 0;          // packets whose tallies are included
    uint64_t packets_traced = 0;   // store-N mode: index of the packet that made the N-th record + 1
    std::vector<UnitTally> units;  // per-unit tallies, in order (for batch means)
    Estimate scalar[kScalarTallies];
    Estimate energy[kEnergyTallies];  // meaningful in spectral runs
    std::vector<Estimate> absorbed_by_region;
    std::vector<Estimate> emitted_by_fluorophore;  // by fluorophore id (UnitTally::emitted_by_fluorophore)
    EscapeRecords records;
    std::shared_ptr<CameraImage> camera_image;  // runs with a camera_view (camera_tally.h)
    bool cancelled = false;
    bool target_reached = false;
    bool spectral = false;
    std::string lanes;  // the lane kernel's instruction set where the float32 lanes served the run, else empty
    bool store_reached = false;
    StopReason stop = StopReason::kNone;
    uint64_t capped_packets = 0;        // packets that ended at the step or path cap (their weight is `cut`)
    std::vector<std::string> warnings;  // conditions a reader of the result must know about
    double seconds = 0;
    std::string grid_path;
    std::vector<std::string> grid_names;
    double grid_absorbed_sum = 0;  // sum of the absorbed (energy) grid, per launched packet
    uint64_t unit_size = 0;
    int threads = 0;
    size_t peak_record_bytes = 0;
    std::vector<EngineStats> unit_stats;  // per merged unit, in order (RunConfig::stats; else empty)
};

// progress(done_packets, total_packets_or_0) is called on the calling thread
// about every 100 ms; returning false cancels the run. `cancel` may be set from
// any thread. Both may be empty/null. The scene and the source are checked
// against float32 ray-tracing limits (scale_check.h) before any ray is cast.
using ProgressFn = std::function<bool(uint64_t, uint64_t)>;

RunResult run(const Scene& scene, const Source& source, const RunConfig& config, const ProgressFn& progress,
              std::atomic<bool>* cancel);

// Recomputes the estimates of `r` from r.units (used after merging).
void finalize_estimates(RunResult& r, int batches);

// ---- A run in pieces (python/endophoton/distributed.py runs one on a Dask
// cluster). Units depend only on the request, so they can be traced anywhere;
// UnitReducer is the one place that merges them, for ep::run's threads and for
// units traced in other processes alike, so both give the same bits.

struct UnitPlan {
    uint64_t unit_size = 0;    // packets per unit (depends only on the request)
    uint64_t limit = 0;        // packet index bound
    uint64_t n_units_max = 0;  // units a run may use at most
};
// The configuration a run really uses: validated (std::invalid_argument naming
// the field), scale-checked, with the event cap of pathological scenes applied
// (its warning appended to `warnings` if not null). `grid_file`: whether this
// process writes the grid file, whose path is then checked (check_vdb_path);
// trace_units passes false, as a worker's file system need not hold it.
RunConfig prepare_config(const Scene& scene, const Source& source, const RunConfig& config,
                         std::vector<std::string>* warnings, bool grid_file = true);
// Cuts a prepared request into units.
UnitPlan plan_units(const RunConfig& prepared);

struct UnitOutput;
struct UnitBatch;
struct GridSet;

// True when the run's units keep their own grids until they are merged: the
// stop rule may end the run after any unit (store, target, time budget), and
// the deposits of units past the stop point must then be discarded with
// them. A fixed count without a time budget ends only after its last unit (or
// is cancelled, which writes no grid), so its units deposit into a staging
// set that is added to the run's grids (or the Dask chunk's) after each unit.
bool grids_per_unit(const RunConfig& prepared);

// Traces units [first_unit, first_unit + count) on the calling thread. Returns
// early (fewer units) once `cancel` is set. The batch holds one grid set for
// all its units, or (grids_per_unit) one per unit.
UnitBatch trace_units(const Scene& scene, const Source& source, const RunConfig& config, uint64_t first_unit,
                      uint64_t count, std::atomic<bool>* cancel);

// Merges finished units strictly in unit order, applies the stop rule after
// each (UnitMerger), and ends the run (estimates, grid file). Not thread-safe.
class UnitReducer {
  public:
    UnitReducer(const Scene& scene, const Source& source, const RunConfig& config);
    ~UnitReducer();
    // Takes unit `index`; it is merged once every unit before it is. Returns
    // true once the run must stop; later units are then discarded, exactly as
    // a local run discards the units its threads traced past the stop point.
    // The own grids of the units merged by this call are added to the run's.
    bool add(uint64_t index, std::unique_ptr<UnitOutput> unit);
    // The same, but the own grids of the merged units are moved to `accepted`:
    // the caller adds them (to any grid set later handed to add_grids), so the
    // additions happen outside the caller's lock.
    bool add(uint64_t index, std::unique_ptr<UnitOutput> unit, std::vector<std::unique_ptr<GridSet>>& accepted);
    // Adds grids whose deposits belong to merged units only (a worker
    // thread's unit, a Dask chunk's). Exact: the order of the calls does not
    // matter. Unlike the other methods, threads may call this at the same
    // time (the run's grids are sharded, grid_shards.h), but not during finish.
    void add_grids(const GridSet& grids);
    // Adds a batch from trace_units (its grids, then its units in order);
    // returns stopped(). A batch's own grid set exists only in runs that end
    // after their last unit (not grids_per_unit), so none of its deposits can
    // belong to a unit past the stop point.
    bool add_batch(UnitBatch&& batch);
    bool stopped() const;
    uint64_t merged_units() const;
    uint64_t records() const;
    const UnitPlan& plan() const;
    const RunConfig& config() const;  // prepared
    // Ends the run. A run its stop rule did not end is marked cancelled, and so
    // is one its caller cancelled after that end (`cancelled`: ep::run's token
    // was set by the time its workers stopped): neither writes a grid file.
    RunResult finish(int threads, bool cancelled = false);

  private:
    struct Impl;
    std::unique_ptr<Impl> impl_;
};

std::string engine_version();

}  // namespace ep
