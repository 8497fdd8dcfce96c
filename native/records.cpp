#include "records.h"

#include <algorithm>

namespace ep {

namespace {
// One value of an EscapeRecord onto its column: a vector as its three components.
template <class T>
void push_value(std::vector<T>& column, const Vec3& p) {
    column.push_back(T(p.x));
    column.push_back(T(p.y));
    column.push_back(T(p.z));
}
template <class T, class V>
void push_value(std::vector<T>& column, const V& v) {
    column.push_back(T(v));
}
template <class T>
void append_n(std::vector<T>& dst, const std::vector<T>& src, size_t n) {
    dst.insert(dst.end(), src.begin(), src.begin() + std::ptrdiff_t(n));
}
}  // namespace

void EscapeRecords::push(const EscapeRecord& r) {
#define EP_PUSH_COLUMN(column, member, type, width) push_value(column, r.member);
    EP_RECORD_COLUMNS(EP_PUSH_COLUMN)
#undef EP_PUSH_COLUMN
}

void EscapeRecords::append(const EscapeRecords& o, size_t count) {
    const size_t n = std::min(count, o.size());
    if (n == 0) return;
    zip_columns(*this, o, [&](auto& dst, const auto& src) { append_n(dst, src, src.size() / o.size() * n); });
}

void EscapeRecords::clear() { *this = EscapeRecords(); }

size_t EscapeRecords::memory_bytes() const {
    constexpr size_t kBytesPerRecord = 0
#define EP_COLUMN_BYTES(column, member, type, width) +width * sizeof(type)
        EP_RECORD_COLUMNS(EP_COLUMN_BYTES)
#undef EP_COLUMN_BYTES
        ;
    return size() * kBytesPerRecord;
}

}  // namespace ep
