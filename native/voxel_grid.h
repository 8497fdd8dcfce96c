// Sparse voxel accumulation for volumetric tallies (absorbed weight,
// fluorescence emission, ...).
//
// The photon loop deposits into a VoxelAccumulator at every interaction when
// grids are requested, so this header deliberately carries no OpenVDB: the
// accumulator is a plain open-addressing hash map from an int32 voxel
// coordinate to a double. Conversion to OpenVDB happens once, at output time,
// in vdb_writer.cpp.
//
// Determinism contract: a voxel holds the exact sum of its deposits as a
// fixed-point number (fixed_point.h), so its value does not depend on the
// order or grouping of the deposits: the engine's worker threads each keep
// one accumulator for the whole run, Dask chunks ship one per chunk, and
// merging them in any order gives the same bits (docs/numerics.md, "Grid
// sums"). Neither the hash layout nor the iteration order enters a result.
#pragma once

#include <array>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <utility>
#include <vector>

#include "fixed_point.h"

namespace ep {

// The three integer coordinates of a voxel (or of a block of voxels) mixed into
// 64 bits by one odd multiplier each (golden-ratio and xxHash primes), so every
// input bit reaches the high bits. VoxelAccumulator's table hash finalises it;
// SharedGridSet takes its top bits to pick a shard.
inline uint64_t mix_coord(int32_t x, int32_t y, int32_t z) {
    return uint64_t(uint32_t(x)) * 0x9E3779B97F4A7C15ull ^ uint64_t(uint32_t(y)) * 0xC2B2AE3D27D4EB4Full ^
           uint64_t(uint32_t(z)) * 0x165667B19E3779F9ull;
}

class VoxelAccumulator {
  public:
    using Coord = std::array<int32_t, 3>;

    // Largest |index| accepted on any axis. OpenVDB uses int32 coordinates and
    // does bounding-box arithmetic (max + 1, max - min) on them; keeping a
    // factor of two of headroom means no tool downstream can overflow.
    static constexpr int32_t kMaxIndex = 1 << 30;

    // voxel_size in scene units; throws std::invalid_argument unless it is a
    // positive finite number.
    explicit VoxelAccumulator(double voxel_size);

    // Deposit `value` at world position (x, y, z), scene units.
    // The voxel index on each axis is f = x / voxel_size rounded to nearest,
    // halves upward: voxels are cell-centred, voxel i takes the f in
    // [i - 0.5, i + 0.5) and is centred at i h. This is the rule of OpenVDB's
    // Coord::round / worldToIndexCellCentered (without its rounding slip just
    // below .5), so a linear transform of scale h maps index (i, j, k) back to
    // the voxel centre.
    // The value is added exactly in fixed point (fixed_point.h: exact for
    // 2^-28 <= |value| < 2^47, rounded to a multiple of 2^-80 below).
    // A deposit is dropped (counted by dropped(), its value summed into
    // dropped_value() if it converts) when the position is not finite, the
    // index is beyond kMaxIndex, or the value is not finite or |value| >= 2^47:
    // NaN never enters the map. A deposit of exactly zero is a no-op and
    // creates no voxel. A voxel total leaving the fixed-point range throws
    // std::overflow_error naming the voxel (never a silent wrap).
    void add(double x, double y, double z, double value) {
        Coord c;
        const bool in_range = index_of(x, y, z, c);
        unsigned __int128 low;
        const bool fast = Fixed128::fast_low(value, low);
        add_resolved(x, y, z, c, in_range, value, fast, low);
    }

    // add(x, y, z, value) with the voxel index already computed by
    // index_of(x, y, z, c) (returning `in_range`) and `value` converted by
    // Fixed128::fast_low (returning `fast`, `low`): several grids of one
    // voxel size that take a deposit at the same point (GridSet::deposit)
    // share these steps. The common deposit (2^-28 <= value < 2^47) stays in
    // registers; every other value (zero included) takes add_general.
    void add_resolved(double x, double y, double z, const Coord& c, bool in_range, double value, bool fast,
                      unsigned __int128 low) {
        if (!fast)
            add_general(x, y, z, value);
        else if (!in_range)
            drop(value);
        else
            add_low(c, low);
    }

    // Adds `value` to voxel `c` directly (index space). Indices beyond
    // kMaxIndex and values that do not convert are dropped like in add().
    void add_index(const Coord& c, double value);
    // Adds the exact fixed-point `value` to voxel `c` (restoring an
    // accumulator from its byte form, unit_io.cpp); a zero value still
    // creates the voxel, as the deposits that summed to it did.
    void add_fixed(const Coord& c, const Fixed128& value);

    // this[v] += other[v] for every voxel of `other` (a voxel missing here is
    // copied), exactly: merging A into B or B into A, or three accumulators
    // in any grouping, gives the same bits. Also adds other's dropped
    // counters. Throws std::invalid_argument if the voxel sizes differ.
    void merge_from(const VoxelAccumulator& other);
    // Throws merge_from's std::invalid_argument if the voxel sizes differ.
    void check_mergeable(const VoxelAccumulator& other) const;

    // A voxel and its exact value: the unit of batch insertion (add_entries)
    // and of the writer's gathered voxel lists.
    struct Entry {
        Coord key;
        Fixed128 value;
    };
    // this[e.key] += e.value for the n entries (keys from an accumulator of
    // this voxel size, so in range), exactly, like merge_from. Each entry's
    // table slot is prefetched a few entries ahead: a table holding a whole
    // run does not fit the cache, and the independent inserts then overlap
    // their memory latency instead of paying it one after the other.
    void add_entries(const Entry* e, size_t n);
    // Calls f(const Coord&, const Fixed128&) for every voxel, in table order
    // (which depends on the hash layout: only for order-free uses).
    template <class F>
    void for_each(F&& f) const {
        for (const Slot& s : slots_)
            if (s.used) f(s.key, s.value);
    }

    // Voxel index of a world position; false if not finite or out of range.
    bool index_of(double x, double y, double z, Coord& out) const {
        const double f[3] = {x / voxel_size_, y / voxel_size_, z / voxel_size_};
        // One predictable branch for all axes; the comparison is false for
        // NaN, so NaN and +-inf are rejected here too.
        const bool in_range = (std::fabs(f[0]) <= double(kMaxIndex)) & (std::fabs(f[1]) <= double(kMaxIndex)) &
                              (std::fabs(f[2]) <= double(kMaxIndex));
        if (!in_range) return false;
        for (int a = 0; a < 3; ++a) {
            // Round half up without branches (the half-way test is a coin flip
            // for the branch predictor, and this runs at every interaction).
            // Not floor(f + 0.5): that sum itself rounds, sending the largest
            // double below 0.5 into voxel 1. Instead floor(f + 1/2) =
            // floor((floor(2f) + 1) / 2), and 2f is exact (|f| <= 2^30), so
            // one truncation, its correction to floor and a shift give the
            // exact rule: one compare fewer per axis than floor(f) plus a
            // test of f - floor(f) >= 1/2.
            const double twice = f[a] + f[a];
            int64_t i = static_cast<int64_t>(twice);       // truncation toward zero
            i -= static_cast<int64_t>(twice < double(i));  // -> floor(2f)
            i = (i + 1) >> 1;                              // arithmetic shift: floor((floor(2f) + 1) / 2)
            out[a] = static_cast<int32_t>(i);
        }
        return true;
    }

    // Value stored at voxel c, rounded to the nearest double (0 if the voxel
    // was never touched).
    double value(const Coord& c) const;
    // The exact fixed-point value of voxel c (0 if never touched).
    Fixed128 fixed(const Coord& c) const;

    // Sum of all voxel values, computed exactly and rounded once to the
    // nearest double.
    double sum() const;
    // The same over several accumulators (the parts of one grid), still
    // rounded once, so it equals sum() of their merge.
    static double sum(const std::vector<const VoxelAccumulator*>& parts);
    // total += the exact sum of the voxels, in three words (Fixed128::add_to_wide):
    // Fixed128::words_to_double(total, 3) rounds it.
    void add_sum_to(uint64_t total[3]) const;

    // All voxels sorted by (x, y, z) ascending, values rounded to doubles.
    std::vector<std::pair<Coord, double>> sorted() const;
    // The same with the exact values (the byte form of unit_io.cpp).
    std::vector<std::pair<Coord, Fixed128>> sorted_fixed() const;

    // Calls f(const Coord&, double) for every voxel in sorted order, with
    // the value rounded to a double (only the slot order is copied).
    template <class F>
    void for_each_sorted(F&& f) const {
        for (size_t i : sorted_slots()) f(slots_[i].key, slots_[i].value.to_double());
    }

    size_t voxel_count() const { return size_; }
    double voxel_size() const { return voxel_size_; }
    uint64_t dropped() const { return dropped_; }
    // Sum of the dropped deposits whose value converts to fixed point (a
    // position out of range); non-finite values and |value| >= 2^47 are only
    // counted. Exact, so it too is independent of the merge order.
    double dropped_value() const { return dropped_value_.to_double(); }
    const Fixed128& dropped_value_fixed() const { return dropped_value_; }

    // Approximate heap + object footprint in bytes.
    size_t memory_bytes() const;

    // Removes all voxels and counters; keeps the voxel size.
    void clear();
    // The same, but keeps the table's memory for reuse (a staging grid that
    // is filled and emptied once per work unit).
    void clear_keep_capacity();

    // Adds to the dropped counters (restoring an accumulator from its byte
    // form, unit_io.cpp, keeps them exact).
    void add_dropped(uint64_t count, const Fixed128& value);

  private:
    // 32 bytes. Not alignas(32): glibc's aligned allocations of the grown
    // tables fragmented the heap (colon at 0.2 mm: peak 343 MB against 300 MB
    // unaligned), so with malloc's 16-byte alignment half of the slots
    // straddle two cache lines.
    struct Slot {
        Coord key;
        uint32_t used;  // 0 = empty; a flag instead of a sentinel key keeps every coordinate legal
        Fixed128 value;
    };
    static_assert(sizeof(Slot) == 32, "a voxel slot is 12 + 4 + 16 bytes");
    static constexpr size_t kNoSlot = ~size_t(0);

    // std::array's operator== lowers to a memcmp call; three integer
    // compares are several times cheaper on the probe path.
    static bool same(const Coord& a, const Coord& b) { return ((a[0] ^ b[0]) | (a[1] ^ b[1]) | (a[2] ^ b[2])) == 0; }

    // Adds a fast_low value to voxel c (in range). Consecutive deposits of one
    // packet usually fall in the same voxel (mean free paths are often
    // shorter than a voxel), so remembering the last slot skips the hash
    // probe in the common case.
    void add_low(const Coord& c, unsigned __int128 low) {
        if (last_slot_ == kNoSlot || !same(c, slots_[last_slot_].key)) last_slot_ = find_or_insert(c);
        if (!slots_[last_slot_].value.add_low(low)) overflow(c);
    }
    std::vector<size_t> sorted_slots() const;  // used slots by ascending key
    void add_general(double x, double y, double z, double value);
    void add_at(const Coord& c, const Fixed128& value);
    void add_to(Slot& s, const Fixed128& value) {
        if (!s.value.add(value)) overflow(s.key);
    }
    [[noreturn]] static void overflow(const Coord& c);
    // Full 64-bit avalanche of the three coordinates. Photon deposits cluster in
    // small neighbourhoods, so a weak hash (xor of scaled coordinates) would pile
    // neighbouring voxels into runs under linear probing; the splitmix64 finalizer
    // spreads them over the whole table.
    static uint64_t hash_coord(const Coord& c) {
        uint64_t h = mix_coord(c[0], c[1], c[2]);
        h ^= h >> 30;
        h *= 0xBF58476D1CE4E5B9ull;
        h ^= h >> 27;
        h *= 0x94D049BB133111EBull;
        h ^= h >> 31;
        return h;
    }
    // The table doubles past this fill. Three quarters keeps linear-probe chains
    // short (about 2.5 probes to find a voxel) while the table holds 4/3 to 8/3
    // slots of 32 bytes a voxel; most deposits hit the cached
    // last slot and probe nothing.
    static constexpr size_t kMaxLoadNum = 3, kMaxLoadDen = 4;
    static constexpr size_t kInitialCapacity = 64;

    size_t find_or_insert(const Coord& c);  // out of line: the deposit path calls it rarely
    // Inline for the batch insert (add_entries), whose loop it is.
    size_t find_or_insert(const Coord& c, uint64_t hash) {
        if ((size_ + 1) * kMaxLoadDen > slots_.size() * kMaxLoadNum) grow();
        const size_t mask = slots_.size() - 1;
        for (size_t i = hash & mask;; i = (i + 1) & mask) {
            Slot& s = slots_[i];
            if (!s.used) {
                s.key = c;
                s.used = 1;
                s.value = Fixed128();
                ++size_;
                return i;
            }
            if (same(s.key, c)) return i;
        }
    }
    size_t find(const Coord& c) const;
    void grow();
    void drop(double value);  // counts it; sums it too if it converts
    void drop(const Fixed128& value);

    double voxel_size_;
    std::vector<Slot> slots_;  // capacity is zero or a power of two
    size_t size_ = 0;
    size_t last_slot_ = kNoSlot;
    uint64_t dropped_ = 0;
    Fixed128 dropped_value_;
};

// The volume grids of a run, or of a part of it whose deposits are summed
// together: a worker thread, a Dask chunk, or one unit of a run whose stop
// rule may discard units (engine.cpp). Absorbed energy, the weight of
// fluorescent packets at their interaction sites (optionally also per
// fluorophore), and the weight each fluorophore converts into fluorescence
// at its conversion points (emission, one grid per fluorophore of a scene
// that has any). docs/design.md, "Grids", defines each quantity.
struct GridSet {
    GridSet(double voxel_size, size_t per_fluorophore_grids, size_t emission_grids = 0);
    VoxelAccumulator absorbed, fluorescence;
    std::vector<VoxelAccumulator> per_fluorophore;
    std::vector<VoxelAccumulator> emission;  // by fluorophore id; empty when the scene has no fluorophore
    // Packets of the finished units whose deposits these grids hold: the
    // engine checks that the run's grids hold exactly its merged packets.
    uint64_t packets = 0;

    // The deposits of one interaction at world position (x, y, z): with
    // `with_absorbed`, `absorbed_value` into the absorbed grid and, when
    // `fluorescent` (a fluorescent packet whose light the run's grids hold),
    // `weight` into the fluorescence grid and, if there are per-fluorophore
    // grids, into that of its fluorophore `fluorophore`. The same bits and
    // counters as calling add(x, y, z, ...) on each of those grids; the grids
    // share one voxel size, so the voxel index is computed once, and the
    // weight converted to fixed point once.
    __attribute__((always_inline)) void deposit(double x, double y, double z, bool with_absorbed, double absorbed_value,
                                                bool fluorescent, size_t fluorophore, double weight) {
        if (!with_absorbed && !fluorescent) return;
        VoxelAccumulator::Coord c;
        const bool in_range = absorbed.index_of(x, y, z, c);
        unsigned __int128 low;
        bool fast;
        if (with_absorbed) {
            fast = Fixed128::fast_low(absorbed_value, low);
            absorbed.add_resolved(x, y, z, c, in_range, absorbed_value, fast, low);
        }
        if (!fluorescent) return;
        fast = Fixed128::fast_low(weight, low);
        fluorescence.add_resolved(x, y, z, c, in_range, weight, fast, low);
        if (!per_fluorophore.empty())
            per_fluorophore[fluorophore].add_resolved(x, y, z, c, in_range, weight, fast, low);
    }

    // A fluorescence event: fluorophore `fluorophore` converts a packet of
    // weight `weight` into fluorescence at world position (x, y, z). Added to
    // its emission grid (rare next to deposit(): once per event).
    void emit(double x, double y, double z, size_t fluorophore, double weight) {
        if (fluorophore < emission.size()) emission[fluorophore].add(x, y, z, weight);
    }

    // The grids by number: 0 absorbed, 1 fluorescence, 2 + f per fluorophore
    // f, then 2 + per_fluorophore.size() + f the emission of fluorophore f.
    size_t grid_count() const { return 2 + per_fluorophore.size() + emission.size(); }
    VoxelAccumulator& grid(size_t k) {
        if (k < 2) return k == 0 ? absorbed : fluorescence;
        k -= 2;
        return k < per_fluorophore.size() ? per_fluorophore[k] : emission[k - per_fluorophore.size()];
    }
    const VoxelAccumulator& grid(size_t k) const { return const_cast<GridSet*>(this)->grid(k); }

    // Adds every grid of `other` (exact, any order); throws
    // std::invalid_argument if the two sets differ in shape or voxel size.
    void merge_from(const GridSet& other);
    // Throws what merge_from throws when `other` cannot be merged into this.
    void check_mergeable(const GridSet& other) const;
    // Empties every grid and the packet count, keeping the tables' memory.
    void clear_keep_capacity();
    size_t memory_bytes() const;
};

}  // namespace ep
