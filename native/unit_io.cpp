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
constexpr char kMagic[8] = {'E', 'P', 'U', 'N', 'I', 'T', '0', '4'};

class Writer {
  public:
    template <class T>
    void put(const T& v) {
        static_assert(std::is_trivially_copyable_v<T>);
        out_.append(reinterpret_cast<const char*>(&v), sizeof(T));
    }
    template <class T>
    void put_vec(const std::vector<T>& v) {
        put(uint64_t(v.size()));
        out_.append(reinterpret_cast<const char*>(v.data()), v.size() * sizeof(T));
    }
    void put_raw(const char* p, size_t n) { out_.append(p, n); }
    std::string take() { return std::move(out_); }

  private:
    std::string out_;
};

class Reader {
  public:
    explicit Reader(const std::string& s) : s_(s) {}
    template <class T>
    T get() {
        T v;
        need(sizeof(T));
        std::memcpy(&v, s_.data() + pos_, sizeof(T));
        pos_ += sizeof(T);
        return v;
    }
    template <class T>
    void get_into(T& v) {  // a fixed-size array
        need(sizeof(T));
        std::memcpy(&v, s_.data() + pos_, sizeof(T));
        pos_ += sizeof(T);
    }
    template <class T>
    void get_vec(std::vector<T>& v) {
        const uint64_t n = get<uint64_t>();
        if (n > (s_.size() - pos_) / sizeof(T)) fail();
        v.resize(n);
        std::memcpy(v.data(), s_.data() + pos_, n * sizeof(T));
        pos_ += n * sizeof(T);
    }
    void expect_raw(const char* p, size_t n) {
        need(n);
        if (std::memcmp(s_.data() + pos_, p, n) != 0)
            throw std::invalid_argument("unit batch: not an endophoton unit batch of engine " + engine_version() +
                                        " (a worker runs another build?)");
        pos_ += n;
    }
    bool at_end() const { return pos_ == s_.size(); }
    [[noreturn]] static void fail() { throw std::invalid_argument("unit batch: truncated or corrupt bytes"); }

  private:
    void need(size_t n) const {
        if (n > s_.size() - pos_) fail();
    }
    const std::string& s_;
    size_t pos_ = 0;
};

// A voxel travels as its index and its exact fixed-point value (three 64-bit
// words), so the receiver adds exactly what the sender summed.
void put_fixed(Writer& w, const Fixed192& f) {
    for (int k = 0; k < 3; ++k) w.put(f.words()[k]);
}

Fixed192 get_fixed(Reader& r) {
    const uint64_t w0 = r.get<uint64_t>(), w1 = r.get<uint64_t>(), w2 = r.get<uint64_t>();
    return Fixed192::from_words(w0, w1, w2);
}

void put_grid(Writer& w, const VoxelAccumulator& g) {
    const auto voxels = g.sorted_fixed();  // sorted: the bytes do not depend on the hash layout
    w.put(uint64_t(voxels.size()));
    for (const auto& [c, v] : voxels) {
        w.put(c);
        put_fixed(w, v);
    }
    w.put(g.dropped());
    put_fixed(w, g.dropped_value_fixed());
}

void get_grid(Reader& r, VoxelAccumulator& g, uint64_t max_voxels) {
    const uint64_t n = r.get<uint64_t>();
    if (n > max_voxels) Reader::fail();
    for (uint64_t i = 0; i < n; ++i) {
        const auto c = r.get<VoxelAccumulator::Coord>();
        g.add_fixed(c, get_fixed(r));
    }
    const uint64_t dropped = r.get<uint64_t>();
    g.add_dropped(dropped, get_fixed(r));
}

void put_grids(Writer& w, const GridSet* g) {
    w.put(uint8_t(g != nullptr));
    if (!g) return;
    w.put(g->packets);
    put_grid(w, g->absorbed);
    put_grid(w, g->fluorescence);
    w.put(uint64_t(g->per_fluorophore.size()));
    for (const auto& a : g->per_fluorophore) put_grid(w, a);
    w.put(uint64_t(g->emission.size()));
    for (const auto& a : g->emission) put_grid(w, a);
}

// Reads a grid set if one follows; `expected` says whether the run needs one
// here (the message names the mismatch instead of merging wrong grids).
std::unique_ptr<GridSet> get_grids(Reader& r, double voxel_size, bool expected, uint64_t max_items, const char* where) {
    const bool present = r.get<uint8_t>() != 0;
    if (present != expected)
        throw std::invalid_argument(std::string("unit batch: ") + where +
                                    (present ? " holds grids, but the run keeps none there"
                                             : " holds no grids, but the run keeps its grids there") +
                                    " (a worker traced another request?)");
    if (!present) return nullptr;
    const uint64_t packets = r.get<uint64_t>();
    auto g = std::make_unique<GridSet>(voxel_size, 0);
    g->packets = packets;
    get_grid(r, g->absorbed, max_items);
    get_grid(r, g->fluorescence, max_items);
    const uint64_t nf = r.get<uint64_t>();
    if (nf > max_items) Reader::fail();
    g->per_fluorophore.assign(nf, VoxelAccumulator(voxel_size));
    for (auto& a : g->per_fluorophore) get_grid(r, a, max_items);
    const uint64_t ne = r.get<uint64_t>();
    if (ne > max_items) Reader::fail();
    g->emission.assign(ne, VoxelAccumulator(voxel_size));
    for (auto& a : g->emission) get_grid(r, a, max_items);
    return g;
}

}  // namespace

std::string pack_units(const UnitBatch& batch) {
    Writer w;
    w.put_raw(kMagic, sizeof(kMagic));
    w.put(batch.first_unit);
    w.put(uint64_t(batch.units.size()));
    for (const auto& u : batch.units) {
        w.put(u->first_packet);
        const UnitTally& t = u->tally;
        w.put(t.packets);
        w.put(t.capped_packets);
        w.put(t.scalar);
        w.put(t.energy);
        w.put_vec(t.absorbed_by_region);
        w.put_vec(t.emitted_by_fluorophore);
        w.put(t.scalar_m);
        w.put(t.energy_m);
        w.put_vec(t.absorbed_by_region_m);
        w.put_vec(t.emitted_by_fluorophore_m);
        EscapeRecords::for_each_column(u->records, [&](const auto& col) { w.put_vec(col); });
        put_grids(w, u->own_grids.get());
    }
    put_grids(w, batch.grids.get());  // the chunk's grids: its units' deposits summed
    return w.take();
}

UnitBatch unpack_units(const std::string& bytes, double voxel_size, bool per_unit) {
    Reader r(bytes);
    r.expect_raw(kMagic, sizeof(kMagic));
    UnitBatch batch;
    batch.first_unit = r.get<uint64_t>();
    const uint64_t n = r.get<uint64_t>();
    if (n > bytes.size()) Reader::fail();
    for (uint64_t i = 0; i < n; ++i) {
        auto u = std::make_unique<UnitOutput>();
        u->first_packet = r.get<uint64_t>();
        UnitTally& t = u->tally;
        t.packets = r.get<uint64_t>();
        t.capped_packets = r.get<uint64_t>();
        r.get_into(t.scalar);
        r.get_into(t.energy);
        r.get_vec(t.absorbed_by_region);
        r.get_vec(t.emitted_by_fluorophore);
        r.get_into(t.scalar_m);
        r.get_into(t.energy_m);
        r.get_vec(t.absorbed_by_region_m);
        r.get_vec(t.emitted_by_fluorophore_m);
        EscapeRecords::for_each_column(u->records, [&](auto& col) { r.get_vec(col); });
        const size_t nrec = u->records.weight.size();
        EscapeRecords::for_each_column(u->records, [&](const auto& col) {
            if (col.size() != nrec && col.size() != 3 * nrec) Reader::fail();
        });
        u->own_grids = get_grids(r, voxel_size, voxel_size > 0 && per_unit, bytes.size(), "a unit");
        u->deposit_into(u->own_grids.get());
        batch.units.push_back(std::move(u));
    }
    batch.grids = get_grids(r, voxel_size, voxel_size > 0 && !per_unit, bytes.size(), "the chunk");
    if (!r.at_end()) Reader::fail();
    return batch;
}

}  // namespace ep
