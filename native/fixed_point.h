// Exact, order-independent sums of doubles: a 192-bit two's-complement
// fixed-point number whose last bit is worth 2^-124 (docs/numerics.md,
// "Grid sums").
//
// Floating-point addition is not associative, so a sum of doubles depends on
// how its terms are grouped: per thread, per Dask chunk, per unit. Every
// deposit converted to this fixed point is an integer number of 2^-124, and
// integer addition is associative and commutative, so a voxel's total is the
// same bits whatever order and grouping its deposits are added in.
//
// Range and precision (kFracBits = 124, 192 bits):
//  - a deposit converts exactly when 2^-72 <= |v| < 2^64 (its 53-bit
//    significand lies at or above the last bit); 0 < |v| < 2^-72 is rounded to
//    the nearest multiple of 2^-124 (ties to even), so it keeps fewer bits and
//    |v| < 2^-125 becomes 0; |v| >= 2^64 or not finite does not convert
//    (from_double returns false: the caller drops and counts the deposit);
//  - a total must stay within [-2^67, 2^67); add() reports the overflow (the
//    caller fails with a named error), it never wraps silently.
// Grid deposits are weights times a spectral factor of order one, so every
// realistic deposit converts exactly, and 2^67 (1.5e20) exceeds any voxel's
// total by many orders of magnitude (2^62 packets at most per run).
#pragma once

#include <cstdint>
#include <cstring>

namespace ep {

class Fixed192 {
  public:
    static constexpr int kFracBits = 124;  // value of the last bit: 2^-kFracBits

    Fixed192() = default;

    // Exact conversion of v (rounded below 2^-72, see above). False when v is
    // not finite or |v| >= 2^64; `out` is then unchanged.
    static bool from_double(double v, Fixed192& out) {
        unsigned __int128 low;
        if (fast_low(v, low)) {
            out.w_[0] = uint64_t(low);
            out.w_[1] = uint64_t(low >> 64);
            out.w_[2] = 0;
            return true;
        }
        return from_double_general(v, out);
    }

    // The fast path of from_double, for the deposit loop: a positive normal
    // double of 2^-72 <= v < 8 is its 53-bit significand shifted left by
    // e - 951 < 75 bits (e: the biased exponent), which fits the low 128 bits
    // (`low`). False for every other v (the sign bit makes e - 951 huge, so
    // negative values, zero, subnormals, large values, inf and NaN all fail):
    // use from_double.
    static bool fast_low(double v, unsigned __int128& low) {
        uint64_t b;
        std::memcpy(&b, &v, sizeof b);
        const uint64_t shift = (b >> 52) - 951;
        if (shift > 74) return false;
        const uint64_t mant = (b & ((uint64_t(1) << 52) - 1)) | (uint64_t(1) << 52);
        low = static_cast<unsigned __int128>(mant) << shift;
        return true;
    }

    // *this += `low` (a fast_low value, below 2^127), exactly. False (and
    // *this unchanged) if the total leaves the range.
    bool add_low(unsigned __int128 low) {
        const unsigned __int128 a = low128(), sum = a + low;
        int64_t top;  // the carry into word 2 overflows it only at INT64_MAX
        if (__builtin_add_overflow(int64_t(w_[2]), int64_t(sum < a), &top)) return false;
        w_[0] = uint64_t(sum);
        w_[1] = uint64_t(sum >> 64);
        w_[2] = uint64_t(top);
        return true;
    }

    // *this += o, exactly. False (and *this unchanged) if the total leaves
    // [-2^67, 2^67).
    bool add(const Fixed192& o) {
        const unsigned __int128 a = low128(), b = o.low128();
        const unsigned __int128 low = a + b;
        const int64_t carry = low < a;
        // The top word in two signed steps, w2 + o2 then + carry. The sum is
        // in range exactly when both steps wrap or neither does: a first
        // step that wraps can only be brought back by the carry when it fell
        // one below INT64_MIN (and then the second step wraps too).
        int64_t partial, high;
        const bool wrap1 = __builtin_add_overflow(int64_t(w_[2]), int64_t(o.w_[2]), &partial);
        const bool wrap2 = __builtin_add_overflow(partial, carry, &high);
        if (wrap1 != wrap2) return false;
        w_[0] = uint64_t(low);
        w_[1] = uint64_t(low >> 64);
        w_[2] = uint64_t(high);
        return true;
    }

    // The value rounded to the nearest double (ties to even).
    double to_double() const { return words_to_double(w_, 3); }
    bool is_zero() const { return (w_[0] | w_[1] | w_[2]) == 0; }
    bool operator==(const Fixed192& o) const { return std::memcmp(w_, o.w_, sizeof w_) == 0; }

    // The three 64-bit words, least significant first (the byte form of
    // unit_io.cpp); from_words is their inverse.
    const uint64_t* words() const { return w_; }
    static Fixed192 from_words(uint64_t w0, uint64_t w1, uint64_t w2) {
        Fixed192 f;
        f.w_[0] = w0;
        f.w_[1] = w1;
        f.w_[2] = w2;
        return f;
    }

    // Rounds the two's-complement number of `n` 64-bit words (least
    // significant first, last bit worth 2^-kFracBits) to the nearest double.
    static double words_to_double(const uint64_t* w, int n);

  private:
    unsigned __int128 low128() const { return (static_cast<unsigned __int128>(w_[1]) << 64) | w_[0]; }
    static bool from_double_general(double v, Fixed192& out);

    // Words, not one __int128 and an int64: keeps the struct 8-byte aligned, so
    // a voxel slot (12-byte key, 4-byte flag, value) is 40 bytes, not 48.
    uint64_t w_[3] = {0, 0, 0};
};

}  // namespace ep
