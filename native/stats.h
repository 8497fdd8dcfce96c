// Engine counters (`--stats`): events the transport loop meets, counted per
// work unit and merged in unit order at the end of the run (the model is
// pbrt-v4's STAT_COUNTER: per-thread counters, merged once, free when off).
//
// A worker points the thread-local `stats::current` at the unit it traces
// (StatsScope) only when the run asked for counters; each hook in the loop is
// one null test and an increment, so a run without counters pays a predicted
// branch per hooked event (measured in docs/performance.md). Building with
// -DEP_ENGINE_STATS=0 removes the hooks altogether.
#pragma once

#include <cstdint>

#ifndef EP_ENGINE_STATS
#define EP_ENGINE_STATS 1
#endif

namespace ep {

struct EngineStats {
    uint64_t interactions = 0;  // scattering/absorption sites (the `interactions` tally's sum)
    uint64_t crossings = 0;     // interfaces crossed or reflected at (region boundaries)
    uint64_t cache_hits = 0;    // steps whose crossings a cube's triangle cache answered
    uint64_t cache_misses = 0;  // steps the cube's cache could not answer (it then takes the full query)
    uint64_t full_queries = 0;  // Embree ray queries for a step's crossings (misses, and every step without caches)

    void add(const EngineStats& o) {
        interactions += o.interactions;
        crossings += o.crossings;
        cache_hits += o.cache_hits;
        cache_misses += o.cache_misses;
        full_queries += o.full_queries;
    }
};

namespace stats {
// The counters of the unit this thread traces, or null when the run counts nothing.
inline thread_local EngineStats* current = nullptr;
}  // namespace stats

// Points this thread's counters at `target` (null: count nothing) for its lifetime.
class StatsScope {
  public:
    explicit StatsScope(EngineStats* target) : previous_(stats::current) { stats::current = target; }
    ~StatsScope() { stats::current = previous_; }
    StatsScope(const StatsScope&) = delete;
    StatsScope& operator=(const StatsScope&) = delete;

  private:
    EngineStats* previous_;
};

}  // namespace ep

#if EP_ENGINE_STATS
// Adds `n` to counter `field` of the unit being traced, if the run counts.
#define EP_STAT_ADD(field, n)                                        \
    do {                                                             \
        if (__builtin_expect(::ep::stats::current != nullptr, 0))    \
            ::ep::stats::current->field += static_cast<uint64_t>(n); \
    } while (0)
#else
#define EP_STAT_ADD(field, n) \
    do {                      \
    } while (0)
#endif
#define EP_STAT(field) EP_STAT_ADD(field, 1)
