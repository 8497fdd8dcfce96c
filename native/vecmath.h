// Small vector algebra for the transport engine.
// Float is the engine's working precision for positions, directions and weights
// (pbrt-v4 convention: one alias, so a float build is one line away).
#pragma once
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>

namespace ep {

using Float = double;
constexpr Float kPi = 3.14159265358979323846;
constexpr Float kInf = std::numeric_limits<Float>::infinity();

struct Vec3 {
    Float x = 0, y = 0, z = 0;
    Vec3() = default;
    constexpr Vec3(Float x_, Float y_, Float z_) : x(x_), y(y_), z(z_) {}
    Float operator[](int i) const { return i == 0 ? x : (i == 1 ? y : z); }
    Vec3 operator+(const Vec3& o) const { return {x + o.x, y + o.y, z + o.z}; }
    Vec3 operator-(const Vec3& o) const { return {x - o.x, y - o.y, z - o.z}; }
    Vec3 operator-() const { return {-x, -y, -z}; }
    Vec3 operator*(Float s) const { return {x * s, y * s, z * s}; }
    Vec3 operator/(Float s) const { return {x / s, y / s, z / s}; }
    Vec3& operator+=(const Vec3& o) {
        x += o.x;
        y += o.y;
        z += o.z;
        return *this;
    }
    Vec3& operator-=(const Vec3& o) {
        x -= o.x;
        y -= o.y;
        z -= o.z;
        return *this;
    }
};

inline Vec3 operator*(Float s, const Vec3& v) { return v * s; }
inline Float dot(const Vec3& a, const Vec3& b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
inline Vec3 cross(const Vec3& a, const Vec3& b) {
    return {a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x};
}
inline Float length(const Vec3& v) { return std::sqrt(dot(v, v)); }
inline Vec3 normalize(const Vec3& v) { return v / length(v); }
inline Float max_abs_component(const Vec3& v) {
    return std::max(std::fabs(v.x), std::max(std::fabs(v.y), std::fabs(v.z)));
}
inline bool is_finite(const Vec3& v) { return std::isfinite(v.x) && std::isfinite(v.y) && std::isfinite(v.z); }

// x < y ? x : y, x > y ? x : y and the square root of an x >= 0, each as one
// SSE2/AVX instruction (minsd and maxsd are defined as exactly these
// selections, sqrtsd is IEEE's correctly rounded root), so the bits are those
// of the plain expressions. Plain code costs more in the hot loop: GCC turns
// a clamp into branches and duplicates the code after it for the clamped
// constants, and std::sqrt tests x < 0 for errno (the build keeps
// math-errno). Inline assembly because the intrinsics' scalar wrappers emit a
// vmovq xmm, xmm that valgrind 3.19 cannot decode.
// kMin: x < y ? x : y (minsd), else x > y ? x : y (maxsd).
template <bool kMin>
inline Float select_sd(Float x, Float y) {
#if defined(__AVX__)
    if constexpr (kMin)
        asm("vminsd %2, %1, %0" : "=x"(x) : "x"(x), "xm"(y));
    else
        asm("vmaxsd %2, %1, %0" : "=x"(x) : "x"(x), "xm"(y));
#elif defined(__SSE2__)
    if constexpr (kMin)
        asm("minsd %1, %0" : "+x"(x) : "xm"(y));
    else
        asm("maxsd %1, %0" : "+x"(x) : "xm"(y));
#else
    x = kMin ? (x < y ? x : y) : (x > y ? x : y);
#endif
    return x;
}
inline Float min_select(Float x, Float y) { return select_sd<true>(x, y); }
inline Float max_select(Float x, Float y) { return select_sd<false>(x, y); }
inline Float sqrt_nonneg(Float x) {
#if defined(__AVX__)
    asm("vsqrtsd %1, %1, %0" : "=x"(x) : "x"(x));
#elif defined(__SSE2__)
    asm("sqrtsd %0, %0" : "+x"(x));
#else
    x = std::sqrt(x);
#endif
    return x;
}

// Orthonormal basis around a unit vector n (Duff et al. 2017, "Building an
// orthonormal basis, revisited"): branch-free and stable for every n, including
// n = (0,0,-1) where the classic Frisvad form divides by zero.
inline void orthonormal_basis(const Vec3& n, Vec3* t, Vec3* b) {
    const Float sign = std::copysign(Float(1), n.z);
    const Float a = Float(-1) / (sign + n.z);
    const Float c = n.x * n.y * a;
    *t = Vec3(1 + sign * n.x * n.x * a, sign * c, -sign * n.x);
    *b = Vec3(c, sign + n.y * n.y * a, -n.y);
}

// Direction with polar cosine cos_theta and azimuth phi about the axis n.
inline Vec3 spherical_about(const Vec3& n, Float cos_theta, Float sin_phi, Float cos_phi) {
    Vec3 t, b;
    orthonormal_basis(n, &t, &b);
    const Float sin_theta = std::sqrt(std::max(Float(0), 1 - cos_theta * cos_theta));
    const Vec3 d = t * (sin_theta * cos_phi) + b * (sin_theta * sin_phi) + n * cos_theta;
    // Renormalise so that rounding does not accumulate over hundreds of
    // scatterings. |d|^2 = 1 + e with e a few ulps, so one Newton step for
    // 1/sqrt(x) at x = 1, d (3 - |d|^2) / 2, leaves |d| = 1 + O(e^2): exact to
    // rounding, without the square root and division of d / |d|.
    return d * (Float(1.5) - Float(0.5) * dot(d, d));
}

// Four doubles in one SIMD value (a GCC/Clang vector extension: one AVX
// register, or two SSE2 ones), a Vec3 in lanes 0-2. Lane-wise + - * are the
// scalar IEEE operations (no contraction: the build uses -ffp-contract=off),
// so a computation in Lanes4 gives the bits of the same computation in Vec3.
// Lane 3 repeats z and is never read: filling it with z instead of 0 spares
// a vmovq that valgrind 3.19 cannot decode (callgrind profiles the engine),
// and the rotations of DirectionFrame keep it bounded like the other lanes.
typedef Float Lanes4 __attribute__((vector_size(4 * sizeof(Float))));
inline Lanes4 to_lanes(const Vec3& v) { return Lanes4{v.x, v.y, v.z, v.z}; }
inline Vec3 to_vec3(const Lanes4& v) { return {v[0], v[1], v[2]}; }

// A unit direction n with unit vectors t, b completing a right-handed
// orthonormal frame, carried from one scattering to the next. A scattering
// turns it by the polar angle theta at azimuth phi measured from t: with
// e1 = cos(phi) t + sin(phi) b and e2 = cos(phi) b - sin(phi) t (the frame
// turned by phi about n), the rotation by theta about e2 takes n to
// cos(theta) n + sin(theta) e1 and e1 to cos(theta) e1 - sin(theta) n. Its
// only dependence on the last direction is a few products and sums (about 12
// cycles of latency), against ~66 for building a basis from n (a division) and
// renormalising the result at every scattering (spherical_about). Any frame
// about n gives the same distribution of directions, since phi is uniform and
// independent of it.
struct DirectionFrame {
    // Orthonormality is restored every this many scatterings (HenyeyGreenstein::scatter).
    static constexpr uint32_t kRenormalizeEvery = 16;
    // t, b, n in Lanes4 (turn() is then 12 vector operations instead of 36
    // scalar ones; callgrind, seed tissue: 271 -> 248 instructions per
    // interaction), with the same IEEE operations per lane as Vec3 arithmetic.
    Lanes4 t{}, b{}, n{};

    DirectionFrame() = default;
    // The frame of orthonormal_basis about the unit vector dir.
    __attribute__((always_inline)) explicit DirectionFrame(const Vec3& dir) : n(to_lanes(dir)) {
        Vec3 t3, b3;
        orthonormal_basis(dir, &t3, &b3);
        t = to_lanes(t3);
        b = to_lanes(b3);
    }
    Vec3 dir() const { return to_vec3(n); }
    Vec3 tangent() const { return to_vec3(t); }
    Vec3 bitangent() const { return to_vec3(b); }
    // True when this frame is about dir, bit for bit (the frame is then valid for it).
    bool about(const Vec3& d) const { return n[0] == d.x && n[1] == d.y && n[2] == d.z; }

    void turn(Float cos_theta, Float sin_theta, Float cos_phi, Float sin_phi) {
        const Lanes4 e1 = t * cos_phi + b * sin_phi;
        b = b * cos_phi - t * sin_phi;
        t = e1 * cos_theta - n * sin_theta;
        n = n * cos_theta + e1 * sin_theta;
    }
    // Each turn moves |n|, |t|, |b| and their dot products by a few roundings
    // (the rotation coefficients are unit to rounding), so the drift grows at
    // most linearly. One Newton step for 1/sqrt(x) at x = |n|^2 = 1 + e,
    // n (3 - |n|^2) / 2, leaves |n| = 1 + O(e^2); t, b are rebuilt about it.
    void renormalize() {
        Vec3 d = dir();
        d = d * (Float(1.5) - Float(0.5) * dot(d, d));
        *this = DirectionFrame(d);
    }
};

}  // namespace ep
