#include "engine.h"

#include <cerrno>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <memory>
#include <mutex>
#include <sstream>
#include <stdexcept>
#include <system_error>
#include <thread>

#include "grid_shards.h"
#include "scale_check.h"
#include "transport.h"
#include "unit_io.h"
#include "vdb_writer.h"
#include "voxel_grid.h"

namespace ep {

std::string engine_version() {
#ifdef ENDOPHOTON_VERSION
    return ENDOPHOTON_VERSION;
#else
    return "dev";
#endif
}

const char* stop_reason_name(StopReason r) {
    switch (r) {
        case StopReason::kNone:
            return "";
        case StopReason::kPhotons:
            return "photons";
        case StopReason::kStore:
            return "store";
        case StopReason::kStoreZero:
            return "store_zero";
        case StopReason::kTarget:
            return "target";
        case StopReason::kTargetZero:
            return "target_zero";
        case StopReason::kTime:
            return "time";
        case StopReason::kMaxPhotons:
            return "max_photons";
        case StopReason::kTargetUnreachable:
            return "target_unreachable";
        case StopReason::kCancelled:
            return "cancelled";
    }
    return "";
}

void finalize_estimates(RunResult& r, int batches) {
    r.packets = 0;
    r.capped_packets = 0;
    for (const UnitTally& u : r.units) {
        r.packets += u.packets;
        r.capped_packets += u.capped_packets;
    }
    for (int k = 0; k < kScalarTallies; ++k)
        r.scalar[k] =
            batch_estimate(r.units, batches, [k](const UnitTally& u) -> const Moments& { return u.scalar_m[k]; });
    for (int k = 0; k < kEnergyTallies; ++k)
        r.energy[k] =
            batch_estimate(r.units, batches, [k](const UnitTally& u) -> const Moments& { return u.energy_m[k]; });
    const size_t nreg = r.units.empty() ? 0 : r.units.front().absorbed_by_region_m.size();
    r.absorbed_by_region.assign(nreg, Estimate{});
    for (size_t k = 0; k < nreg; ++k)
        r.absorbed_by_region[k] = batch_estimate(
            r.units, batches, [k](const UnitTally& u) -> const Moments& { return u.absorbed_by_region_m[k]; });
    const size_t nfl = r.units.empty() ? 0 : r.units.front().emitted_by_fluorophore_m.size();
    r.emitted_by_fluorophore.assign(nfl, Estimate{});
    for (size_t k = 0; k < nfl; ++k)
        r.emitted_by_fluorophore[k] = batch_estimate(
            r.units, batches, [k](const UnitTally& u) -> const Moments& { return u.emitted_by_fluorophore_m[k]; });
}

// ---------------------------------------------------------------- stop rule

StopRule::StopRule(const RunConfig& cfg, uint64_t n_units_max) : cfg_(cfg), n_units_max_(n_units_max) {}

StopReason StopRule::after_merge(const UnitTally& unit, size_t k, uint64_t records, double elapsed_s) {
    const bool time_up = cfg_.time_budget_s > 0 && elapsed_s >= cfg_.time_budget_s;
    if (cfg_.photons > 0) {
        if (k >= n_units_max_) return StopReason::kPhotons;
        return time_up ? StopReason::kTime : StopReason::kNone;
    }
    if (cfg_.store > 0) {
        if (records >= cfg_.store) return StopReason::kStore;
        // No record at all after 1000 units: the request cannot be met (say,
        // fluorescent escapes of a scene whose fluorophores never fire).
        if (records == 0 && k >= kZeroUnits) return StopReason::kStoreZero;
    }
    if (cfg_.target_tally >= 0) {
        prefix_n_.push_back(prefix_n_.back() + unit.packets);
        prefix_sum_.push_back(prefix_sum_.back() + unit.scalar_m[cfg_.target_tally].sum);
        if (k >= kMinTargetUnits) {
            const Estimate e = batch_estimate_prefix(prefix_n_, prefix_sum_, cfg_.batches);
            if (e.mean != 0 && e.stderr_ / std::fabs(e.mean) <= cfg_.target_rel_error) return StopReason::kTarget;
            // The relative error of a tally that stays exactly zero is undefined.
            if (e.mean == 0 && k >= kZeroUnits) return StopReason::kTargetZero;
            // Without max_photons (the default cap): a cap the user chose is run to.
            if (e.mean != 0 && k >= kProjectionUnits && cfg_.max_photons == 0) {
                const double ratio = e.stderr_ / (std::fabs(e.mean) * cfg_.target_rel_error);
                projected_units_ = double(k) * ratio * ratio;
                if (projected_units_ > kUnreachableFactor * double(n_units_max_)) return StopReason::kTargetUnreachable;
            }
        }
    }
    if (k >= n_units_max_) return StopReason::kMaxPhotons;
    return time_up ? StopReason::kTime : StopReason::kNone;
}

namespace {

// The grids' quantities: at least one grid to write, and per-fluorophore
// grids only beside the fluorescent_light grid they split.
void check_grid_quantities(const RunConfig& c, const Scene& scene) {
    if (!c.grid_absorbed && !c.grid_fluorescent_light && !c.grid_emission)
        throw std::invalid_argument(
            "grids.absorbed, grids.fluorescent_light and grids.emission are all False: no grid to write");
    if (c.grid_per_fluorophore && !c.grid_fluorescent_light)
        throw std::invalid_argument(
            "grids.per_fluorophore = True needs grids.fluorescent_light = True (its grids split that one)");
    if (!c.grid_absorbed && !c.grid_fluorescent_light && !scene.has_fluorophores())
        throw std::invalid_argument(
            "grids.emission is the only grid asked for, and the scene has no fluorophore: no grid to write");
}

// `grid_file`: whether this process writes the grid file (not a Dask worker,
// whose file system need not hold the client's directory).
void validate_config(const RunConfig& c, const Scene& scene, bool grid_file) {
    auto bad = [](const std::string& field, double v, const char* rule) {
        std::ostringstream os;
        os.precision(17);
        os << field << " = " << v << " " << rule;
        throw std::invalid_argument(os.str());
    };
    const int modes = (c.photons > 0) + (c.store > 0) + (c.target_tally >= 0);
    if (modes == 0) throw std::invalid_argument("photons = 0: give photons > 0, store > 0 or a target accuracy");
    if (c.photons > 0 && c.store > 0) throw std::invalid_argument("photons and store are exclusive: give one");
    for (auto [name, v] : {std::pair<const char*, uint64_t>{"photons", c.photons},
                           {"store", c.store},
                           {"max_photons", c.max_photons},
                           {"unit_size", c.unit_size}})
        if (v > kMaxPacketRequest)
            throw std::invalid_argument(std::string(name) + " = " + std::to_string(v) +
                                        " exceeds the limit 2^62 = " + std::to_string(kMaxPacketRequest));
    if (!(c.roulette_threshold >= 0) || !std::isfinite(c.roulette_threshold))
        bad("roulette_threshold", c.roulette_threshold, "must be a finite number >= 0");
    if (!(c.roulette_chance > 0 && c.roulette_chance <= 1))
        bad("roulette_chance", c.roulette_chance, "must be in (0, 1]");
    if (!(c.max_path_cm >= 0) || !std::isfinite(c.max_path_cm)) bad("max_path_cm", c.max_path_cm, "must be >= 0");
    if (!(c.grid_voxel_size >= 0) || !std::isfinite(c.grid_voxel_size))
        bad("grids.voxel_size", c.grid_voxel_size, "must be a positive finite number");
    if (c.grid_voxel_size > 0 && c.grid_path.empty()) throw std::invalid_argument("grids.path is empty");
    if (c.grid_voxel_size > 0) check_grid_quantities(c, scene);
    // Checked before the run, which the file could not be written after.
    if (c.grid_voxel_size > 0) check_vdb_voxel_size(c.grid_voxel_size);
    if (c.grid_voxel_size > 0 && grid_file) check_vdb_path(c.grid_path);
    if (c.target_tally >= kScalarTallies) bad("target.tally", c.target_tally, "is not a tally index");
    if (c.target_tally >= 0 && !(c.target_rel_error > 0 && std::isfinite(c.target_rel_error)))
        bad("target.rel_error", c.target_rel_error, "must be a finite number > 0");
    if (!(c.time_budget_s >= 0) || !std::isfinite(c.time_budget_s))
        bad("time_budget_s", c.time_budget_s, "must be a finite number >= 0 (0 = none)");
    if (c.threads < 0) bad("threads", c.threads, "must be >= 0");
    if (c.batches < 2) bad("batches", c.batches, "must be >= 2");
    if (c.camera_view) {
        if (c.photons == 0 || c.store > 0 || c.target_tally >= 0 || c.time_budget_s > 0)
            throw std::invalid_argument("camera_view needs a fixed photon count (no store, target or time budget)");
        if (c.camera_view->packets != c.photons)
            throw std::invalid_argument("camera_view.packets = " + std::to_string(c.camera_view->packets) +
                                        " must equal photons = " + std::to_string(c.photons));
        c.camera_view->check();
        if (!spectral_run(scene, c))
            throw std::invalid_argument(
                "camera_view needs a spectral run (spectral=True): its colours need wavelengths");
    }
    if (c.store > 0 && !c.record_escapes)
        throw std::invalid_argument("store = " + std::to_string(c.store) + " needs record_escapes = True");
    if (c.store > 0 && c.fluorescent_only && !scene.has_fluorophores())
        throw std::invalid_argument("store = " + std::to_string(c.store) +
                                    " with fluorescent_only = True needs a fluorophore, and the scene has none");
}

// Writes the run's grids, normalised per launched packet so that the absorbed
// grid sums to the `absorbed` fraction. The file is written atomically
// (write_vdb). Throws std::logic_error if the grids do not hold the deposits
// of exactly the merged packets (a unit counted twice or lost).
// The grids are built on up to `threads` threads; each grid's voxel tables are
// freed once its tree is built (the run needs them no more).
void write_grids(SharedGridSet& grids, const Scene& scene, const RunConfig& cfg, RunResult& result, int threads) {
    if (grids.packets() != result.packets)
        throw std::logic_error("grids: hold the deposits of " + std::to_string(grids.packets()) +
                               " packets, but the run merged " + std::to_string(result.packets) +
                               " (internal error: please report it)");
    const double s = 1.0 / double(result.packets);
    std::vector<GridOutput> outs;
    // Grid k of the set (GridSet::grid numbering) with its name and meaning.
    const auto output = [&](size_t k, std::string name, std::string meaning) {
        const std::vector<const VoxelAccumulator*> parts = grids.parts(k);
        // Each shard's voxel table is freed once its voxels are in the tree
        // (the write then holds the tables not yet read and one or two trees).
        outs.push_back({std::move(name),
                        std::move(meaning),
                        parts.front(),
                        s,
                        {parts.begin() + 1, parts.end()},
                        [&grids, k](size_t shard) { grids.release(k, shard); }});
    };
    // Names and meanings: docs/design.md, "Grids" (endophoton.vdb.GRID_QUANTITIES says the same to readers).
    // Only the grids the run was asked for (the others took no deposit).
    if (cfg.grid_absorbed)
        output(0, "absorbed",
               "energy absorbed in the voxel (packet weight x 500 nm / wavelength; weight when the run is not "
               "spectral), per launched packet; dimensionless, per voxel");
    if (cfg.grid_fluorescent_light)
        output(1, "fluorescent_light",
               "weight of fluorescent packets summed over their interaction sites in the voxel (collision density "
               "of fluorescence light), per launched packet; dimensionless, per voxel");
    const size_t per_fl = grids.grid_count() - 2 - scene.fluorophore_count();
    for (size_t f = 0; f < per_fl; ++f)
        output(f + 2, "fluorescent_light_" + scene.fluorophore_name(int(f)),
               "weight of packets that fluoresced by " + scene.fluorophore_name(int(f)) +
                   ", summed over their interaction sites in the voxel (where its light goes, not where it is), "
                   "per launched packet; dimensionless, per voxel");
    for (size_t f = 0; f < (cfg.grid_emission ? scene.fluorophore_count() : 0); ++f)
        output(2 + per_fl + f, "emission_" + scene.fluorophore_name(int(f)),
               "packet weight " + scene.fluorophore_name(int(f)) +
                   " converted into fluorescence at its conversion points in the voxel (fluorescence photons "
                   "emitted per launched photon), per launched packet; dimensionless, per voxel");
    std::map<std::string, std::string> meta;
    meta["packets"] = std::to_string(result.packets);
    meta["seed"] = std::to_string(cfg.seed);
    meta["unit_cm"] = std::to_string(scene.unit_cm());
    meta["engine"] = "endophoton " + engine_version();
    meta["voxel_size"] = std::to_string(cfg.grid_voxel_size);
    // The writer sums each grid exactly (its "accumulator_sum"); the absorbed
    // grid's is the result's grid_absorbed_sum (0 when it was not asked for).
    const std::vector<double> sums = write_vdb(cfg.grid_path, outs, meta, threads, cfg.grid_max_tree_bytes);
    result.grid_absorbed_sum = cfg.grid_absorbed ? sums.front() : 0.0;
    result.grid_path = cfg.grid_path;
    for (const auto& o : outs) result.grid_names.push_back(o.name);
}

size_t per_fluorophore_grids(const Scene& scene, const RunConfig& cfg) {
    return cfg.grid_per_fluorophore ? scene.fluorophore_count() : 0;
}

// One emission grid per fluorophore of the scene (none without fluorophores).
std::unique_ptr<GridSet> new_grids(const Scene& scene, const RunConfig& cfg) {
    return std::make_unique<GridSet>(cfg.grid_voxel_size, per_fluorophore_grids(scene, cfg), scene.fluorophore_count());
}

// Merges finished units strictly in unit order (bit-identical totals for any
// thread count) and applies the stop rule after each. The own grids of the
// units it merges (runs with grids_per_unit) wait in accepted() for the
// caller to add them, in any order. Not thread-safe: the caller holds the
// run's mutex.
class UnitMerger {
  public:
    UnitMerger(const RunConfig& cfg, uint64_t n_units_max, RunResult& result,
               std::chrono::steady_clock::time_point t_start)
        : cfg_(cfg), rule_(cfg, n_units_max), result_(result), t_start_(t_start) {}

    // The units the stop rule last projected a target run to need (0: none yet).
    double projected_units() const { return rule_.projected_units(); }

    // Takes a finished unit; returns true once the run must stop.
    bool add(uint64_t index, std::unique_ptr<UnitOutput> unit) {
        pending_.emplace(index, std::move(unit));
        while (result_.stop == StopReason::kNone) {
            auto it = pending_.find(result_.units.size());
            if (it == pending_.end()) break;
            std::unique_ptr<UnitOutput> u = std::move(it->second);
            pending_.erase(it);
            merge(*u);
        }
        return result_.stop != StopReason::kNone;
    }
    uint64_t records() const { return records_; }
    std::vector<std::unique_ptr<GridSet>>& accepted() { return accepted_; }

  private:
    void merge(UnitOutput& u) {
        if (cfg_.record_escapes) {
            size_t take = u.records.size();
            if (cfg_.store > 0) take = std::min<uint64_t>(take, cfg_.store - records_);
            if (records_ + take > cfg_.max_records)
                throw std::runtime_error("escape records exceed max_records = " + std::to_string(cfg_.max_records) +
                                         ": pass record_escapes=False, fluorescent_only=True or a larger max_records");
            result_.records.append(u.records, take);
            records_ += take;
            result_.peak_record_bytes = std::max(result_.peak_record_bytes, result_.records.memory_bytes());
        }
        if (u.own_grids) accepted_.push_back(std::move(u.own_grids));
        if (cfg_.camera_view) {  // in unit order: the image is the same on any thread count
            if (!result_.camera_image) result_.camera_image = std::make_shared<CameraImage>(cfg_.camera_view);
            result_.camera_image->add(u.camera);
        }
        result_.units.push_back(std::move(u.tally));
        if (cfg_.stats) result_.unit_stats.push_back(u.stats);
        const size_t k = result_.units.size();
        if (cfg_.test_cancel_after_units > 0 && k >= cfg_.test_cancel_after_units) {
            result_.stop = StopReason::kCancelled;
            return;
        }
        const double elapsed = std::chrono::duration<double>(std::chrono::steady_clock::now() - t_start_).count();
        result_.stop = rule_.after_merge(result_.units.back(), k, records_, elapsed);
    }

    const RunConfig& cfg_;
    StopRule rule_;
    RunResult& result_;
    std::chrono::steady_clock::time_point t_start_;
    std::map<uint64_t, std::unique_ptr<UnitOutput>> pending_;
    std::vector<std::unique_ptr<GridSet>> accepted_;
    uint64_t records_ = 0;
};

// The shared state of one run's workers and its watcher.
struct RunState {
    const Scene& scene;
    const Source& source;
    const RunConfig& cfg;
    const Halton halton;
    uint64_t unit_size, limit, n_units_max;
    UnitReducer& merger;
    std::atomic<bool>* cancel;
    std::mutex mu;
    std::atomic<uint64_t> next_unit{0}, done_packets{0};
    std::atomic<bool> stop{false}, user_cancel{false};
    std::string error;

    RunState(const Scene& sc, const Source& so, const RunConfig& c, uint64_t usize, uint64_t lim, uint64_t nmax,
             UnitReducer& m, std::atomic<bool>* cancel_flag)
        : scene(sc),
          source(so),
          cfg(c),
          halton(c.seed),
          unit_size(usize),
          limit(lim),
          n_units_max(nmax),
          merger(m),
          cancel(cancel_flag) {}
    bool cancelled() const { return user_cancel.load() || (cancel && cancel->load()); }
    void fail(const std::string& what) {
        std::lock_guard<std::mutex> lock(mu);
        if (error.empty()) error = what;
        stop.store(true);
    }
};

// A unit whose deposits go to `staging`, or to its own grids when the run
// keeps grids per unit.
std::unique_ptr<UnitOutput> new_unit(const Scene& scene, const RunConfig& cfg, uint64_t unit_size, uint64_t u,
                                     GridSet* staging) {
    auto out = std::make_unique<UnitOutput>();
    out->tally.reset(scene.region_count(), scene.fluorophore_count());
    out->first_packet = u * unit_size;
    if (grids_per_unit(cfg)) {
        out->own_grids = new_grids(scene, cfg);
        out->deposit_into(out->own_grids.get());
    } else if (cfg.grid_voxel_size > 0) {
        if (!staging) throw std::logic_error("grids: a unit of a fixed-count run has no grids to deposit into");
        out->deposit_into(staging);
    }
    return out;
}

// Traces the packets of unit `u` (local threads and trace_units alike).
// `tick(k)` is called before every packet with its index; returning false
// abandons the unit (nullptr) and discards every deposit still staged. A
// fixed-count unit deposits into `staging`, a grid set small enough to stay
// in cache, where the grids of a whole run or chunk would take a cache miss
// per deposit; once it holds at least `flush_packets` packets (every unit
// when 0), `flush(staging)` adds it to those grids and it is emptied. Exact
// sums: adding a unit's voxels at once, several units' at once, or its
// deposits one by one gives the same bits.
template <class Tick, class Flush>
std::unique_ptr<UnitOutput> trace_unit(Tracer& tracer, const Scene& scene, const RunConfig& cfg, const UnitPlan& plan,
                                       uint64_t u, GridSet* staging, uint64_t flush_packets, Tick&& tick,
                                       Flush&& flush) {
    auto out = new_unit(scene, cfg, plan.unit_size, u, staging);
    const uint64_t first = u * plan.unit_size, end = std::min(plan.limit, first + plan.unit_size);
    const StatsScope counting(cfg.stats ? &out->stats : nullptr);
    tracer.begin_unit();
    // Packet by packet, or 16 in flight in the float32 lanes; false: the tick stopped the unit.
    auto traced = [&] {
        if (tracer.lanes()) return tracer.trace_lanes(first, end, *out, [&](uint64_t k) { return bool(tick(k)); });
        for (uint64_t k = first; k < end; ++k) {
            if (!tick(k)) return false;
            tracer.trace(k, *out);
            out->tally.record_packet();
        }
        return true;
    };
    if (!traced()) {
        if (staging) staging->clear_keep_capacity();
        return nullptr;
    }
    if (out->grids) out->grids->packets += out->tally.packets;
    if (staging && out->grids == staging && staging->packets >= flush_packets) {
        flush(*staging);
        staging->clear_keep_capacity();
    }
    return out;
}

// Packets a local worker stages before it adds them to the run's grids: each
// addition then inserts every distinct voxel of several units into the large
// shared tables at once, rather than those of each unit (a 150-packet unit of
// a 150k-packet run), so fewer inserts miss the cache and evict what the
// tracing keeps there. (Callgrind, colon with grids, 40k packets: 512 staged
// packets instead of 64 cost 1.7 % fewer instructions and 6.6 % fewer L1
// read misses.) The staging set then holds a few tens of thousands of voxels.
constexpr uint64_t kStagedPackets = 512;

// A staging grid set for trace_unit, or null when the run has no grids or
// each unit keeps its own.
std::unique_ptr<GridSet> new_staging(const Scene& scene, const RunConfig& cfg) {
    return cfg.grid_voxel_size > 0 && !grids_per_unit(cfg) ? new_grids(scene, cfg) : nullptr;
}

// trace_claimed_units' loop: claims units and traces them until the run stops
// or no unit is left.
template <class Flush>
void trace_units_until_done(RunState& st, const UnitPlan& plan, Tracer& tracer, GridSet* staging, const Flush& flush,
                            std::vector<std::unique_ptr<GridSet>>& accepted) {
    while (!st.stop.load()) {
        if (st.cancelled()) return;
        const uint64_t u = st.next_unit.fetch_add(1);
        if (u >= st.n_units_max) return;
        const uint64_t first = u * st.unit_size, end = std::min(st.limit, first + st.unit_size);
        uint64_t counted = first;
        const auto tick = [&](uint64_t k) {
            // Cancel is checked before every packet (two relaxed loads), so a
            // Ctrl-C lands within one packet even when packets are slow: the
            // unit is abandoned, never merged (the result holds whole units).
            if (st.cfg.test_cancel_at_packet > 0 && k >= st.cfg.test_cancel_at_packet) st.user_cancel.store(true);
            if (st.cancelled() || st.stop.load(std::memory_order_relaxed)) return false;
            if ((k & 255) == 0) {
                st.done_packets.fetch_add(k - counted);  // progress every 256 packets
                counted = k;
            }
            return true;
        };
        auto out = trace_unit(tracer, st.scene, st.cfg, plan, u, staging, kStagedPackets, tick, flush);
        if (!out) return;
        st.done_packets.fetch_add(end - counted);
        {
            std::lock_guard<std::mutex> lock(st.mu);
            if (st.stop.load()) return;
            if (st.merger.add(u, std::move(out), accepted)) st.stop.store(true);
        }
        for (const auto& g : accepted) st.merger.add_grids(*g);
        accepted.clear();
    }
}

// One worker: claims units, traces their packets and hands them to the
// merger until the run stops or no unit is left. A unit's deposits are
// staged and then added to the run's grids (UnitReducer::add_grids, which
// threads may call at once); the own grids of units of runs that keep grids
// per unit come back here once the merger has accepted their unit and are
// added the same way, outside the run's lock.
void trace_claimed_units(RunState& st) {
    const UnitPlan plan{st.unit_size, st.limit, st.n_units_max};
    Tracer tracer(st.scene, st.source, st.halton, st.cfg);
    std::vector<std::unique_ptr<GridSet>> accepted;
    std::unique_ptr<GridSet> staging = new_staging(st.scene, st.cfg);
    const auto flush = [&](const GridSet& g) { st.merger.add_grids(g); };
    trace_units_until_done(st, plan, tracer, staging.get(), flush, accepted);
    // The worker leaves: the units still staged are added. (An abandoned unit
    // emptied the staging set, deposits of earlier units included; units are
    // only abandoned when the run is cancelled or failed, and then no grid is
    // written, so a cancelled run adds nothing. A fixed-count run stops once
    // its last unit merged.)
    if (staging && staging->packets > 0 && !st.cancelled()) flush(*staging);
}

void worker(RunState& st) {
    try {
        trace_claimed_units(st);
    } catch (const std::exception& e) {
        st.fail(e.what());
    }
}

// Starts the workers and watches them from the calling thread, which reports
// progress and forwards cancellation (so a Python caller can release the GIL).
// A thread that cannot be created stops the run with a named error.
void run_workers(RunState& st, int threads, uint64_t total, const ProgressFn& progress) {
    // The calling thread reports progress every 0.1 s and is woken as soon
    // as the last worker ends: a fixed sleep would add up to its period to
    // every run (it did: 20 ms, a third of a 60 ms run, and a bias in the
    // bench's thread scaling).
    std::mutex done_mu;
    std::condition_variable done_cv;
    int active = 0;
    std::vector<std::thread> pool;
    pool.reserve(size_t(threads));  // emplace_back then only fails by the thread's own start
    for (int t = 0; t < threads; ++t) {
        // Counted before the attempt, so that a failed one is uncounted
        // exactly once and `active` reaches 0 when the started ones end.
        {
            std::lock_guard<std::mutex> lock(done_mu);
            ++active;
        }
        try {
            if (st.cfg.test_fail_thread > 0 && t + 1 >= st.cfg.test_fail_thread)
                throw std::system_error(EAGAIN, std::generic_category(), "Resource temporarily unavailable");
            pool.emplace_back([&st, &active, &done_mu, &done_cv]() {
                worker(st);
                std::lock_guard<std::mutex> lock(done_mu);
                if (--active == 0) done_cv.notify_all();
            });
        } catch (const std::system_error& e) {
            {
                std::lock_guard<std::mutex> lock(done_mu);
                --active;
            }
            st.fail("threads = " + std::to_string(threads) + ": could not start thread " + std::to_string(t + 1) +
                    " (" + e.what() + "); ask for fewer threads");
            break;
        }
    }
    const auto period = std::chrono::milliseconds(100);
    while (true) {
        {
            std::unique_lock<std::mutex> lock(done_mu);
            if (done_cv.wait_for(lock, period, [&active] { return active == 0; })) break;
        }
        if (progress && !progress(st.done_packets.load(), total)) st.user_cancel.store(true);
    }
    for (auto& th : pool) th.join();
}

// The most memory a run's voxel tables may take: grids.max_memory_mb, or
// three quarters of the memory available now (tree_memory_limit).
uint64_t grid_memory_limit(const RunConfig& cfg) {
    return cfg.grid_max_tree_bytes ? cfg.grid_max_tree_bytes : tree_memory_limit();
}

}  // namespace

RunConfig prepare_config(const Scene& scene, const Source& source, const RunConfig& cfg_in,
                         std::vector<std::string>* warnings, bool grid_file) {
    RunConfig cfg = cfg_in;
    validate_config(cfg, scene, grid_file);
    check_scale(scene, source, cfg);
    std::vector<std::string> ignored;
    if (cfg.max_steps == 0) cfg.max_steps = pathological_event_cap(scene, warnings ? *warnings : ignored);
    edge_resolution_warnings(scene, warnings ? *warnings : ignored);
    return cfg;
}

UnitPlan plan_units(const RunConfig& cfg) {
    const bool fixed = cfg.photons > 0;
    UnitPlan p;
    p.unit_size = cfg.unit_size;
    if (p.unit_size == 0) {
        // Depends only on the request, never on the thread count.
        // Store and target runs check their stop rule after every merged unit:
        // 1024-packet units for "store N", 256 for targets so that a loose target
        // can stop after its minimum of 20 units (5120 packets).
        p.unit_size =
            fixed ? std::clamp<uint64_t>((cfg.photons + 999) / 1000, 64, 65536) : (cfg.target_tally >= 0 ? 256 : 1024);
    }
    // A target run without max_photons has a default cap (kDefaultTargetMaxPackets): a target
    // that cannot be reached stops there, or as soon as its projection exceeds it (StopRule).
    const uint64_t open_cap = cfg.target_tally >= 0 ? kDefaultTargetMaxPackets : kMaxPacketRequest;
    p.limit = fixed ? cfg.photons : (cfg.max_photons > 0 ? cfg.max_photons : open_cap);
    p.n_units_max = (p.limit + p.unit_size - 1) / p.unit_size;
    return p;
}

bool grids_per_unit(const RunConfig& cfg) {
    return cfg.grid_voxel_size > 0 && (cfg.photons == 0 || cfg.time_budget_s > 0);
}

UnitBatch trace_units(const Scene& scene, const Source& source, const RunConfig& cfg_in, uint64_t first_unit,
                      uint64_t count, std::atomic<bool>* cancel) {
    const RunConfig cfg = prepare_config(scene, source, cfg_in, nullptr, /*grid_file=*/false);
    const UnitPlan plan = plan_units(cfg);
    UnitBatch batch;
    batch.first_unit = first_unit;
    // One grid set for the whole chunk unless every unit keeps its own; the
    // units are staged into it as a local worker's are into the run's grids.
    std::unique_ptr<GridSet> staging = new_staging(scene, cfg);
    if (staging) batch.grids = new_grids(scene, cfg);
    if (first_unit >= plan.n_units_max) return batch;
    count = std::min(count, plan.n_units_max - first_unit);
    const Halton halton(cfg.seed);
    Tracer tracer(scene, source, halton, cfg);
    const auto tick = [&](uint64_t) { return !(cancel && cancel->load(std::memory_order_relaxed)); };
    const auto flush = [&](const GridSet& g) { batch.grids->merge_from(g); };
    // The chunk's grids (or its units' own) have the run's memory limit on
    // the worker too: the client's SharedGridSet checks it only when the
    // chunk arrives, after the worker has held (and packed) all of it.
    const uint64_t limit = cfg.grid_voxel_size > 0 ? grid_memory_limit(cfg) : 0;
    uint64_t own_bytes = 0;  // the kept units' own grids
    for (uint64_t u = first_unit; u < first_unit + count; ++u) {
        auto out = trace_unit(tracer, scene, cfg, plan, u, staging.get(), /*flush_packets=*/0, tick, flush);
        if (!out) break;
        if (out->own_grids) own_bytes += out->own_grids->memory_bytes();
        batch.units.push_back(std::move(out));
        const uint64_t took = own_bytes + (batch.grids ? batch.grids->memory_bytes() : 0);
        if (limit > 0 && took > limit) throw_voxel_tables_over(cfg.grid_voxel_size, took, limit);
    }
    return batch;
}

struct UnitReducer::Impl {
    const Scene& scene;
    RunResult result;
    const RunConfig cfg;
    const UnitPlan plan;
    const std::chrono::steady_clock::time_point t_start;
    std::unique_ptr<SharedGridSet> grids;  // the run's: the sum of every grid set handed in (null: no grids)
    UnitMerger merger;

    Impl(const Scene& sc, const Source& so, const RunConfig& c)
        : scene(sc),
          cfg(prepare_config(sc, so, c, &result.warnings)),
          plan(plan_units(cfg)),
          t_start(std::chrono::steady_clock::now()),
          merger(cfg, plan.n_units_max, result, t_start) {
        result.unit_size = plan.unit_size;
        if (cfg.grid_voxel_size > 0)
            grids = std::make_unique<SharedGridSet>(cfg.grid_voxel_size, per_fluorophore_grids(sc, cfg),
                                                    grid_memory_limit(cfg), sc.fluorophore_count());
    }
};

UnitReducer::UnitReducer(const Scene& scene, const Source& source, const RunConfig& cfg)
    : impl_(std::make_unique<Impl>(scene, source, cfg)) {}
UnitReducer::~UnitReducer() = default;
bool UnitReducer::add(uint64_t index, std::unique_ptr<UnitOutput> unit,
                      std::vector<std::unique_ptr<GridSet>>& accepted) {
    if (impl_->result.stop != StopReason::kNone) return true;  // past the stop point: discarded
    const bool stop = impl_->merger.add(index, std::move(unit));
    for (auto& g : impl_->merger.accepted()) accepted.push_back(std::move(g));
    impl_->merger.accepted().clear();
    return stop;
}
bool UnitReducer::add(uint64_t index, std::unique_ptr<UnitOutput> unit) {
    std::vector<std::unique_ptr<GridSet>> accepted;
    const bool stop = add(index, std::move(unit), accepted);
    for (const auto& g : accepted) add_grids(*g);
    return stop;
}
void UnitReducer::add_grids(const GridSet& grids) {
    if (!impl_->grids) throw std::logic_error("grids: a run without grids was handed a grid set");
    impl_->grids->add(grids);
}
bool UnitReducer::add_batch(UnitBatch&& batch) {
    if (stopped()) return true;  // past the stop point: discarded
    if (batch.grids) add_grids(*batch.grids);
    for (size_t i = 0; i < batch.units.size(); ++i)
        if (add(batch.first_unit + i, std::move(batch.units[i]))) break;
    return stopped();
}
bool UnitReducer::stopped() const { return impl_->result.stop != StopReason::kNone; }
uint64_t UnitReducer::merged_units() const { return impl_->result.units.size(); }
uint64_t UnitReducer::records() const { return impl_->merger.records(); }
const UnitPlan& UnitReducer::plan() const { return impl_->plan; }
const RunConfig& UnitReducer::config() const { return impl_->cfg; }

namespace {

// The warning of a target run that ended without reaching its target: the relative error it
// reached, the cap, and (stopped early) the packets its projection needed.
std::string target_warning(const RunResult& r, const RunConfig& cfg, const UnitPlan& plan, double projected_units) {
    const Estimate& e = r.scalar[cfg.target_tally];
    std::ostringstream os;
    os.precision(3);
    os << "target not reached: " << tally_name(cfg.target_tally) << " to a relative error of " << cfg.target_rel_error
       << " (reached ";
    if (e.mean != 0)
        os << e.stderr_ / std::fabs(e.mean);
    else
        os << "undefined: the tally is 0";
    os << " after " << r.packets << " packets); ";
    const std::string cap = cfg.max_photons > 0
                                ? "max_photons = " + std::to_string(plan.limit)
                                : "the default cap of " + std::to_string(plan.limit) + " packets (max_photons = 0)";
    if (r.stop == StopReason::kTargetUnreachable)
        os << "it would need about " << projected_units * double(plan.unit_size)
           << " packets (1/sqrt(N) from the error so far), more than " << StopRule::kUnreachableFactor << " times "
           << cap << ": stopped early";
    else
        os << "stopped at " << cap;
    os << "; raise max_photons or loosen the target";
    return os.str();
}

}  // namespace

RunResult UnitReducer::finish(int threads, bool cancelled) {
    RunResult& result = impl_->result;
    const RunConfig& cfg = impl_->cfg;
    result.threads = threads;
    // Workers that left early, or a cancel after the stop rule's end (before the grid write): cancelled.
    if (result.stop == StopReason::kNone || cancelled) result.stop = StopReason::kCancelled;
    result.cancelled = result.stop == StopReason::kCancelled;
    result.target_reached = result.stop == StopReason::kTarget;
    result.store_reached = result.stop == StopReason::kStore;
    finalize_estimates(result, cfg.batches);
    result.packets_traced =
        cfg.store > 0 && result.records.size() > 0 ? result.records.packet.back() + 1 : result.packets;
    const Scene& scene = impl_->scene;
    result.spectral = spectral_run(scene, cfg);
    if (lanes_serve(cfg)) result.lanes = lane_isa_name(lane_isa());
    if (result.packets == 0)
        result.warnings.push_back(
            "no work unit finished before the run stopped: the result holds no estimate "
            "(every fraction and its stderr is 0, photons = 0)");
    if (cfg.target_tally >= 0 &&
        (result.stop == StopReason::kMaxPhotons || result.stop == StopReason::kTargetUnreachable))
        result.warnings.push_back(target_warning(result, cfg, impl_->plan, impl_->merger.projected_units()));
    if (result.capped_packets > 0)
        result.warnings.push_back(std::to_string(result.capped_packets) +
                                  " packets reached the step or path cap; their remaining weight is tallied as cut");
    if (cfg.grid_voxel_size > 0 && result.packets > 0 && !result.cancelled) {  // cancelled: no file
        write_grids(*impl_->grids, scene, cfg, result, std::max(threads, 1));
    }
    impl_->grids.reset();
    result.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - impl_->t_start).count();
    return std::move(result);
}

RunResult run(const Scene& scene, const Source& source, const RunConfig& cfg_in, const ProgressFn& progress,
              std::atomic<bool>* cancel) {
    UnitReducer reducer(scene, source, cfg_in);
    const RunConfig& cfg = reducer.config();
    const UnitPlan& plan = reducer.plan();
    int threads = cfg.threads > 0 ? cfg.threads : int(std::max(1u, std::thread::hardware_concurrency()));
    threads = int(std::min<uint64_t>(uint64_t(threads), plan.n_units_max));
    RunState st(scene, source, cfg, plan.unit_size, plan.limit, plan.n_units_max, reducer, cancel);
    run_workers(st, threads, cfg.photons > 0 ? cfg.photons : 0, progress);
    if (!st.error.empty()) throw std::runtime_error(st.error);
    return reducer.finish(threads, st.cancelled());
}

}  // namespace ep
