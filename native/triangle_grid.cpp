#include "triangle_grid.h"

#include <algorithm>
#include <cmath>
#include <limits>

namespace ep {

namespace {

Vec3 vertex(const std::vector<float>& v, uint32_t i) {
    return Vec3(v[3 * size_t(i)], v[3 * size_t(i) + 1], v[3 * size_t(i) + 2]);
}

}  // namespace

bool TriangleGrid::cell_range(const Vec3& lo, const Vec3& hi, int a[3], int b[3]) const {
    if (res_[0] == 0) return false;
    for (int k = 0; k < 3; ++k) {
        const Float l = (lo[k] - origin_[k]) * inv_cell_, h = (hi[k] - origin_[k]) * inv_cell_;
        // Every triangle lies in [origin, origin + res cell] (bounds padded by
        // the margin), so a box beyond it meets none.
        if (!(h >= 0) || !(l <= Float(res_[k]))) return false;
        // Indices are clamped the same way at registration and here: floor and
        // clamp are monotone, so overlapping intervals keep overlapping ranges.
        // (l <= res and h >= 0 here, so a non-negative l and an h below res
        // truncate to their floor, as in cube_of: no floor call.)
        const int top = res_[k] - 1;
        a[k] = l > 0 ? std::min(int(l), top) : 0;
        b[k] = h < Float(res_[k]) ? int(h) : top;
    }
    return true;
}

void TriangleGrid::build(const std::vector<std::vector<float>>& vertices,
                         const std::vector<std::vector<uint32_t>>& triangles) {
    Vec3 lo(kInf, kInf, kInf), hi(-kInf, -kInf, -kInf);
    triangle_count_ = 0;
    region_start_.assign(1, 0);
    for (size_t r = 0; r < vertices.size(); ++r) {
        triangle_count_ += triangles[r].size() / 3;
        region_start_.push_back(uint32_t(triangle_count_));
        for (size_t i = 0; i < vertices[r].size() / 3; ++i) {
            const Vec3 p = vertex(vertices[r], uint32_t(i));
            lo = Vec3(std::min(lo.x, p.x), std::min(lo.y, p.y), std::min(lo.z, p.z));
            hi = Vec3(std::max(hi.x, p.x), std::max(hi.y, p.y), std::max(hi.z, p.z));
        }
    }
    start_.clear();
    refs_.clear();
    res_[0] = res_[1] = res_[2] = 0;
    if (triangle_count_ == 0) return;
    const Float side = std::max({hi.x - lo.x, hi.y - lo.y, hi.z - lo.z});
    // Rounding room scaled to the coordinates' magnitude (pbrt-v4 practice),
    // so far-away scenes (1e6 cm offsets) keep a conservative superset.
    margin_ = 1e-9 * (std::max(max_abs_component(lo), max_abs_component(hi)) + side) + 1e-300;
    // ceil(3 cbrt(count)) cells a side, in integers: the least n with n^3 >= 27 count (no libm, whose
    // cbrt may round a perfect cube's root either way: det_math.h).
    int n = 1;
    while (n < kMaxRes && uint64_t(n) * uint64_t(n) * uint64_t(n) < 27 * uint64_t(triangle_count_)) ++n;
    cell_ = side > 0 ? (side + 2 * margin_) / n : 1;
    inv_cell_ = 1 / cell_;
    origin_ = lo - Vec3(margin_, margin_, margin_);
    for (int k = 0; k < 3; ++k)
        res_[k] = std::clamp(int(std::ceil((hi[k] - lo[k] + 2 * margin_) * inv_cell_)), 1, kMaxRes);
    const size_t cells = size_t(res_[0]) * size_t(res_[1]) * size_t(res_[2]);

    // Two passes (count, then fill) over the cells each triangle meets: its
    // padded bounding box, then its plane against the cell's box.
    std::vector<uint32_t> count(cells + 1, 0);
    auto each_cell = [&](const Vec3& a, const Vec3& b, const Vec3& c, auto&& f) {
        const Vec3 m(margin_, margin_, margin_);
        const Vec3 tlo = Vec3(std::min({a.x, b.x, c.x}), std::min({a.y, b.y, c.y}), std::min({a.z, b.z, c.z})) - m;
        const Vec3 thi = Vec3(std::max({a.x, b.x, c.x}), std::max({a.y, b.y, c.y}), std::max({a.z, b.z, c.z})) + m;
        int ca[3], cb[3];
        if (!cell_range(tlo, thi, ca, cb)) return;
        const Vec3 nrm = cross(b - a, c - a);
        const Float len = length(nrm);
        const Vec3 u = len > 0 ? nrm / len : Vec3(0, 0, 0);
        const Float half = 0.5 * cell_ * (std::fabs(u.x) + std::fabs(u.y) + std::fabs(u.z)) + 2 * margin_;
        for (int z = ca[2]; z <= cb[2]; ++z)
            for (int y = ca[1]; y <= cb[1]; ++y)
                for (int x = ca[0]; x <= cb[0]; ++x) {
                    const Vec3 centre = origin_ + Vec3(x + 0.5, y + 0.5, z + 0.5) * cell_;
                    if (len > 0 && std::fabs(dot(u, centre - a)) > half) continue;  // plane misses the cell
                    f((size_t(z) * size_t(res_[1]) + size_t(y)) * size_t(res_[0]) + size_t(x));
                }
    };
    auto each_triangle = [&](auto&& f) {
        uint32_t id = 0;
        for (size_t r = 0; r < vertices.size(); ++r)
            for (size_t i = 0; i < triangles[r].size() / 3; ++i, ++id) {
                const uint32_t* t = &triangles[r][3 * i];
                const Vec3 a = vertex(vertices[r], t[0]), b = vertex(vertices[r], t[1]), c = vertex(vertices[r], t[2]);
                // Bounding sphere about the centroid rounded to float (then
                // exact in double), padded by the margin; its reach rounded
                // up to float.
                const Vec3 m0 = (a + b + c) / 3;
                const float mf[3] = {float(m0.x), float(m0.y), float(m0.z)};
                const Vec3 m(mf[0], mf[1], mf[2]);
                const Float reach = std::max({length(a - m), length(b - m), length(c - m)}) * (1 + 1e-9) + margin_;
                float rf = float(reach);
                if (Float(rf) < reach) rf = std::nextafter(rf, std::numeric_limits<float>::infinity());
                const Ref ref{{mf[0], mf[1], mf[2]}, rf, id};
                each_cell(a, b, c, [&](size_t cell) { f(cell, ref); });
            }
    };
    each_triangle([&](size_t cell, const Ref&) { ++count[cell + 1]; });
    for (size_t c = 0; c < cells; ++c) count[c + 1] += count[c];
    start_ = count;
    refs_.resize(start_.back());
    each_triangle([&](size_t cell, const Ref& ref) { refs_[count[cell]++] = ref; });
}

}  // namespace ep
