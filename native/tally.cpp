#include "tally.h"

#include <algorithm>
#include <cmath>

namespace ep {

const char* tally_name(int i) {
    static const char* names[kScalarTallies] = {"specular_reflectance",
                                                "diffuse_reflectance",
                                                "transmittance",
                                                "absorbed",
                                                "missed",
                                                "cut",
                                                "roulette",
                                                "occluded",
                                                "camera_collected",
                                                "fluorescent_escaped",
                                                "escaped_energy",
                                                "interactions",
                                                "fluorescence_trials",
                                                "fluorescence_events"};
    return names[i];
}

const char* energy_tally_name(int i) {
    static const char* names[kEnergyTallies] = {"specular_reflectance_energy",
                                                "diffuse_reflectance_energy",
                                                "transmittance_energy",
                                                "absorbed_energy",
                                                "missed_energy",
                                                "cut_energy",
                                                "roulette_energy",
                                                "occluded_energy",
                                                "camera_collected_energy",
                                                "stokes_loss",
                                                "launched_energy"};
    return names[i];
}

namespace {

// Moves one running sum into its moments. A packet leaves most tallies at zero
// (every energy tally in a run that is not spectral), and adding a zero
// changes no sum: x + 0 = x for every x but -0, and a sum that starts at +0
// never becomes -0 (round to nearest gives +0 for exact cancellation), so
// skipping zeros keeps every sum bit-identical and costs a test instead of a
// load-add-store of two sums and a store (issue 11: the per-packet cost).
inline void move_to(double& running, Moments& m) {
    if (running == 0) return;
    m.add_packet(running);
    running = 0;
}

}  // namespace

void UnitTally::record_packet() {
    if (scalar[kCut] != 0) ++capped_packets;
    for (int k = 0; k < kScalarTallies; ++k) move_to(scalar[k], scalar_m[k]);
    for (int k = 0; k < kEnergyTallies; ++k) move_to(energy[k], energy_m[k]);
    for (size_t k = 0; k < absorbed_by_region.size(); ++k) move_to(absorbed_by_region[k], absorbed_by_region_m[k]);
    for (size_t k = 0; k < emitted_by_fluorophore.size(); ++k)
        move_to(emitted_by_fluorophore[k], emitted_by_fluorophore_m[k]);
}

void UnitTally::take_packet(UnitTally& p) {
    auto take = [](double& to, double& from) {  // as move_to: zeros skipped
        if (from == 0) return;
        to += from;
        from = 0;
    };
    packets += p.packets;
    p.packets = 0;
    for (int k = 0; k < kScalarTallies; ++k) take(scalar[k], p.scalar[k]);
    for (int k = 0; k < kEnergyTallies; ++k) take(energy[k], p.energy[k]);
    for (size_t k = 0; k < absorbed_by_region.size(); ++k) take(absorbed_by_region[k], p.absorbed_by_region[k]);
    for (size_t k = 0; k < emitted_by_fluorophore.size(); ++k)
        take(emitted_by_fluorophore[k], p.emitted_by_fluorophore[k]);
    record_packet();
}

double per_packet_stderr(uint64_t n, double sum, double sum_sq) {
    if (n == 0) return 0;
    const double dn = double(n);
    if (n == 1) return std::sqrt(sum_sq);
    // Sample variance s^2 = (sum_sq - sum^2 / n) / (n - 1); rounding can make
    // the difference slightly negative for a constant tally.
    const double var = std::max(0.0, (sum_sq - sum * sum / dn) / (dn - 1));
    return std::sqrt(var / dn);
}

Estimate batch_estimate_impl(const std::vector<uint64_t>& packets, const std::vector<double>& sums,
                             const std::vector<double>& sum_sq, int batches) {
    Estimate e;
    uint64_t total = 0;
    double total_sum = 0, total_sq = 0;
    for (size_t i = 0; i < packets.size(); ++i) {
        total += packets[i];
        total_sum += sums[i];
        if (!sum_sq.empty()) total_sq += sum_sq[i];
    }
    if (total == 0) return e;
    e.mean = total_sum / double(total);
    const size_t K = packets.size();
    const size_t B = std::min<size_t>(K, size_t(std::max(batches, 2)));
    // Contiguous groups: unit i goes to batch floor(i * B / K).
    std::vector<double> bsum(B, 0.0);
    std::vector<uint64_t> bn(B, 0);
    for (size_t i = 0; i < K; ++i) {
        const size_t b = i * B / K;
        bsum[b] += sums[i];
        bn[b] += packets[i];
    }
    // Weighted batch means: var(mean) = sum n_b^2 (x_b - x)^2 / (N^2) * B/(B-1).
    double acc = 0;
    size_t used = 0;
    for (size_t b = 0; b < B; ++b) {
        if (bn[b] == 0) continue;
        const double xb = bsum[b] / double(bn[b]);
        const double w = double(bn[b]) / double(total);
        acc += w * w * (xb - e.mean) * (xb - e.mean);
        ++used;
    }
    if (used >= 2)
        e.stderr_ = std::sqrt(acc * double(used) / double(used - 1));
    else if (!sum_sq.empty())
        e.stderr_ = per_packet_stderr(total, total_sum, total_sq);
    return e;
}

Estimate batch_estimate_prefix(const std::vector<uint64_t>& prefix_n, const std::vector<double>& prefix_sum,
                               int batches) {
    const size_t K = prefix_n.size() - 1;
    const size_t B = std::min<size_t>(K, size_t(std::max(batches, 2)));
    std::vector<uint64_t> bn(B);
    std::vector<double> bs(B);
    for (size_t b = 0; b < B; ++b) {
        // Same grouping as batch_estimate_impl: unit i in batch floor(i B / K).
        const size_t lo = (b * K + B - 1) / B, hi = ((b + 1) * K + B - 1) / B;
        bn[b] = prefix_n[hi] - prefix_n[lo];
        bs[b] = prefix_sum[hi] - prefix_sum[lo];
    }
    return batch_estimate_impl(bn, bs, {}, batches);
}

}  // namespace ep
