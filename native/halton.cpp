#include "halton.h"

#include <stdexcept>

#include "rng.h"

namespace ep {

namespace {
constexpr int kPrimes[Halton::kMaxDimensions] = {2, 3, 5, 7, 11, 13, 17, 19};  // kInverse below follows them
}

int Halton::base(int dim) { return kPrimes[dim]; }

Halton::Halton(uint64_t seed) {
    for (int d = 0; d < kMaxDimensions; ++d) {
        const int b = kPrimes[d];
        perm_[d].resize(b);
        for (int i = 0; i < b; ++i) perm_[d][i] = uint16_t(i);
        // Fisher–Yates with a stream reserved for the scrambling tables.
        Rng rng(seed, 0xFFFFFFFF00000000ULL + uint64_t(d));
        for (int i = b - 1; i > 0; --i) {
            const int j = int(rng.next_u64() % uint64_t(i + 1));
            std::swap(perm_[d][i], perm_[d][j]);
        }
        // The weights b^-k by repeated multiplication and each term's
        // product, exactly as the digit loop of radical_inverse forms them.
        const double inv_b = 1.0 / double(b);
        for (double w = inv_b; w > 0x1.0p-53; w *= inv_b)
            for (int j = 0; j < b; ++j) terms_[d].push_back(double(perm_[d][j]) * w);
    }
}

namespace {

// Permuted radical inverse of `index` in base B over a fixed number of digits
// K, down to double resolution (b^-K < 2^-53, so indices up to 2^53 stay
// distinct). Permuting the index's leading zeros too (they map to p[0]) is
// what scrambles; stopping after K digits keeps their sum below one cell
// width, so the first b^k points are the lattice j b^-k shifted by one common
// offset < b^-k. (Summing the infinite tail instead would push a whole cell
// over when p[0] = b - 1.) The digit loop is
//     value += p[digit k] * b^-k   (k = 1..K, the index's lowest digit first),
// its terms p[j] b^-k read from Halton's table of them (`t`, K rows of B),
// rounded as the loop rounds them, and added in the same order, so the sum
// is the same bit for bit. B is a compile-time constant, so % and / are a
// multiply and a shift, and once the index runs out of digits the leading
// zeros need no division at all (issue 11: 145 divisions per packet of the
// endoscope's five dimensions; the table: ~730 -> ~520 instructions a
// packet for the four table dimensions on colon_polyp, callgrind).
template <uint64_t B>
double radical_inverse(const uint16_t*, const double* t, const double* end, uint64_t index) {
    double value = 0.0;
    for (; index != 0 && t != end; t += B) {
        value += t[index % B];
        index /= B;
    }
#pragma GCC unroll 4
    for (; t != end; t += B) value += t[0];  // the leading zeros' digit p[0]
    return value;
}

// Base 2 in closed form, bit-identical to the digit loop above: its terms
// p[bit] 2^-k (k = 1..52) are distinct powers of two inside one 52-bit
// window, so every partial sum is exact and the loop's value is the integer
// M 2^-52, M the index's low 52 bits reversed (bit j to bit 51 - j) and
// flipped when the permutation swaps 0 and 1 (p[bit] = bit xor p[0]); the
// leading zeros give the flipped bits beyond the index's highest one.
// (callgrind, colon_polyp: ~350 of emit's ~1.7k instructions a packet.)
template <>
double radical_inverse<2>(const uint16_t* p, const double*, const double*, uint64_t index) {
    uint64_t r = index;  // bit reversal of 64 bits by swapping halves, quarters, ...
    r = ((r >> 1) & 0x5555555555555555ULL) | ((r & 0x5555555555555555ULL) << 1);
    r = ((r >> 2) & 0x3333333333333333ULL) | ((r & 0x3333333333333333ULL) << 2);
    r = ((r >> 4) & 0x0F0F0F0F0F0F0F0FULL) | ((r & 0x0F0F0F0F0F0F0F0FULL) << 4);
    r = __builtin_bswap64(r);
    const uint64_t mask = (uint64_t(1) << 52) - 1;
    const uint64_t m = (r >> 12) ^ (p[0] ? mask : 0);
    return double(m) * 0x1.0p-52;
}

}  // namespace

double Halton::sample(uint64_t index, int dim) const {
    if (dim < 0 || dim >= kMaxDimensions) throw std::out_of_range("Halton dimension out of range");
    // One instantiation per base of kPrimes, in the same order.
    using Inverse = double (*)(const uint16_t*, const double*, const double*, uint64_t);
    static constexpr Inverse kInverse[kMaxDimensions] = {radical_inverse<2>,  radical_inverse<3>,  radical_inverse<5>,
                                                         radical_inverse<7>,  radical_inverse<11>, radical_inverse<13>,
                                                         radical_inverse<17>, radical_inverse<19>};
    const std::vector<double>& t = terms_[dim];
    const double value = kInverse[dim](perm_[dim].data(), t.data(), t.data() + t.size(), index);
    return value < 1.0 ? value : 0x1.fffffffffffffp-1;
}

}  // namespace ep
