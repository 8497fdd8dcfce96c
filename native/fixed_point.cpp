#include "fixed_point.h"

#include <cmath>
#include <cstring>

namespace ep {

namespace {

// Two's-complement negation of n words in place.
void negate(uint64_t* w, int n) {
    uint64_t carry = 1;
    for (int i = 0; i < n; ++i) {
        w[i] = ~w[i] + carry;
        carry = carry && w[i] == 0;
    }
}

}  // namespace

bool Fixed128::from_double_general(double v, Fixed128& out) {
    if (!std::isfinite(v) || std::fabs(v) >= 0x1p47) return false;
    uint64_t w[2] = {0, 0};
    if (v != 0) {
        // |v| = m 2^e with m in [0.5, 1): |v| = mant 2^(e - 53) with the
        // integer mant = m 2^53 (exact, subnormals included), which is
        // mant 2^s in units of the last bit.
        int e = 0;
        const double m = std::frexp(std::fabs(v), &e);
        const uint64_t mant = uint64_t(std::ldexp(m, 53));
        const int s = e - 53 + kFracBits;
        if (s >= 0) {
            // |v| < 2^47 gives e <= 47, s <= 74: the shifted significand
            // stays below 2^127 (no bit lost, sign clear).
            const unsigned __int128 t = static_cast<unsigned __int128>(mant) << s;
            w[0] = uint64_t(t);
            w[1] = uint64_t(t >> 64);
        } else if (-s < 64) {
            // Below 2^-28: round mant 2^s to an integer, to nearest, ties to even.
            const int k = -s;
            const uint64_t q = mant >> k, rem = mant & ((uint64_t(1) << k) - 1), half = uint64_t(1) << (k - 1);
            w[0] = q + uint64_t(rem > half || (rem == half && (q & 1)));
        }
        // -s >= 64: mant < 2^53 makes |v| < 2^-11 of the last bit: rounds to 0.
        if (v < 0) negate(w, 2);
    }
    out.w_[0] = w[0];
    out.w_[1] = w[1];
    return true;
}

double Fixed128::words_to_double(const uint64_t* w_in, int n) {
    uint64_t w[4];
    if (n < 1 || n > 4) return 0;  // not reached: callers pass 2 or 3 words
    for (int i = 0; i < n; ++i) w[i] = w_in[i];
    const bool neg = int64_t(w[n - 1]) < 0;
    if (neg) negate(w, n);  // the magnitude, read as unsigned (covers -2^(64 n - 1))
    int top = n - 1;
    while (top >= 0 && w[top] == 0) --top;
    if (top < 0) return 0.0;
    // Bit position of the leading 1 counted from bit 0 of word 0.
    const int lead = 64 * top + 63 - __builtin_clzll(w[top]);
    // The 63 bits from the leading one down, with every bit below them folded
    // into the last one (sticky): converting that to double rounds exactly as
    // the full number would round, since 63 > 53 + 2 bits keep the guard bit
    // and the sticky bit apart.
    const int low = lead - 62;  // position of the last kept bit, >= -62
    uint64_t head;
    bool sticky = false;
    if (low <= 0) {
        head = w[0] << -low;
    } else {
        const int q = low / 64, r = low % 64;
        head = w[q] >> r;
        if (r > 0 && q + 1 < n) head |= w[q + 1] << (64 - r);
        sticky = (w[q] & ((uint64_t(1) << r) - 1)) != 0;
        for (int i = 0; i < q; ++i) sticky = sticky || w[i] != 0;
    }
    // head | sticky lies in [2^62, 2^63): the conversion to double rounds it
    // once, and the scale 2^(low - kFracBits), with low - kFracBits in
    // [-142, 114) (lead < 256), keeps it a normal double, so multiplying by that power of
    // two is exact, as ldexp would be, without the library call (the writer
    // converts every voxel of a run's grids).
    const uint64_t scale_bits = uint64_t(1023 + low - kFracBits) << 52;
    double scale;
    std::memcpy(&scale, &scale_bits, sizeof scale);
    const double mag = double(int64_t(head | uint64_t(sticky))) * scale;
    return neg ? -mag : mag;
}

}  // namespace ep
