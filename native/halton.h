// Scrambled Halton sequence for emission sampling (the seed shoots photons
// "using Halton sequence", §4). Dimension d uses the d-th prime as base and a
// random digit permutation per dimension (Braaten–Weller style scrambling),
// derived from the run seed, so the sequence is deterministic for a seed and
// avoids the correlation of unscrambled high bases.
#pragma once
#include <cstdint>
#include <vector>

namespace ep {

class Halton {
  public:
    static constexpr int kMaxDimensions = 8;
    explicit Halton(uint64_t seed);
    // Point `index` (packet index) in dimension `dim` (0 <= dim < kMaxDimensions), in [0, 1).
    double sample(uint64_t index, int dim) const;
    static int base(int dim);

    // Dimension dim's digit permutation (its table of base(dim) entries).
    const std::vector<uint16_t>& permutation(int dim) const { return perm_[dim]; }

  private:
    std::vector<uint16_t> perm_[kMaxDimensions];
    // The radical inverse's terms as its digit loop rounds them: terms_[d]
    // holds p[j] * b^-(k+1) at k b + j, for the places k whose weight b^-(k+1)
    // exceeds 2^-53.
    std::vector<double> terms_[kMaxDimensions];
};

}  // namespace ep
