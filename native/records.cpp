#include "records.h"

#include <algorithm>

namespace ep {

namespace {
void push3(std::vector<float>& v, const Vec3& p) {
    v.push_back(float(p.x));
    v.push_back(float(p.y));
    v.push_back(float(p.z));
}
template <class T>
void append_n(std::vector<T>& dst, const std::vector<T>& src, size_t n) {
    dst.insert(dst.end(), src.begin(), src.begin() + std::ptrdiff_t(n));
}
}  // namespace

void EscapeRecords::push(const EscapeRecord& r) {
    push3(position, r.position);
    push3(direction, r.direction);
    push3(normal, r.normal);
    push3(entry, r.entry);
    weight.push_back(r.weight);
    energy.push_back(r.energy);
    wavelength.push_back(float(r.wavelength));
    max_depth.push_back(float(r.max_depth_cm));
    fluorescent.push_back(r.fluorescent);
    light.push_back(r.light);
    kind.push_back(r.kind);
    fluorophore.push_back(r.fluorophore);
    region.push_back(r.region);
    scatterings.push_back(r.scatterings);
    packet.push_back(r.packet);
    exit_order.push_back(r.exit_order);
    next_hit.push_back(r.next_hit);
}

void EscapeRecords::append(const EscapeRecords& o, size_t count) {
    const size_t n = std::min(count, o.size());
    if (n == 0) return;
    // Each column holds size() * width values (width 3 for vectors, else 1).
    zip_columns(*this, o, [&](auto& dst, const auto& src) { append_n(dst, src, src.size() / o.size() * n); });
}

void EscapeRecords::clear() { *this = EscapeRecords(); }

size_t EscapeRecords::memory_bytes() const {
    return size() * (12 * sizeof(float) + 2 * sizeof(double) + 2 * sizeof(float) + 3 + 2 * sizeof(int32_t) +
                     2 * sizeof(uint32_t) + sizeof(uint64_t) + 1);
}

}  // namespace ep
