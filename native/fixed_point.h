// Exact, order-independent sums of doubles: a 128-bit two's-complement
// fixed-point number whose last bit is worth 2^-80 (docs/numerics.md,
// "Grid sums").
//
// Floating-point addition is not associative, so a sum of doubles depends on
// how its terms are grouped: per thread, per Dask chunk, per unit. Every
// deposit converted to this fixed point is an integer number of 2^-80, and
// integer addition is associative and commutative, so a voxel's total is the
// same bits whatever order and grouping its deposits are added in.
//
// Range and precision (kFracBits = 80, 128 bits; it was 192 bits with a last
// bit of 2^-124 before issue 39, which made a voxel slot 40 bytes, not 32):
//  - a deposit converts exactly when 2^-28 <= |v| < 2^47 (its 53-bit
//    significand lies at or above the last bit); 0 < |v| < 2^-28 is rounded to
//    the nearest multiple of 2^-80 (ties to even), so it keeps fewer bits
//    (v = 2^-40 keeps 40) and |v| <= 2^-81 becomes 0; |v| >= 2^47 or not
//    finite does not convert (from_double returns false: the caller drops and
//    counts the deposit);
//  - a total must stay within [-2^47, 2^47) (1.4e14); add() reports the
//    overflow (the caller fails with a named error), it never wraps silently.
// Grid deposits are weights (>= the roulette threshold, 1e-4 by default)
// times an albedo-like fraction and a spectral factor of order one, so the
// realistic deposit lies far above 2^-28 (3.7e-9) and converts exactly; the
// busiest voxel of the colon at 0.2 mm gains 0.004 per packet, so it reaches
// 2^47 after 3.5e16 packets (docs/numerics.md, "Grid sums").
#pragma once

#include <cstdint>
#include <cstring>

namespace ep {

class Fixed128 {
  public:
    static constexpr int kFracBits = 80;  // value of the last bit: 2^-kFracBits

    Fixed128() = default;

    // Exact conversion of v (rounded below 2^-28, see above). False when v is
    // not finite or |v| >= 2^47; `out` is then unchanged.
    static bool from_double(double v, Fixed128& out) {
        unsigned __int128 low;
        if (fast_low(v, low)) {
            out.set(__int128(low));
            return true;
        }
        return from_double_general(v, out);
    }

    // The fast path of from_double, for the deposit loop: a positive normal
    // double of 2^-28 <= v < 2^47 is its 53-bit significand shifted left by
    // e - 995 <= 74 bits (e: the biased exponent; 995 = 1023 + 52 - 80), which
    // stays below 2^127 (`low`, non-negative as a signed value). False for
    // every other v (the sign bit makes e - 995 huge, so negative values,
    // zero, subnormals, large values, inf and NaN all fail): use from_double.
    static bool fast_low(double v, unsigned __int128& low) {
        uint64_t b;
        std::memcpy(&b, &v, sizeof b);
        const uint64_t shift = (b >> 52) - 995;
        if (shift > 74) return false;
        const uint64_t mant = (b & ((uint64_t(1) << 52) - 1)) | (uint64_t(1) << 52);
        low = static_cast<unsigned __int128>(mant) << shift;
        return true;
    }

    // *this += `low` (a fast_low value, below 2^127), exactly. False (and
    // *this unchanged) if the total leaves the range.
    bool add_low(unsigned __int128 low) { return add_value(__int128(low)); }

    // *this += o, exactly. False (and *this unchanged) if the total leaves
    // [-2^47, 2^47): the signed overflow flag of one 128-bit addition.
    bool add(const Fixed128& o) { return add_value(o.get()); }

    // The value rounded to the nearest double (ties to even).
    double to_double() const { return words_to_double(w_, 2); }
    bool is_zero() const { return (w_[0] | w_[1]) == 0; }
    bool operator==(const Fixed128& o) const { return std::memcmp(w_, o.w_, sizeof w_) == 0; }

    // The two 64-bit words, least significant first (the byte form of
    // unit_io.cpp); from_words is their inverse.
    const uint64_t* words() const { return w_; }
    static Fixed128 from_words(uint64_t w0, uint64_t w1) {
        Fixed128 f;
        f.w_[0] = w0;
        f.w_[1] = w1;
        return f;
    }

    // Rounds the two's-complement number of `n` (1 to 4) 64-bit words (least
    // significant first, last bit worth 2^-kFracBits) to the nearest double.
    static double words_to_double(const uint64_t* w, int n);
    // total += this, in three words (the value sign-extended): exact for the
    // sum of up to 2^64 values (|value| <= 2^47 = 2^127 last bits < 2^191).
    void add_to_wide(uint64_t total[3]) const {
        const uint64_t w[3] = {w_[0], w_[1], int64_t(w_[1]) < 0 ? ~uint64_t(0) : 0};
        add_wide(total, w);
    }
    // total += w, two three-word two's-complement numbers (wide sums).
    static void add_wide(uint64_t total[3], const uint64_t w[3]) {
        uint64_t carry = 0;
        for (int k = 0; k < 3; ++k) {
            const uint64_t t = total[k] + carry, c1 = t < carry;
            total[k] = t + w[k];
            carry = c1 + (total[k] < w[k]);
        }
    }

  private:
    __int128 get() const { return __int128((static_cast<unsigned __int128>(w_[1]) << 64) | w_[0]); }
    void set(__int128 v) {
        w_[0] = uint64_t(v);
        w_[1] = uint64_t(static_cast<unsigned __int128>(v) >> 64);
    }
    bool add_value(__int128 b) {
        __int128 sum;
        if (__builtin_add_overflow(get(), b, &sum)) return false;
        set(sum);
        return true;
    }
    static bool from_double_general(double v, Fixed128& out);

    // Words, not one __int128: keeps the struct 8-byte aligned, so a voxel
    // slot (12-byte key, 4-byte flag, value) is 32 bytes with no padding.
    uint64_t w_[2] = {0, 0};
};

}  // namespace ep
