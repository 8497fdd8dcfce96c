#include "voxel_grid.h"

#include <algorithm>
#include <sstream>
#include <stdexcept>
#include <string>

namespace ep {

VoxelAccumulator::VoxelAccumulator(double voxel_size) : voxel_size_(voxel_size) {
    if (!(std::isfinite(voxel_size) && voxel_size > 0.0)) {
        std::ostringstream msg;
        msg << "grids.voxel_size = " << voxel_size << " must be a positive finite number";
        throw std::invalid_argument(msg.str());
    }
}

size_t VoxelAccumulator::find(const Coord& c) const {
    if (slots_.empty()) return kNoSlot;
    const size_t mask = slots_.size() - 1;
    for (size_t i = hash_coord(c) & mask;; i = (i + 1) & mask) {
        const Slot& s = slots_[i];
        if (!s.used) return kNoSlot;
        if (same(s.key, c)) return i;
    }
}

size_t VoxelAccumulator::find_or_insert(const Coord& c) { return find_or_insert(c, hash_coord(c)); }

void VoxelAccumulator::grow() {
    const size_t new_cap = slots_.empty() ? kInitialCapacity : slots_.size() * 2;
    std::vector<Slot> old(new_cap, Slot{{0, 0, 0}, 0, Fixed128()});
    old.swap(slots_);
    const size_t mask = new_cap - 1;
    for (const Slot& s : old) {
        if (!s.used) continue;
        size_t i = hash_coord(s.key) & mask;
        while (slots_[i].used) i = (i + 1) & mask;
        slots_[i] = s;
    }
    // Slot positions moved, so the cached slot is stale.
    last_slot_ = kNoSlot;
}

void VoxelAccumulator::overflow(const Coord& c) {
    std::ostringstream msg;
    msg << "grids: voxel (" << c[0] << ", " << c[1] << ", " << c[2]
        << ") sums to 2^47 or more in magnitude, beyond the exact fixed-point range of a grid voxel "
           "(docs/numerics.md, \"Grid sums\")";
    throw std::overflow_error(msg.str());
}

void VoxelAccumulator::drop(double value) {
    Fixed128 f;
    if (Fixed128::from_double(value, f))
        drop(f);
    else
        ++dropped_;  // not finite or |value| >= 2^47: counted only
}

void VoxelAccumulator::drop(const Fixed128& value) { add_dropped(1, value); }

void VoxelAccumulator::add_dropped(uint64_t count, const Fixed128& value) {
    dropped_ += count;
    if (!dropped_value_.add(value))
        throw std::overflow_error(
            "grids: the dropped deposits sum to 2^47 or more in magnitude, beyond the exact fixed-point "
            "range (docs/numerics.md, \"Grid sums\")");
}

void VoxelAccumulator::add_general(double x, double y, double z, double value) {
    if (value == 0.0) return;
    Fixed128 f;
    Coord c;
    if (!Fixed128::from_double(value, f)) {
        drop(value);
        return;
    }
    if (!index_of(x, y, z, c)) {
        drop(f);
        return;
    }
    add_at(c, f);
}

void VoxelAccumulator::add_at(const Coord& c, const Fixed128& value) {
    const size_t i = find_or_insert(c);
    add_to(slots_[i], value);
    last_slot_ = i;
}

void VoxelAccumulator::add_index(const Coord& c, double value) {
    if (value == 0.0) return;
    Fixed128 f;
    if (!Fixed128::from_double(value, f)) {
        drop(value);
        return;
    }
    for (int a = 0; a < 3; ++a) {
        if (c[a] < -kMaxIndex || c[a] > kMaxIndex) {
            drop(f);
            return;
        }
    }
    add_at(c, f);
}

void VoxelAccumulator::add_fixed(const Coord& c, const Fixed128& value) {
    for (int a = 0; a < 3; ++a) {
        if (c[a] < -kMaxIndex || c[a] > kMaxIndex) {
            drop(value);
            return;
        }
    }
    add_at(c, value);
}

void VoxelAccumulator::check_mergeable(const VoxelAccumulator& other) const {
    if (other.voxel_size_ != voxel_size_) {
        std::ostringstream msg;
        msg.precision(17);
        msg << "grids.voxel_size = " << other.voxel_size_
            << " cannot be merged into an accumulator with voxel_size = " << voxel_size_;
        throw std::invalid_argument(msg.str());
    }
}

void VoxelAccumulator::merge_from(const VoxelAccumulator& other) {
    check_mergeable(other);
    if (&other == this) {
        // Self-merge doubles every value; done explicitly because inserting
        // while iterating our own table would be unsafe.
        for (Slot& s : slots_)
            if (s.used) add_to(s, Fixed128(s.value));
        add_dropped(dropped_, Fixed128(dropped_value_));
        return;
    }
    // Fixed-point addition is exact, so a new voxel and an existing one are
    // treated alike and the result does not depend on which side is merged
    // into which. Batches of entries let add_entries prefetch.
    constexpr size_t kBatch = 256;
    Entry batch[kBatch];
    size_t n = 0;
    for (const Slot& s : other.slots_) {
        if (!s.used) continue;
        batch[n++] = Entry{s.key, s.value};
        if (n == kBatch) {
            add_entries(batch, n);
            n = 0;
        }
    }
    add_entries(batch, n);
    add_dropped(other.dropped_, other.dropped_value_);
}

void VoxelAccumulator::add_entries(const Entry* e, size_t n) {
    // Hashes of the next kAhead entries, whose slots are being prefetched. A
    // table growth inside the batch only makes some prefetches useless: the
    // slot itself is always found with the current mask.
    constexpr size_t kAhead = 8;
    uint64_t hash[kAhead];
    const auto prefetch = [&](size_t j) {
        hash[j % kAhead] = hash_coord(e[j].key);
        if (slots_.empty()) return;
        // A 32-byte slot straddles two cache lines at half of the offsets
        // (the table is 16-byte aligned, voxel_grid.h): fetch both.
        const char* slot = reinterpret_cast<const char*>(&slots_[hash[j % kAhead] & (slots_.size() - 1)]);
        __builtin_prefetch(slot, 1);
        __builtin_prefetch(slot + sizeof(Slot) - 1, 1);
    };
    for (size_t j = 0; j < std::min(n, kAhead); ++j) prefetch(j);
    for (size_t j = 0; j < n; ++j) {
        const uint64_t h = hash[j % kAhead];
        if (j + kAhead < n) prefetch(j + kAhead);
        add_to(slots_[find_or_insert(e[j].key, h)], e[j].value);
    }
    last_slot_ = kNoSlot;
}

double VoxelAccumulator::value(const Coord& c) const { return fixed(c).to_double(); }

Fixed128 VoxelAccumulator::fixed(const Coord& c) const {
    const size_t i = find(c);
    return i == kNoSlot ? Fixed128() : slots_[i].value;
}

std::vector<size_t> VoxelAccumulator::sorted_slots() const {
    std::vector<size_t> order;
    order.reserve(size_);
    for (size_t i = 0; i < slots_.size(); ++i)
        if (slots_[i].used) order.push_back(i);
    // Keys are unique, so comparing keys alone gives a total order.
    std::sort(order.begin(), order.end(), [this](size_t a, size_t b) { return slots_[a].key < slots_[b].key; });
    return order;
}

std::vector<std::pair<VoxelAccumulator::Coord, Fixed128>> VoxelAccumulator::sorted_fixed() const {
    std::vector<std::pair<Coord, Fixed128>> out;
    out.reserve(size_);
    for (size_t i : sorted_slots()) out.emplace_back(slots_[i].key, slots_[i].value);
    return out;
}

std::vector<std::pair<VoxelAccumulator::Coord, double>> VoxelAccumulator::sorted() const {
    std::vector<std::pair<Coord, double>> out;
    out.reserve(size_);
    for_each_sorted([&](const Coord& c, double v) { out.emplace_back(c, v); });
    return out;
}

double VoxelAccumulator::sum() const { return sum({this}); }

double VoxelAccumulator::sum(const std::vector<const VoxelAccumulator*>& parts) {
    uint64_t total[3] = {0, 0, 0};
    for (const VoxelAccumulator* p : parts) p->add_sum_to(total);
    return Fixed128::words_to_double(total, 3);
}

void VoxelAccumulator::add_sum_to(uint64_t total[3]) const {
    // Exact: the voxels' fixed-point values added in a third word of headroom
    // (Fixed128::add_to_wide), rounded once by the caller. Tallies mix voxels
    // near the source (large values) with a long tail of tiny ones; none of
    // the tail is lost, and no order enters.
    for (const Slot& s : slots_)
        if (s.used) s.value.add_to_wide(total);
}

size_t VoxelAccumulator::memory_bytes() const { return sizeof(*this) + slots_.capacity() * sizeof(Slot); }

void VoxelAccumulator::clear() {
    std::vector<Slot>().swap(slots_);
    size_ = 0;
    last_slot_ = kNoSlot;
    dropped_ = 0;
    dropped_value_ = Fixed128();
}

void VoxelAccumulator::clear_keep_capacity() {
    for (Slot& slot : slots_) slot.used = 0;
    size_ = 0;
    last_slot_ = kNoSlot;
    dropped_ = 0;
    dropped_value_ = Fixed128();
}

void GridSet::clear_keep_capacity() {
    for (size_t k = 0; k < grid_count(); ++k) grid(k).clear_keep_capacity();
    packets = 0;
}

GridSet::GridSet(double voxel_size, size_t per_fl, size_t emission_grids)
    : absorbed(voxel_size), fluorescence(voxel_size) {
    per_fluorophore.assign(per_fl, VoxelAccumulator(voxel_size));
    emission.assign(emission_grids, VoxelAccumulator(voxel_size));
}

void GridSet::check_mergeable(const GridSet& other) const {
    if (other.per_fluorophore.size() != per_fluorophore.size())
        throw std::invalid_argument("grids: a grid set with " + std::to_string(other.per_fluorophore.size()) +
                                    " per-fluorophore grids cannot be merged into one with " +
                                    std::to_string(per_fluorophore.size()));
    if (other.emission.size() != emission.size())
        throw std::invalid_argument("grids: a grid set with " + std::to_string(other.emission.size()) +
                                    " emission grids cannot be merged into one with " +
                                    std::to_string(emission.size()));
    absorbed.check_mergeable(other.absorbed);
}

void GridSet::merge_from(const GridSet& other) {
    check_mergeable(other);
    for (size_t k = 0; k < grid_count(); ++k) grid(k).merge_from(other.grid(k));
    packets += other.packets;
}

size_t GridSet::memory_bytes() const {
    size_t n = 0;
    for (size_t k = 0; k < grid_count(); ++k) n += grid(k).memory_bytes();
    return n;
}

}  // namespace ep
