// The surface photon map: one record per exit of a packet from the tissue into
// the ambient (a packet that crosses the lumen and leaves again gives several),
// stored column-wise so that each column can be handed to numpy without a copy.
#pragma once
#include <cstdint>
#include <vector>

#include "vecmath.h"

namespace ep {

struct EscapeRecord {
    Vec3 position, direction, normal, entry;
    Float weight = 0, energy = 0;
    Float wavelength = 0, max_depth_cm = 0;
    int fluorophore = -1;
    int region = -1;
    uint32_t scatterings = 0;
    uint64_t packet = 0;
    uint8_t fluorescent = 0, light = 0, kind = 0;  // kind: 0 reflected, 1 transmitted
    uint32_t exit_order = 1;  // 1 for the packet's first exit into the ambient, 2 for its second, ...
    uint8_t next_hit = 0;     // where the exit's ray went next: a NextHit
};

// Where the straight ray of an exit into the ambient goes next.
enum NextHit : uint8_t { kNextAway = 0, kNextTissue = 1, kNextHead = 2, kNextCamera = 3 };

struct EscapeRecords {
    std::vector<float> position, direction, normal, entry;  // 3 per record
    std::vector<double> weight, energy;
    std::vector<float> wavelength, max_depth;
    std::vector<uint8_t> fluorescent, light, kind;
    std::vector<int32_t> fluorophore, region;
    std::vector<uint32_t> scatterings;
    std::vector<uint64_t> packet;
    std::vector<uint32_t> exit_order;
    std::vector<uint8_t> next_hit;

    size_t size() const { return weight.size(); }
    // Calls f(a.column, b.column) for every column, in one fixed order: the one
    // list of columns that appending, serialising (unit_io) and any other
    // column-wise operation share, so a new column cannot be forgotten.
    template <class A, class B, class F>
    static void zip_columns(A& a, B& b, F&& f) {
        f(a.position, b.position), f(a.direction, b.direction), f(a.normal, b.normal), f(a.entry, b.entry);
        f(a.weight, b.weight), f(a.energy, b.energy), f(a.wavelength, b.wavelength), f(a.max_depth, b.max_depth);
        f(a.fluorescent, b.fluorescent), f(a.light, b.light), f(a.kind, b.kind), f(a.fluorophore, b.fluorophore);
        f(a.region, b.region), f(a.scatterings, b.scatterings), f(a.packet, b.packet);
        f(a.exit_order, b.exit_order), f(a.next_hit, b.next_hit);
    }
    template <class R, class F>
    static void for_each_column(R& r, F&& f) {
        zip_columns(r, r, [&](auto& col, auto&) { f(col); });
    }
    void push(const EscapeRecord& r);
    // Appends the first `count` records of `other` (all if count exceeds its size).
    void append(const EscapeRecords& other, size_t count = SIZE_MAX);
    void clear();
    size_t memory_bytes() const;
};

}  // namespace ep
