#include "surface_hits.h"

#include <algorithm>
#include <thread>
#include <vector>

namespace ep {

SurfaceHit first_surface(const Scene& scene, const Vec3& o, const Vec3& d_in, Float tnear, Float tfar) {
    SurfaceHit out;
    const Float len = length(d_in);
    if (!(len > 0) || !is_finite(o)) return out;
    const Vec3 d = d_in / len;
    std::vector<Hit> hits;
    scene.intersect_all(o, d, tnear, tfar, hits);
    // Coincident crossings (touching regions) differ only by rounding: group
    // them with a tolerance scaled to the coordinates (pbrt-style offsets).
    const Float scale = max_abs_component(o) + scene.extent();
    uint64_t inside = 0;
    size_t i = 0;
    while (i < hits.size()) {
        const Float t0 = hits[i].t;
        const Float tol = 1e-6 * (scale + std::fabs(t0));
        size_t j = i;
        bool entered = false;
        for (; j < hits.size() && hits[j].t - t0 <= tol; ++j) {
            const uint64_t bit = uint64_t(1) << hits[j].region;
            if (hits[j].cos_dn < 0) {
                inside |= bit;
                entered = true;
            } else if (inside & bit) {
                inside &= ~bit;
            } else if (!entered && inside == 0) {
                out.region = kStartsInside;  // leaves a region it never entered: started inside
                out.t = t0;
                return out;
            }
        }
        if (inside != 0) {
            const int top = scene.top(inside);
            out.t = t0;
            out.region = top;
            for (size_t k = i; k < j; ++k)  // the entered triangle of the top region
                if (int(hits[k].region) == top && hits[k].cos_dn < 0) {
                    out.prim = int32_t(hits[k].prim);
                    out.normal = scene.region(size_t(top)).normals[hits[k].prim];
                }
            return out;
        }
        i = j;
    }
    return out;
}

void first_surfaces(const Scene& scene, const double* org, const double* dir, const double* tfar, size_t n, Float tnear,
                    int threads, double* t_out, int32_t* region_out, int32_t* prim_out, double* normal_out) {
    auto work = [&](size_t lo, size_t hi) {
        for (size_t k = lo; k < hi; ++k) {
            const Vec3 o(org[3 * k], org[3 * k + 1], org[3 * k + 2]);
            const Vec3 d(dir[3 * k], dir[3 * k + 1], dir[3 * k + 2]);
            const SurfaceHit h = first_surface(scene, o, d, tnear, tfar ? tfar[k] : kInf);
            t_out[k] = h.t;
            region_out[k] = h.region;
            prim_out[k] = h.prim;
            normal_out[3 * k] = h.normal.x;
            normal_out[3 * k + 1] = h.normal.y;
            normal_out[3 * k + 2] = h.normal.z;
        }
    };
    size_t nt = threads > 0 ? size_t(threads) : std::max(1u, std::thread::hardware_concurrency());
    nt = std::max<size_t>(1, std::min(nt, n / 256 + 1));
    if (nt == 1) {
        work(0, n);
        return;
    }
    std::vector<std::thread> pool;
    for (size_t w = 0; w < nt; ++w) pool.emplace_back(work, n * w / nt, n * (w + 1) / nt);
    for (auto& th : pool) th.join();
}

}  // namespace ep
