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
    }
}

namespace {

// Permuted radical inverse of `index` in base B over a fixed number of digits
// K, down to double resolution (b^-K < 2^-53, so indices up to 2^53 stay
// distinct). Permuting the index's leading zeros too (they map to p[0]) is
// what scrambles; stopping after K digits keeps their sum below one cell
// width, so the first b^k points are the lattice j b^-k shifted by one common
// offset < b^-k. (Summing the infinite tail instead would push a whole cell
// over when p[0] = b - 1.) B is a compile-time constant, so % and / are a
// multiply and a shift, and once the index runs out of digits the leading
// zeros need no division at all (issue 11: 145 divisions per packet of the
// endoscope's five dimensions); the sum is the same, term by term.
template <uint64_t B>
double radical_inverse(const uint16_t* p, uint64_t index) {
    constexpr double inv_b = 1.0 / double(B);
    double inv_bk = inv_b, value = 0.0;
    while (index != 0 && inv_bk > 0x1.0p-53) {
        value += double(p[index % B]) * inv_bk;
        index /= B;
        inv_bk *= inv_b;
    }
    const double zero_digit = double(p[0]);
    while (inv_bk > 0x1.0p-53) {
        value += zero_digit * inv_bk;
        inv_bk *= inv_b;
    }
    return value;
}

}  // namespace

double Halton::sample(uint64_t index, int dim) const {
    if (dim < 0 || dim >= kMaxDimensions) throw std::out_of_range("Halton dimension out of range");
    // One instantiation per base of kPrimes, in the same order.
    using Inverse = double (*)(const uint16_t*, uint64_t);
    static constexpr Inverse kInverse[kMaxDimensions] = {radical_inverse<2>,  radical_inverse<3>,  radical_inverse<5>,
                                                         radical_inverse<7>,  radical_inverse<11>, radical_inverse<13>,
                                                         radical_inverse<17>, radical_inverse<19>};
    const double value = kInverse[dim](perm_[dim].data(), index);
    return value < 1.0 ? value : 0x1.fffffffffffffp-1;
}

}  // namespace ep
