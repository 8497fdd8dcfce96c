// A uniform grid of triangle lists over the scene's bounding box (issue 11).
// The local triangle cache (triangle_cache.h) re-gathers the triangles that
// meet a ball around the packet whenever the packet leaves the ball. Through
// Embree's BVH (rtcPointQuery) that gather costs a traversal from the root and
// a callback per candidate, ~8.7k instructions on the 15k-triangle colon, as
// much as a dozen steps. Through this grid it costs the few cells the ball's
// bounding box overlaps, O(local), whatever the scene's triangle count.
//
// A cell lists every triangle whose bounding box and plane meet the cell (a
// conservative superset: the caller applies the exact ball test). A triangle
// spanning several cells appears in each, so visits repeat and the caller
// deduplicates (TriangleCache keeps a per-thread mailbox).
#pragma once
#include <cmath>
#include <cstdint>
#include <vector>

#include "vecmath.h"

namespace ep {

class TriangleGrid {
  public:
    // A listing: 20 bytes, so that a gather's walk over the cells' lists
    // reads few cache lines (48 bytes with a double sphere, region and prim:
    // callgrind, colon at 30,000 packets, a cube build missed the last level
    // ~9 times a gather, mostly on the lists). The sphere is float, its
    // centre exact in double and its reach rounded up, so it still bounds
    // the triangle.
    struct Ref {
        float c[3];   // bounding sphere of the triangle (padded for rounding):
        float reach;  // a ball farther than `reach` from `centre()` misses it
        uint32_t id;  // scene-wide triangle index (mailbox slot)
        Vec3 centre() const { return Vec3(c[0], c[1], c[2]); }
    };

    // Builds the lists from per-region float (x, y, z) vertices and uint32
    // (a, b, c) triangles. Resolution: the pbrt-v1 grid rule, 3 cbrt(N)
    // cells along the longest side, at most kMaxRes per axis, cubic cells.
    void build(const std::vector<std::vector<float>>& vertices, const std::vector<std::vector<uint32_t>>& triangles);

    // Calls f(const Ref&) for every triangle listed in a cell that meets the
    // box [lo, hi] (a triangle spanning several cells comes once per cell);
    // stops when f returns false.
    template <class F>
    void visit(const Vec3& lo, const Vec3& hi, F&& f) const {
        int a[3], b[3];
        if (!cell_range(lo, hi, a, b)) return;
        for (int z = a[2]; z <= b[2]; ++z)
            for (int y = a[1]; y <= b[1]; ++y) {
                const size_t row = (size_t(z) * size_t(res_[1]) + size_t(y)) * size_t(res_[0]);
                const uint32_t* s = &start_[row + size_t(a[0])];
                for (uint32_t k = s[0], e = s[b[0] - a[0] + 1]; k < e; ++k)
                    if (!f(refs_[k])) return;
            }
    }

    // The cube holding p when every cell is split into kSplit^3 cubes: the
    // cell's index, the cube's index in the cell ((z kSplit + y) kSplit + x)
    // and the cube's centre; false outside the grid. One conversion per axis
    // on the grid of cubes (a coordinate in [0, res kSplit) truncates to its
    // floor, so no floor call), the cell and the cube in it by unsigned
    // division (a multiply and a shift).
    template <int kSplit>
    bool cube_of(const Vec3& p, size_t* cell, int* cube, Vec3* centre) const {
        if (res_[0] == 0) return false;
        const Float inv_side = inv_cell_ * kSplit;
        unsigned q[3], c[3], k[3];
        for (int a = 0; a < 3; ++a) {
            const Float f = (p[a] - origin_[a]) * inv_side;
            if (!(f >= 0 && f < Float(res_[a] * kSplit))) return false;
            q[a] = unsigned(f);
            c[a] = q[a] / unsigned(kSplit);
            k[a] = q[a] - c[a] * unsigned(kSplit);
        }
        *cell = (size_t(c[2]) * size_t(res_[1]) + size_t(c[1])) * size_t(res_[0]) + size_t(c[0]);
        *cube = int((k[2] * kSplit + k[1]) * kSplit + k[0]);
        *centre = origin_ + Vec3(q[0] + Float(0.5), q[1] + Float(0.5), q[2] + Float(0.5)) * (cell_ / kSplit);
        return true;
    }

    // The region and the index in it of scene-wide triangle `id` (ids run
    // region by region, in the order build() took them).
    uint32_t region_of(uint32_t id) const {
        uint32_t r = 0;
        while (r + 1 < region_start_.size() && region_start_[r + 1] <= id) ++r;
        return r;
    }
    uint32_t prim_of(uint32_t id, uint32_t region) const { return id - region_start_[region]; }
    // Whether triangle `id` belongs to `region` (a range test, no search).
    bool in_region(uint32_t id, uint32_t region) const {
        return id - region_start_[region] < region_start_[region + 1] - region_start_[region];
    }

    size_t triangle_count() const { return triangle_count_; }
    size_t cell_count() const { return start_.empty() ? 0 : start_.size() - 1; }
    size_t ref_count() const { return refs_.size(); }
    Float cell_size() const { return cell_; }

    static constexpr int kMaxRes = 128;

  private:
    // Cells [a, b] (inclusive, per axis) meeting the box [lo, hi]; false when
    // the box misses the grid.
    bool cell_range(const Vec3& lo, const Vec3& hi, int a[3], int b[3]) const;

    Vec3 origin_;
    Float cell_ = 1, inv_cell_ = 1, margin_ = 0;
    int res_[3] = {0, 0, 0};
    size_t triangle_count_ = 0;
    std::vector<uint32_t> region_start_;  // scene-wide id of each region's first triangle, then the count
    std::vector<uint32_t> start_;         // CSR: cell c lists refs_[start_[c], start_[c + 1])
    std::vector<Ref> refs_;
};

}  // namespace ep
