#include "unit_io.h"

#include <cstring>
#include <stdexcept>
#include <type_traits>

#include "engine.h"
#include "voxel_grid.h"

namespace ep {

namespace {

// Bumped whenever the layout below changes; a worker with another build is
// then refused by name instead of producing garbage.
constexpr char kMagic[8] = {'E', 'P', 'U', 'N', 'I', 'T', '0', '5'};

enum class GridPlace { kUnit, kChunk };

// The one list of a unit's fields, in their byte order: pack_units (io is a
// Writer) and unpack_units (a Reader) both walk it, io.field writing or
// reading each. A new field that must travel is one io.field line here (any
// trivially copyable value, fixed array, or std::vector of them) and a new
// kMagic; the record columns follow EP_RECORD_COLUMNS (records.h).
template <class IO, class Unit>
void unit_fields(IO& io, Unit& u) {
    io.field(u.first_packet);
    auto& t = u.tally;
    io.field(t.packets);
    io.field(t.capped_packets);
    io.field(t.scalar);
    io.field(t.energy);
    io.field(t.absorbed_by_region);
    io.field(t.emitted_by_fluorophore);
    io.field(t.scalar_m);
    io.field(t.energy_m);
    io.field(t.absorbed_by_region_m);
    io.field(t.emitted_by_fluorophore_m);
    EscapeRecords::for_each_column(u.records, [&](auto& column, RecordColumn) { io.field(column); });
    io.grids(u.own_grids, GridPlace::kUnit);
}

// A grid set's fields, in their byte order (after its presence byte).
template <class IO, class Grids>
void grid_set_fields(IO& io, Grids& g) {
    io.field(g.packets);
    io.grid(g.absorbed);
    io.grid(g.fluorescence);
    io.grid_list(g.per_fluorophore);
    io.grid_list(g.emission);
}

// A batch: the magic, its first unit, its units, and the chunk's grids (its units' deposits summed).
template <class IO, class Batch>
void batch_fields(IO& io, Batch& b) {
    io.magic();
    io.field(b.first_unit);
    io.units(b.units);
    io.grids(b.grids, GridPlace::kChunk);
}

class Writer {
  public:
    template <class T>
    void field(const T& v) {
        static_assert(std::is_trivially_copyable_v<T>);
        out_.append(reinterpret_cast<const char*>(&v), sizeof(T));
    }
    template <class T>
    void field(const std::vector<T>& v) {
        static_assert(std::is_trivially_copyable_v<T>);
        field(uint64_t(v.size()));
        out_.append(reinterpret_cast<const char*>(v.data()), v.size() * sizeof(T));
    }
    void magic() { out_.append(kMagic, sizeof(kMagic)); }
    void units(const std::vector<std::unique_ptr<UnitOutput>>& units) {
        field(uint64_t(units.size()));
        for (const auto& u : units) unit_fields(*this, *u);
    }
    void grids(const std::unique_ptr<GridSet>& g, GridPlace) {
        field(uint8_t(g != nullptr));
        if (g) grid_set_fields(*this, *g);
    }
    // A voxel travels as its index and its exact fixed-point value (two
    // 64-bit words), so the receiver adds exactly what the sender summed.
    void grid(const VoxelAccumulator& g) {
        const auto voxels = g.sorted_fixed();  // sorted: the bytes do not depend on the hash layout
        field(uint64_t(voxels.size()));
        for (const auto& [c, v] : voxels) {
            field(c);
            fixed(v);
        }
        field(g.dropped());
        fixed(g.dropped_value_fixed());
    }
    void grid_list(const std::vector<VoxelAccumulator>& grids) {
        field(uint64_t(grids.size()));
        for (const auto& a : grids) grid(a);
    }
    std::string take() { return std::move(out_); }

  private:
    void fixed(const Fixed128& f) {
        for (int k = 0; k < 2; ++k) field(f.words()[k]);
    }
    std::string out_;
};

class Reader {
  public:
    // `voxel_size` (0: no grids) and `per_unit` say where the run keeps its grids.
    Reader(const std::string& s, double voxel_size, bool per_unit)
        : s_(s), voxel_size_(voxel_size), per_unit_(per_unit) {}
    template <class T>
    void field(T& v) {
        static_assert(std::is_trivially_copyable_v<T>);
        need(sizeof(T));
        std::memcpy(&v, s_.data() + pos_, sizeof(T));
        pos_ += sizeof(T);
    }
    template <class T>
    void field(std::vector<T>& v) {
        const uint64_t n = get<uint64_t>();
        if (n > (s_.size() - pos_) / sizeof(T)) fail();
        v.resize(n);
        std::memcpy(v.data(), s_.data() + pos_, n * sizeof(T));
        pos_ += n * sizeof(T);
    }
    void magic() {
        need(sizeof(kMagic));
        if (std::memcmp(s_.data() + pos_, kMagic, sizeof(kMagic)) != 0)
            throw std::invalid_argument("unit batch: not an endophoton unit batch of engine " + engine_version() +
                                        " (a worker runs another build?)");
        pos_ += sizeof(kMagic);
    }
    void units(std::vector<std::unique_ptr<UnitOutput>>& units) {
        const uint64_t n = get<uint64_t>();
        if (n > s_.size()) fail();
        for (uint64_t i = 0; i < n; ++i) {
            auto u = std::make_unique<UnitOutput>();
            unit_fields(*this, *u);
            const size_t nrec = u->records.size();
            EscapeRecords::for_each_column(u->records, [&](const auto& col, RecordColumn c) {
                if (col.size() != size_t(c.width) * nrec) fail();
            });
            u->deposit_into(u->own_grids.get());
            units.push_back(std::move(u));
        }
    }
    // Reads a grid set if one follows; the run says whether it needs one
    // here (the message names the mismatch instead of merging wrong grids).
    void grids(std::unique_ptr<GridSet>& g, GridPlace place) {
        const bool expected = voxel_size_ > 0 && per_unit_ == (place == GridPlace::kUnit);
        const bool present = get<uint8_t>() != 0;
        if (present != expected)
            throw std::invalid_argument(std::string("unit batch: ") +
                                        (place == GridPlace::kUnit ? "a unit" : "the chunk") +
                                        (present ? " holds grids, but the run keeps none there"
                                                 : " holds no grids, but the run keeps its grids there") +
                                        " (a worker traced another request?)");
        if (!present) return;
        g = std::make_unique<GridSet>(voxel_size_, 0);
        grid_set_fields(*this, *g);
    }
    void grid(VoxelAccumulator& g) {
        const uint64_t n = get<uint64_t>();
        if (n > s_.size()) fail();
        for (uint64_t i = 0; i < n; ++i) {
            const auto c = get<VoxelAccumulator::Coord>();
            g.add_fixed(c, fixed());
        }
        const uint64_t dropped = get<uint64_t>();
        g.add_dropped(dropped, fixed());
    }
    void grid_list(std::vector<VoxelAccumulator>& grids) {
        const uint64_t n = get<uint64_t>();
        if (n > s_.size()) fail();
        grids.assign(n, VoxelAccumulator(voxel_size_));
        for (auto& a : grids) grid(a);
    }
    bool at_end() const { return pos_ == s_.size(); }
    [[noreturn]] static void fail() { throw std::invalid_argument("unit batch: truncated or corrupt bytes"); }

  private:
    template <class T>
    T get() {
        T v;
        field(v);
        return v;
    }
    Fixed128 fixed() {
        const uint64_t w0 = get<uint64_t>(), w1 = get<uint64_t>();
        return Fixed128::from_words(w0, w1);
    }
    void need(size_t n) const {
        if (n > s_.size() - pos_) fail();
    }
    const std::string& s_;
    double voxel_size_;
    bool per_unit_;
    size_t pos_ = 0;
};

}  // namespace

std::string pack_units(const UnitBatch& batch) {
    Writer w;
    batch_fields(w, batch);
    return w.take();
}

UnitBatch unpack_units(const std::string& bytes, double voxel_size, bool per_unit) {
    Reader r(bytes, voxel_size, per_unit);
    UnitBatch batch;
    batch_fields(r, batch);
    if (!r.at_end()) Reader::fail();
    return batch;
}

}  // namespace ep
