#include "engine.h"

#include <chrono>
#include <cmath>
#include <memory>
#include <mutex>
#include <sstream>
#include <stdexcept>
#include <thread>

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

void finalize_estimates(RunResult& r, int batches) {
    r.packets = 0;
    for (const UnitTally& u : r.units) r.packets += u.packets;
    for (int k = 0; k < kScalarTallies; ++k)
        r.scalar[k] = batch_estimate(r.units, batches, [k](const UnitTally& u) { return u.scalar[k]; });
    for (int k = 0; k < kEnergyTallies; ++k)
        r.energy[k] = batch_estimate(r.units, batches, [k](const UnitTally& u) { return u.energy[k]; });
    const size_t nreg = r.units.empty() ? 0 : r.units.front().absorbed_by_region.size();
    r.absorbed_by_region.assign(nreg, Estimate{});
    for (size_t k = 0; k < nreg; ++k)
        r.absorbed_by_region[k] =
            batch_estimate(r.units, batches, [k](const UnitTally& u) { return u.absorbed_by_region[k]; });
}

namespace {

void validate_config(const RunConfig& c) {
    auto bad = [](const std::string& field, double v, const char* rule) {
        std::ostringstream os;
        os.precision(17);
        os << field << " = " << v << " " << rule;
        throw std::invalid_argument(os.str());
    };
    const int modes = (c.photons > 0) + (c.store > 0) + (c.target_tally >= 0);
    if (modes == 0) throw std::invalid_argument("photons = 0: give photons > 0, store > 0 or a target accuracy");
    if (c.photons > 0 && c.store > 0) throw std::invalid_argument("photons and store are exclusive: give one");
    if (!(c.roulette_threshold >= 0) || !std::isfinite(c.roulette_threshold))
        bad("roulette_threshold", c.roulette_threshold, "must be a finite number >= 0");
    if (!(c.roulette_chance > 0 && c.roulette_chance <= 1)) bad("roulette_chance", c.roulette_chance, "must be in (0, 1]");
    if (!(c.max_path_cm >= 0) || !std::isfinite(c.max_path_cm)) bad("max_path_cm", c.max_path_cm, "must be >= 0");
    if (!(c.grid_voxel_size >= 0) || !std::isfinite(c.grid_voxel_size))
        bad("grids.voxel_size", c.grid_voxel_size, "must be a positive finite number");
    if (c.grid_voxel_size > 0 && c.grid_path.empty()) throw std::invalid_argument("grids.path is empty");
    if (c.target_tally >= kScalarTallies) bad("target.tally", c.target_tally, "is not a tally index");
    if (c.target_tally >= 0 && !(c.target_rel_error > 0)) bad("target.rel_error", c.target_rel_error, "must be > 0");
    if (c.threads < 0) bad("threads", c.threads, "must be >= 0");
    if (c.batches < 2) bad("batches", c.batches, "must be >= 2");
}

std::unique_ptr<VoxelAccumulator> scaled(const VoxelAccumulator& a, double s) {
    auto out = std::make_unique<VoxelAccumulator>(a.voxel_size());
    for (const auto& [c, v] : a.sorted()) out->add_index(c, v * s);
    return out;
}

}  // namespace

UnitPlan plan_units(const RunConfig& cfg) {
    validate_config(cfg);
    const bool fixed = cfg.photons > 0;
    UnitPlan p;
    p.unit_size = cfg.unit_size;
    if (p.unit_size == 0) {
        // Depends only on the request, never on the thread count.
        // Store and target runs check their stop rule after every merged unit:
        // 1024-packet units for "store N", 256 for targets so that a loose target
        // can stop after its minimum of 20 units (5120 packets).
        p.unit_size = fixed ? std::clamp<uint64_t>((cfg.photons + 999) / 1000, 64, 65536)
                            : (cfg.target_tally >= 0 ? 256 : 1024);
    }
    p.limit = fixed ? cfg.photons : (cfg.max_photons > 0 ? cfg.max_photons : UINT64_MAX / 2);
    p.n_units_max = (p.limit + p.unit_size - 1) / p.unit_size;
    return p;
}

namespace {

std::unique_ptr<UnitOutput> new_unit(const Scene& scene, const RunConfig& cfg, const UnitPlan& plan, uint64_t u) {
    auto out = std::make_unique<UnitOutput>();
    out->tally.reset(scene.region_count());
    out->first_packet = u * plan.unit_size;
    if (cfg.grid_voxel_size > 0) {
        out->absorbed_grid = std::make_unique<VoxelAccumulator>(cfg.grid_voxel_size);
        out->fluorescence_grid = std::make_unique<VoxelAccumulator>(cfg.grid_voxel_size);
        if (cfg.grid_per_fluorophore)
            for (size_t f = 0; f < scene.fluorophore_count(); ++f)
                out->per_fluorophore.push_back(std::make_unique<VoxelAccumulator>(cfg.grid_voxel_size));
    }
    return out;
}

// Traces the packets of unit `u`. `tick(k)` is called every 256 packets with
// the index about to be traced; returning false abandons the unit (nullptr).
template <class Tick>
std::unique_ptr<UnitOutput> trace_unit(Tracer& tracer, const Scene& scene, const RunConfig& cfg,
                                       const UnitPlan& plan, uint64_t u, Tick&& tick) {
    auto out = new_unit(scene, cfg, plan, u);
    const uint64_t first = u * plan.unit_size, end = std::min(plan.limit, first + plan.unit_size);
    for (uint64_t k = first; k < end; ++k) {
        if ((k & 255) == 0 && !tick(k)) return nullptr;
        tracer.trace(k, *out);
    }
    return out;
}

}  // namespace

UnitBatch trace_units(const Scene& scene, const Source& source, const RunConfig& cfg, uint64_t first_unit,
                      uint64_t count, std::atomic<bool>* cancel) {
    const UnitPlan plan = plan_units(cfg);
    UnitBatch batch;
    batch.first_unit = first_unit;
    if (first_unit >= plan.n_units_max) return batch;
    count = std::min(count, plan.n_units_max - first_unit);
    const Halton halton(cfg.seed);
    Tracer tracer(scene, source, halton, cfg);
    for (uint64_t u = first_unit; u < first_unit + count; ++u) {
        auto out = trace_unit(tracer, scene, cfg, plan, u, [&](uint64_t) { return !(cancel && cancel->load()); });
        if (!out) break;
        batch.units.push_back(std::move(out));
    }
    return batch;
}

struct UnitReducer::Impl {
    const Scene& scene;
    RunConfig cfg;
    UnitPlan plan;
    std::chrono::steady_clock::time_point t_start = std::chrono::steady_clock::now();
    RunResult result;
    std::map<uint64_t, std::unique_ptr<UnitOutput>> pending;
    uint64_t next_merge = 0;
    uint64_t record_count = 0;
    bool stop = false;
    std::unique_ptr<VoxelAccumulator> g_abs, g_fl;
    std::vector<std::unique_ptr<VoxelAccumulator>> g_per;
    // Prefix sums of the target tally over merged units: the stop rule is then
    // O(batches) per unit instead of O(units).
    std::vector<uint64_t> target_prefix_n{0};
    std::vector<double> target_prefix_sum{0.0};

    Impl(const Scene& s, const RunConfig& c) : scene(s), cfg(c), plan(plan_units(c)) {
        result.unit_size = plan.unit_size;
        if (cfg.grid_voxel_size > 0) {
            g_abs = std::make_unique<VoxelAccumulator>(cfg.grid_voxel_size);
            g_fl = std::make_unique<VoxelAccumulator>(cfg.grid_voxel_size);
            if (cfg.grid_per_fluorophore)
                for (size_t f = 0; f < scene.fluorophore_count(); ++f)
                    g_per.push_back(std::make_unique<VoxelAccumulator>(cfg.grid_voxel_size));
        }
    }

    bool time_is_up() const {
        if (cfg.time_budget_s <= 0) return false;
        const double el = std::chrono::duration<double>(std::chrono::steady_clock::now() - t_start).count();
        return el >= cfg.time_budget_s;
    }

    // Called right after unit next_merge-1 was merged.
    bool stop_predicate() {
        if (cfg.photons > 0) {
            if (next_merge >= plan.n_units_max) return true;
            if (time_is_up()) {
                result.stop_reason = "time";
                return true;
            }
            return false;
        }
        if (next_merge >= plan.n_units_max) {
            result.stop_reason = "max_photons";
            return true;
        }
        if (cfg.store > 0 && record_count >= cfg.store) {
            result.store_reached = true;
            result.stop_reason = "store";
            return true;
        }
        if (cfg.target_tally >= 0) {
            const UnitTally& last = result.units.back();
            target_prefix_n.push_back(target_prefix_n.back() + last.packets);
            target_prefix_sum.push_back(target_prefix_sum.back() + last.scalar[cfg.target_tally]);
            const size_t k = result.units.size();
            if (k >= 20) {
                const Estimate e = batch_estimate_prefix(target_prefix_n, target_prefix_sum, cfg.batches);
                if (e.mean != 0 && std::isfinite(e.stderr_) && e.stderr_ / std::fabs(e.mean) <= cfg.target_rel_error) {
                    result.target_reached = true;
                    result.stop_reason = "target";
                    return true;
                }
                // A relative error of a tally that stays exactly zero is undefined:
                // after 1000 units (256k packets) say so instead of running on.
                if (e.mean == 0 && k >= 1000) {
                    result.stop_reason = "target_zero";
                    return true;
                }
            }
        }
        if (time_is_up()) {
            result.stop_reason = "time";
            return true;
        }
        return false;
    }

    void merge(UnitOutput& u) {
        result.units.push_back(u.tally);
        if (cfg.record_escapes) {
            size_t take = u.records.size();
            if (cfg.store > 0) take = std::min<uint64_t>(take, cfg.store - record_count);
            if (record_count + take > cfg.max_records)
                throw std::runtime_error("escape records exceed max_records = " + std::to_string(cfg.max_records) +
                                         ": pass record_escapes=False, fluorescent_only=True or a larger max_records");
            result.records.append(u.records, take);
            record_count += take;
            result.peak_record_bytes = std::max(result.peak_record_bytes, result.records.memory_bytes());
        }
        if (g_abs) {
            g_abs->merge_from(*u.absorbed_grid);
            g_fl->merge_from(*u.fluorescence_grid);
            for (size_t f = 0; f < g_per.size(); ++f) g_per[f]->merge_from(*u.per_fluorophore[f]);
        }
        ++next_merge;
        if (stop_predicate()) stop = true;
    }

    void write_grids() {
        // Grids hold per-launched-packet values, so the absorbed grid sums to the
        // `absorbed` fraction.
        const double s = 1.0 / double(result.packets);
        auto abs_n = scaled(*g_abs, s);
        auto fl_n = scaled(*g_fl, s);
        std::vector<std::unique_ptr<VoxelAccumulator>> per_n;
        std::vector<GridOutput> outs;
        outs.push_back({"absorbed", "absorbed energy per voxel (weight x 500 nm / wavelength; weight when not spectral), per launched packet", abs_n.get()});
        outs.push_back({"fluorescence", "weight of fluorescent packets summed over their interaction sites (volume photon map density), per launched packet", fl_n.get()});
        for (size_t f = 0; f < g_per.size(); ++f) {
            per_n.push_back(scaled(*g_per[f], s));
            outs.push_back({"fluorescence_" + scene.fluorophore_name(int(f)),
                            "volume photon map density of packets that fluoresced by " + scene.fluorophore_name(int(f)),
                            per_n.back().get()});
        }
        std::map<std::string, std::string> meta;
        meta["packets"] = std::to_string(result.packets);
        meta["seed"] = std::to_string(cfg.seed);
        meta["unit_cm"] = std::to_string(scene.unit_cm());
        meta["engine"] = "endophoton " + engine_version();
        meta["voxel_size"] = std::to_string(cfg.grid_voxel_size);
        write_vdb(cfg.grid_path, outs, meta);
        result.grid_path = cfg.grid_path;
        for (const auto& o : outs) result.grid_names.push_back(o.name);
        result.grid_absorbed_sum = abs_n->sum();
    }
};

UnitReducer::UnitReducer(const Scene& scene, const RunConfig& cfg) : impl_(std::make_unique<Impl>(scene, cfg)) {}
UnitReducer::~UnitReducer() = default;
bool UnitReducer::stopped() const { return impl_->stop; }
uint64_t UnitReducer::merged_units() const { return impl_->next_merge; }
uint64_t UnitReducer::records() const { return impl_->record_count; }
const UnitPlan& UnitReducer::plan() const { return impl_->plan; }

bool UnitReducer::add(uint64_t index, std::unique_ptr<UnitOutput> unit) {
    Impl& m = *impl_;
    if (m.stop || index < m.next_merge) return m.stop;  // past the stop point, or a duplicate
    m.pending.emplace(index, std::move(unit));
    while (!m.stop) {
        auto it = m.pending.find(m.next_merge);
        if (it == m.pending.end()) break;
        std::unique_ptr<UnitOutput> u = std::move(it->second);
        m.pending.erase(it);
        m.merge(*u);
    }
    if (m.stop) m.pending.clear();
    return m.stop;
}

RunResult UnitReducer::finish(int threads) {
    Impl& m = *impl_;
    RunResult& result = m.result;
    const bool fixed = m.cfg.photons > 0;
    result.threads = threads;
    result.cancelled = !m.stop && result.stop_reason.empty();
    if (result.cancelled) result.stop_reason = "cancelled";
    if (fixed && !result.cancelled && result.stop_reason.empty()) result.stop_reason = "photons";
    finalize_estimates(result, m.cfg.batches);
    if (m.cfg.store > 0 && result.records.size() > 0)
        result.packets_traced = result.records.packet.back() + 1;
    else
        result.packets_traced = result.packets;
    result.spectral = m.cfg.force_spectral || m.scene.has_fluorophores() || m.scene.has_spectral_media();
    if (m.g_abs && result.packets > 0 && !result.cancelled) m.write_grids();  // a cancelled run writes no file
    result.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - m.t_start).count();
    return std::move(result);
}

RunResult run(const Scene& scene, const Source& source, const RunConfig& cfg, const ProgressFn& progress,
              std::atomic<bool>* cancel) {
    UnitReducer reducer(scene, cfg);
    const UnitPlan plan = reducer.plan();
    int threads = cfg.threads > 0 ? cfg.threads : int(std::max(1u, std::thread::hardware_concurrency()));
    threads = int(std::min<uint64_t>(uint64_t(threads), plan.n_units_max));
    const Halton halton(cfg.seed);

    std::mutex mu;  // guards the reducer
    std::atomic<uint64_t> next_unit{0};
    std::atomic<bool> stop{false};
    std::atomic<uint64_t> done_packets{0};
    std::string error;
    std::atomic<bool> user_cancel{false};
    auto cancelled = [&]() { return user_cancel.load() || (cancel && cancel->load()); };

    auto worker = [&]() {
        try {
            Tracer tracer(scene, source, halton, cfg);
            while (!stop.load()) {
                if (cancelled()) return;
                const uint64_t u = next_unit.fetch_add(1);
                if (u >= plan.n_units_max) return;
                uint64_t counted = u * plan.unit_size;
                auto out = trace_unit(tracer, scene, cfg, plan, u, [&](uint64_t k) {
                    if (cancelled() || stop.load()) return false;
                    done_packets.fetch_add(k - counted);  // progress every 256 packets
                    counted = k;
                    return true;
                });
                if (!out) return;
                done_packets.fetch_add(std::min(plan.limit, (u + 1) * plan.unit_size) - counted);
                std::lock_guard<std::mutex> lock(mu);
                if (reducer.add(u, std::move(out))) stop.store(true);
            }
        } catch (const std::exception& e) {
            std::lock_guard<std::mutex> lock(mu);
            if (error.empty()) error = e.what();
            stop.store(true);
        }
    };

    // Workers trace; the calling thread only watches: it reports progress and
    // forwards cancellation, so a Python caller can release the GIL here.
    std::atomic<int> active{threads};
    std::vector<std::thread> pool;
    for (int t = 0; t < threads; ++t)
        pool.emplace_back([&]() {
            worker();
            active.fetch_sub(1);
        });
    const uint64_t total = cfg.photons > 0 ? cfg.photons : 0;
    auto last = std::chrono::steady_clock::now();
    while (active.load() > 0) {
        std::this_thread::sleep_for(std::chrono::milliseconds(20));
        const auto now = std::chrono::steady_clock::now();
        if (progress && std::chrono::duration<double>(now - last).count() >= 0.1) {
            last = now;
            if (!progress(done_packets.load(), total)) user_cancel.store(true);
        }
    }
    for (auto& th : pool) th.join();
    if (!error.empty()) throw std::runtime_error(error);
    return reducer.finish(threads);
}

}  // namespace ep
