// Meshes shared by the C++ tests.
#pragma once
#include <cstdint>
#include <vector>

#include "medium.h"

// A scattering test medium: mua 1, mus 10 cm^-1, g 0, n 1 (optics do not matter to geometry tests).
inline ep::Medium plain_medium() {
    ep::Medium m;
    m.mua = 1;
    m.mus = 10;
    return m;
}

// An axis-aligned box, 8 vertices and 12 triangles, CCW seen from outside.
inline void box(float x0, float y0, float z0, float x1, float y1, float z1, std::vector<float>& v,
                std::vector<uint32_t>& t) {
    v.clear();
    for (int k = 0; k < 8; ++k) {
        v.push_back(k & 1 ? x1 : x0);
        v.push_back(k & 2 ? y1 : y0);
        v.push_back(k & 4 ? z1 : z0);
    }
    const uint32_t q[6][4] = {{0, 2, 3, 1}, {4, 5, 7, 6}, {0, 1, 5, 4}, {2, 6, 7, 3}, {0, 4, 6, 2}, {1, 3, 7, 5}};
    t.clear();
    for (auto& f : q) {
        t.insert(t.end(), {f[0], f[1], f[2]});
        t.insert(t.end(), {f[0], f[2], f[3]});
    }
}
