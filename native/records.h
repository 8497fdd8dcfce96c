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
    void push(const EscapeRecord& r);
    // Appends the first `count` records of `other` (all if count exceeds its size).
    void append(const EscapeRecords& other, size_t count = SIZE_MAX);
    void clear();
    size_t memory_bytes() const;
};

}  // namespace ep
