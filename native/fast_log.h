// Natural logarithm for the free path s = -ln(u) / mu_t (seed eq. 2), without a
// libm call and without a division: a table of 128 entries and a polynomial of
// degree 6, about 30 instructions against ~50 for glibc's log. Relative error
// below 1e-15 (bound below; measured 4.4e-16, printed by
// tests/cpp/test_fast_log.cpp), far under any Monte Carlo resolution (1e9
// packets resolve 3e-5 relative).
#pragma once
#include <cstdint>
#include <cstring>

namespace ep {

namespace log_detail {

// x = 2^e z with z in [kOff, 2 kOff), kOff = 0.708984375, and that range cut
// into 128 pieces of equal width in the bits of z (2^45 apart): 74 of width
// 2^-8 below 1 and 53 of width 2^-7 above, and the piece with index 74,
// [1 - 2^-9, 1 + 2^-8), across 1. Each piece is centred (in the bits) on c: c = 1
// exactly for piece 74, and every c has at most 10 significant bits.
constexpr uint64_t kOffBits = 0x3FF0000000000000ULL - 149 * (uint64_t(1) << 44);
constexpr int kPieceShift = 45;

// 32 bytes (a power of two): the entry's address is the piece's bits
// shifted, with no multiplication by 3.
struct alignas(32) Piece {
    double c = 0, inv_c = 0, ln_c = 0;
};

// ln c for c in [0.7, 1.42], at compile time and to about half a unit in the
// last place: 2 atanh(s), s = (c - 1)/(c + 1), |s| <= 0.18 (A&S 4.1.27).
// c - 1 and c + 1 are exact (c has few bits). The rounding error ds of the
// quotient s is recovered exactly (Veltkamp's split of s into halves of 26
// bits, whose products with c + 1 are exact) and enters to first order,
// 2 ds / (1 - s^2); the series beyond 2 s, at most 3 % of the result, is
// summed until its terms fall below 1e-22. So only the last addition rounds
// at full weight.
constexpr double ln_of_short(double c) {
    const double num = c - 1, den = c + 1, s = num / den, z = s * s;
    const double split = s * 134217729.0;  // 2^27 + 1
    const double s_hi = split - (split - s), s_lo = s - s_hi;
    const double ds = ((num - s_hi * den) - s_lo * den) / den;
    double tail = 0, power = z;
    for (int k = 1; k < 40; ++k) {
        tail += power / (2 * k + 1);
        power *= z;
    }
    return 2 * s + (2 * s * tail + 2 * ds / (1 - z));
}

struct PieceTable {
    Piece at[128];
    constexpr PieceTable() {
        for (int i = 0; i < 128; ++i) {
            // The centre's bits, decoded by hand (constexpr cannot memcpy):
            // exponent 2^-1 or 2^0, mantissa m 2^-52.
            const uint64_t bits = kOffBits + (uint64_t(i) << kPieceShift) + (uint64_t(1) << (kPieceShift - 1));
            const double mantissa = 1 + double(bits & ((uint64_t(1) << 52) - 1)) * 0x1.0p-52;
            const double c = (bits >> 52) == 0x3FF ? mantissa : mantissa * 0.5;
            at[i].c = c;
            at[i].inv_c = 1 / c;
            at[i].ln_c = ln_of_short(c);
        }
    }
};
// Internal linkage (no inline): addressed directly, not through the GOT.
constexpr PieceTable kPieces{};

// x = 2^e z split by its bits (see kOffBits): off = bits(x) - kOffBits, so
// e = off >> 52 (arithmetic: it floors) and z's bits are off's low 52 bits
// plus kOffBits; r = (z - c) / c for the piece's centre c, with z - c exact
// (Sterbenz) and the division a product with the tabulated 1/c: r has two
// roundings, |r| <= 2^-8.
struct Reduced {
    int64_t e;
    const Piece* piece;
    double r;
};
inline Reduced reduce_offset(uint64_t off) {
    const Piece& piece = kPieces.at[(off >> kPieceShift) & 127];
    const uint64_t z_bits = (off & ((uint64_t(1) << 52) - 1)) + kOffBits;
    double z;
    std::memcpy(&z, &z_bits, sizeof z);
    return {int64_t(off) >> 52, &piece, (z - piece.c) * piece.inv_c};
}

// ln(1 + r) = r + r^2 q(r) on |r| <= 2^-8, q a Chebyshev fit of degree 4 of
// (ln(1 + r) - r) / r^2 on [-2^-8, 2^-8] (scripts/fit_log1p.py), off by at
// most 3.2e-17 relative to r; q by Estrin's scheme, a shorter dependency
// chain than Horner's.
inline double log1p_small(double r) {
    const double r2 = r * r;
    const double q = (-0.5 + 0.33333333332293896 * r) +
                     r2 * ((-0.24999999999090491 + 0.20000272481609913 * r) + r2 * -0.16666905088156186);
    return r + r2 * q;
}

constexpr double kLn2 = 0.693147180559945309417232121458176568;

}  // namespace log_detail

// ln x for a positive, finite, normal x (the engine's uniforms are >= 2^-53).
// ln x = e ln 2 + ln c + ln(1 + r) (log_detail::reduce_offset, log1p_small).
// The sum rounds a few times, relative to |ln x|: near x = 1 (piece 74, c = 1,
// e = 0) it is r + r^2 q alone, so ln x keeps its relative accuracy there;
// elsewhere |ln x| >= 2e-3 and is at least about half of the largest term.
inline double log_positive(double x) {
    using namespace log_detail;
    uint64_t bits;
    std::memcpy(&bits, &x, sizeof bits);
    const Reduced d = reduce_offset(bits - kOffBits);
    return (double(d.e) * kLn2 + d.piece->ln_c) + log1p_small(d.r);
}

// -ln(m 2^-53) for an integer m in [1, 2^53] (the engine's (0, 1] uniforms,
// Rng::lattice_open_low): bit for bit -log_positive(m * 0x1.0p-53), in fewer
// instructions. m 2^-53 is normal, so its bits are those of double(m) (exact)
// less 53 in the exponent: that subtraction joins kOffBits, in place of a
// multiplication. And the negation is carried into the sum, -(a + b) =
// (-a) - b in round-to-nearest, so no sign flip at the end.
inline double neg_log_lattice(uint64_t m) {
    using namespace log_detail;
    const double dm = double(int64_t(m));
    uint64_t bits;
    std::memcpy(&bits, &dm, sizeof bits);
    const Reduced d = reduce_offset(bits - (kOffBits + (uint64_t(53) << 52)));
    return (double(d.e) * -kLn2 - d.piece->ln_c) - log1p_small(d.r);
}

}  // namespace ep
