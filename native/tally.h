// Weight tallies of one work unit (a fixed block of packet indices). Units are
// merged in index order, so the totals are bit-identical for any thread count,
// and the spread of per-batch fractions gives the standard errors (batch means,
// as MCML's 10 x 50k runs do, but inside one run).
#pragma once
#include <cstdint>
#include <string>
#include <vector>

namespace ep {

enum TallyIndex : int {
    kSpecular = 0,  // Rsp: specular reflection at the first boundary
    kDiffuse,       // Rd: escaped back (direction against the source axis)
    kTransmitted,   // Tt: escaped forward
    kAbsorbed,      // A
    kMissed,        // never met a region
    kCut,           // removed by the step / path cap
    kRoulette,      // net weight destroyed (+) or created (-) by Russian roulette
    kOccluded,      // landed on the endoscope head (opaque, black) after leaving the tissue or by specular reflection
    kCameraCollected,     // landed on the camera's aperture: the camera's signal
    kFluorescentEscaped,  // weight of escaping fluorescent packets
    kEscapedEnergy,       // energy (weight x 500/lambda) of escaping packets
    kInteractions,        // count of interaction events (not weighted)
    kFluorescenceTrials,  // count of fluorescence decisions (interaction x eligible fluorophore)
    kFluorescenceEvents,  // count of fluorescence events
    kScalarTallies
};

// The fates of launched weight: tallies [0, kBalanceTallies) sum to 1 in every run.
constexpr int kBalanceTallies = kCameraCollected + 1;

const char* tally_name(int i);

// Energy tallies of spectral runs (energy = weight x 500 nm / lambda). The
// first nine mirror the weight tallies of the balance (same indices); kStokes is the energy
// fluorescence removed by lengthening wavelengths, kLaunched the energy that
// was emitted. Launched = sum of the others, to rounding.
enum EnergyIndex : int {
    kEnergySpecular = 0,
    kEnergyDiffuse,
    kEnergyTransmitted,
    kEnergyAbsorbed,
    kEnergyMissed,
    kEnergyCut,
    kEnergyRoulette,
    kEnergyOccluded,
    kEnergyCameraCollected,
    kEnergyStokes,
    kEnergyLaunched,
    kEnergyTallies
};
const char* energy_tally_name(int i);

// Sum of one tally over a unit's packets and the sum of the squares of each
// packet's contribution: the second gives the per-packet variance, the only
// standard error a run of fewer than two batches has.
struct Moments {
    double sum = 0, sum_sq = 0;
    void add_packet(double w) {
        sum += w;
        sum_sq += w * w;
    }
};

struct UnitTally {
    uint64_t packets = 0;
    uint64_t capped_packets = 0;  // packets that ended at the step or path cap
    // Running sums the tracer adds to during a packet; record_packet() moves
    // each packet's contribution into the moments.
    double scalar[kScalarTallies] = {};
    double energy[kEnergyTallies] = {};
    std::vector<double> absorbed_by_region;
    // Packet weight each fluorophore (by id) converted into fluorescence: the
    // sum over its fluorescence events of the packet's weight there.
    std::vector<double> emitted_by_fluorophore;
    Moments scalar_m[kScalarTallies];
    Moments energy_m[kEnergyTallies];
    std::vector<Moments> absorbed_by_region_m;
    std::vector<Moments> emitted_by_fluorophore_m;
    void reset(size_t regions, size_t fluorophores = 0) {
        *this = UnitTally{};
        absorbed_by_region.assign(regions, 0.0);
        absorbed_by_region_m.assign(regions, Moments{});
        emitted_by_fluorophore.assign(fluorophores, 0.0);
        emitted_by_fluorophore_m.assign(fluorophores, Moments{});
    }
    // Ends one packet: its contribution (the running sums) goes to the moments,
    // and the running sums are cleared for the next packet.
    void record_packet();
    // Ends one packet traced into `packet`'s running sums instead (the
    // lanes' packets in flight, Tracer::trace_lanes): adds them to these,
    // clears them, and records the packet.
    void take_packet(UnitTally& packet);
};

// Mean per launched packet and its standard error.
struct Estimate {
    double mean = 0, stderr_ = 0;
};

// Groups consecutive units into at most `batches` batches of (nearly) equal
// packet counts and returns mean and standard error of sum/packets for the
// moments picked by `value(unit)`. The standard error comes from batch means
// when there are at least two non-empty batches, else from the per-packet
// variance (always finite).
template <class F>
Estimate batch_estimate(const std::vector<UnitTally>& units, int batches, F value);

// Implementation. `sum_sq` (per-packet squares, summed per unit) may be empty
// when only batch means are wanted (the stop rule, which waits for 20 units);
// then fewer than two batches give a standard error of 0.
Estimate batch_estimate_impl(const std::vector<uint64_t>& packets, const std::vector<double>& sums,
                             const std::vector<double>& sum_sq, int batches);

// Standard error of the mean of n packets from the per-packet moments:
// sqrt(sample variance / n); with one packet, sqrt(sum_sq) (the variance is
// bounded by the second moment), so the value is finite and conservative.
double per_packet_stderr(uint64_t n, double sum, double sum_sq);

// The same estimate from prefix sums over units (prefix_n[0] = prefix_sum[0] = 0,
// K + 1 entries): O(batches) per call, for stop rules checked after every unit.
Estimate batch_estimate_prefix(const std::vector<uint64_t>& prefix_n, const std::vector<double>& prefix_sum,
                               int batches);

template <class F>
Estimate batch_estimate(const std::vector<UnitTally>& units, int batches, F value) {
    std::vector<uint64_t> packets(units.size());
    std::vector<double> sums(units.size()), sum_sq(units.size());
    for (size_t i = 0; i < units.size(); ++i) {
        const Moments& m = value(units[i]);
        packets[i] = units[i].packets;
        sums[i] = m.sum;
        sum_sq[i] = m.sum_sq;
    }
    return batch_estimate_impl(packets, sums, sum_sq, batches);
}

}  // namespace ep
