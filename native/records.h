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

// The one list of record columns, in their fixed order:
// X(column, member of EscapeRecord, value type, values per record).
// EscapeRecords declares, pushes, appends and sizes its columns from it,
// unit_io serialises them in this order and the binding's records_dict names
// them with `column`; a new column is one line here (and a new unit_io magic).
#define EP_RECORD_COLUMNS(X)                 \
    X(position, position, float, 3)          \
    X(direction, direction, float, 3)        \
    X(normal, normal, float, 3)              \
    X(entry, entry, float, 3)                \
    X(weight, weight, double, 1)             \
    X(energy, energy, double, 1)             \
    X(wavelength, wavelength, float, 1)      \
    X(max_depth, max_depth_cm, float, 1)     \
    X(fluorescent, fluorescent, uint8_t, 1)  \
    X(light, light, uint8_t, 1)              \
    X(kind, kind, uint8_t, 1)                \
    X(fluorophore, fluorophore, int32_t, 1)  \
    X(region, region, int32_t, 1)            \
    X(scatterings, scatterings, uint32_t, 1) \
    X(packet, packet, uint64_t, 1)           \
    X(exit_order, exit_order, uint32_t, 1)   \
    X(next_hit, next_hit, uint8_t, 1)

// A column's name (the key of the binding's records dict) and its values per record.
struct RecordColumn {
    const char* name;
    int width;
};

struct EscapeRecords {
#define EP_DECLARE_COLUMN(column, member, type, width) std::vector<type> column;
    EP_RECORD_COLUMNS(EP_DECLARE_COLUMN)
#undef EP_DECLARE_COLUMN

    size_t size() const { return weight.size(); }
    // Calls f(a.column, b.column) for every column of EP_RECORD_COLUMNS, in its order.
    template <class A, class B, class F>
    static void zip_columns(A& a, B& b, F&& f) {
#define EP_ZIP_COLUMN(column, member, type, width) f(a.column, b.column);
        EP_RECORD_COLUMNS(EP_ZIP_COLUMN)
#undef EP_ZIP_COLUMN
    }
    // Calls f(column, RecordColumn{name, width}) for every column, in the same order.
    template <class R, class F>
    static void for_each_column(R& r, F&& f) {
#define EP_VISIT_COLUMN(column, member, type, width) f(r.column, RecordColumn{#column, width});
        EP_RECORD_COLUMNS(EP_VISIT_COLUMN)
#undef EP_VISIT_COLUMN
    }
    void push(const EscapeRecord& r);
    // Appends the first `count` records of `other` (all if count exceeds its size).
    void append(const EscapeRecords& other, size_t count = SIZE_MAX);
    void clear();
    size_t memory_bytes() const;
};

}  // namespace ep
