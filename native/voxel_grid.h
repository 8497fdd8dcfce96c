// Sparse voxel accumulation for volumetric tallies (absorbed weight,
// fluorescence emission, ...).
//
// The photon loop deposits into a VoxelAccumulator at every interaction when
// grids are requested, so this header deliberately carries no OpenVDB: the
// accumulator is a plain open-addressing hash map from an int32 voxel
// coordinate to a double. Conversion to OpenVDB happens once, at output time,
// in vdb_writer.cpp.
//
// Determinism contract: the engine gives every work unit its own accumulator
// and merges them in unit order. Within one accumulator the value of a voxel
// is the sum of its deposits in call order; merge_from() adds exactly one
// term per voxel, so neither the hash layout nor the iteration order of the
// source can change any bit of the result.
#pragma once

#include <array>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <utility>
#include <vector>

namespace ep {

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
    // A deposit is dropped (counted by dropped(), its value if finite summed
    // into dropped_value()) when the position is not finite, the index is
    // beyond kMaxIndex, or the value is not finite: NaN never enters the map.
    // A deposit of exactly zero is a no-op and creates no voxel.
    void add(double x, double y, double z, double value) {
        if (value == 0.0) return;
        Coord c;
        if (!std::isfinite(value) || !index_of(x, y, z, c)) {
            drop(value);
            return;
        }
        // Consecutive deposits of one packet usually fall in the same voxel
        // (mean free paths are often shorter than a voxel), so remembering the
        // last slot skips the hash probe in the common case.
        if (last_slot_ != kNoSlot && same(c, slots_[last_slot_].key)) {
            slots_[last_slot_].value += value;
            return;
        }
        add_at(c, value);
    }

    // Adds `value` to voxel `c` directly (index space). No range check beyond
    // kMaxIndex; non-finite values are dropped like in add().
    void add_index(const Coord& c, double value);

    // this[v] += other[v] for every voxel of `other` (a voxel missing here is
    // copied). Also adds other's dropped counters. Throws std::invalid_argument
    // if the voxel sizes differ.
    void merge_from(const VoxelAccumulator& other);

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
            // double below 0.5 into voxel 1. f - floor(f) is exact, so the
            // half-way test sees the true fractional part.
            int64_t i = static_cast<int64_t>(f[a]);       // truncation toward zero
            i -= static_cast<int64_t>(f[a] < double(i));  // -> floor
            i += static_cast<int64_t>(f[a] - double(i) >= 0.5);
            out[a] = static_cast<int32_t>(i);
        }
        return true;
    }

    // Value stored at voxel c (0 if the voxel was never touched).
    double value(const Coord& c) const;

    // Sum of all voxel values, in ascending key order with compensated
    // (Neumaier) summation: the result does not depend on insertion history.
    double sum() const;

    // All voxels sorted by (x, y, z) ascending.
    std::vector<std::pair<Coord, double>> sorted() const;

    // Calls f(const Coord&, double) for every voxel in sorted order.
    template <class F>
    void for_each_sorted(F&& f) const {
        for (const auto& kv : sorted()) f(kv.first, kv.second);
    }

    size_t voxel_count() const { return size_; }
    double voxel_size() const { return voxel_size_; }
    uint64_t dropped() const { return dropped_; }
    double dropped_value() const { return dropped_value_; }

    // Approximate heap + object footprint in bytes.
    size_t memory_bytes() const;

    // Removes all voxels and counters; keeps the voxel size.
    void clear();

    // Adds to the dropped counters (restoring an accumulator from its byte
    // form, unit_io.cpp, keeps them exact).
    void add_dropped(uint64_t count, double value) {
        dropped_ += count;
        dropped_value_ += value;
    }

  private:
    struct Slot {
        Coord key;
        uint32_t used;  // 0 = empty; a flag instead of a sentinel key keeps every coordinate legal
        double value;
    };
    static constexpr size_t kNoSlot = ~size_t(0);

    // std::array's operator== lowers to a memcmp call; three integer
    // compares are several times cheaper on the probe path.
    static bool same(const Coord& a, const Coord& b) { return ((a[0] ^ b[0]) | (a[1] ^ b[1]) | (a[2] ^ b[2])) == 0; }

    void add_at(const Coord& c, double value);
    size_t find_or_insert(const Coord& c);
    size_t find(const Coord& c) const;
    void grow();
    void drop(double value) {
        ++dropped_;
        if (std::isfinite(value)) dropped_value_ += value;
    }

    double voxel_size_;
    std::vector<Slot> slots_;  // capacity is zero or a power of two
    size_t size_ = 0;
    size_t last_slot_ = kNoSlot;
    uint64_t dropped_ = 0;
    double dropped_value_ = 0.0;
};

}  // namespace ep
