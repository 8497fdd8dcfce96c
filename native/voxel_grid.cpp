#include "voxel_grid.h"

#include <algorithm>
#include <sstream>
#include <stdexcept>

namespace ep {

namespace {

// Full 64-bit avalanche of the three coordinates. Photon deposits cluster in
// small neighbourhoods, so a weak hash (xor of scaled coordinates) would pile
// neighbouring voxels into runs under linear probing; the splitmix64 finalizer
// spreads them over the whole table.
inline uint64_t hash_coord(const VoxelAccumulator::Coord& c) {
    uint64_t h = uint64_t(uint32_t(c[0])) * 0x9E3779B97F4A7C15ull;
    h ^= uint64_t(uint32_t(c[1])) * 0xC2B2AE3D27D4EB4Full;
    h ^= uint64_t(uint32_t(c[2])) * 0x165667B19E3779F9ull;
    h ^= h >> 30;
    h *= 0xBF58476D1CE4E5B9ull;
    h ^= h >> 27;
    h *= 0x94D049BB133111EBull;
    h ^= h >> 31;
    return h;
}

// Keeps linear-probe chains short; the table doubles past this fill.
constexpr size_t kMaxLoadNum = 1, kMaxLoadDen = 2;
constexpr size_t kInitialCapacity = 64;

}  // namespace

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

size_t VoxelAccumulator::find_or_insert(const Coord& c) {
    if ((size_ + 1) * kMaxLoadDen > slots_.size() * kMaxLoadNum) grow();
    const size_t mask = slots_.size() - 1;
    for (size_t i = hash_coord(c) & mask;; i = (i + 1) & mask) {
        Slot& s = slots_[i];
        if (!s.used) {
            s.key = c;
            s.used = 1;
            s.value = 0.0;
            ++size_;
            return i;
        }
        if (same(s.key, c)) return i;
    }
}

void VoxelAccumulator::grow() {
    const size_t new_cap = slots_.empty() ? kInitialCapacity : slots_.size() * 2;
    std::vector<Slot> old(new_cap, Slot{{0, 0, 0}, 0, 0.0});
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

void VoxelAccumulator::add_at(const Coord& c, double value) {
    const size_t i = find_or_insert(c);
    slots_[i].value += value;
    last_slot_ = i;
}

void VoxelAccumulator::add_index(const Coord& c, double value) {
    if (value == 0.0) return;
    for (int a = 0; a < 3; ++a) {
        if (c[a] < -kMaxIndex || c[a] > kMaxIndex) {
            drop(value);
            return;
        }
    }
    if (!std::isfinite(value)) {
        drop(value);
        return;
    }
    add_at(c, value);
}

void VoxelAccumulator::merge_from(const VoxelAccumulator& other) {
    if (other.voxel_size_ != voxel_size_) {
        std::ostringstream msg;
        msg.precision(17);
        msg << "grids.voxel_size = " << other.voxel_size_
            << " cannot be merged into an accumulator with voxel_size = " << voxel_size_;
        throw std::invalid_argument(msg.str());
    }
    if (&other == this) {
        // Self-merge doubles every value; done explicitly because inserting
        // while iterating our own table would be unsafe.
        for (Slot& s : slots_)
            if (s.used) s.value += s.value;
        dropped_ += dropped_;
        dropped_value_ += dropped_value_;
        return;
    }
    for (const Slot& s : other.slots_) {
        if (!s.used) continue;
        const size_t before = size_;
        const size_t i = find_or_insert(s.key);
        // A new voxel takes other's value as is; an existing one gets exactly
        // one addition, and IEEE addition is commutative, so merging A into B
        // or B into A yields identical bits.
        if (size_ != before)
            slots_[i].value = s.value;
        else
            slots_[i].value += s.value;
    }
    last_slot_ = kNoSlot;
    dropped_ += other.dropped_;
    dropped_value_ += other.dropped_value_;
}

double VoxelAccumulator::value(const Coord& c) const {
    const size_t i = find(c);
    return i == kNoSlot ? 0.0 : slots_[i].value;
}

std::vector<std::pair<VoxelAccumulator::Coord, double>> VoxelAccumulator::sorted() const {
    std::vector<std::pair<Coord, double>> out;
    out.reserve(size_);
    for (const Slot& s : slots_)
        if (s.used) out.emplace_back(s.key, s.value);
    // Keys are unique, so comparing keys alone gives a total order.
    std::sort(out.begin(), out.end(), [](const auto& a, const auto& b) { return a.first < b.first; });
    return out;
}

double VoxelAccumulator::sum() const {
    // Neumaier summation: tallies mix voxels near the source (large values)
    // with a long tail of tiny ones, exactly the case where naive summation
    // loses the tail. Sorting first makes the result independent of the hash
    // layout, which depends on insertion and growth history.
    double s = 0.0, comp = 0.0;
    for (const auto& kv : sorted()) {
        const double v = kv.second;
        const double t = s + v;
        if (std::fabs(s) >= std::fabs(v))
            comp += (s - t) + v;
        else
            comp += (v - t) + s;
        s = t;
    }
    return s + comp;
}

size_t VoxelAccumulator::memory_bytes() const { return sizeof(*this) + slots_.capacity() * sizeof(Slot); }

void VoxelAccumulator::clear() {
    std::vector<Slot>().swap(slots_);
    size_ = 0;
    last_slot_ = kNoSlot;
    dropped_ = 0;
    dropped_value_ = 0.0;
}

}  // namespace ep
