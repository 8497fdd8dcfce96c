// Packets in float32 lanes (issue 39; docs/performance.md §28, §29): the plain
// interior steps of 16 packets at once -- free path, move, capture,
// fluorescence trials, HG scattering -- in single precision, structure of
// arrays, one vector lane a packet. The walk (transport.cpp) hands a packet
// to a slot where its next steps cross nothing (a zone of ClearSteps,
// triangle_cache.h) and takes it back where a step may cross something, a
// trial fires, or roulette or the caps are due.
//
// The block is plain data and the kernel (lane_kernel.h) is compiled once per
// instruction set (lane_steps_sse2/avx2/avx512.cpp: 4, 8 or 16 lanes). Every
// lane operation is an elementwise IEEE single-precision operation, with no
// contraction into fused multiply-adds and the exact square root, and the 16
// slots are stepped alike whatever the width: so the same packets give the
// same bits on every x86-64 processor and at every lane width
// (tests/python/test_lanes.py). They are not the bits of the scalar double
// walk: a lane run is a different sample of the same physics, checked
// against MCML, van de Hulst and Chandrasekhar's H-function (docs/numerics.md,
// "Float32 lanes").
#pragma once
#include <cstdint>

namespace ep {

enum class LaneIsa : int { kSse2 = 0, kAvx2 = 1, kAvx512 = 2 };

// Why a slot left the lanes (LaneBlock::reason).
enum LaneExit : int32_t {
    kLaneBlocked = 1,     // its next step (tau, unchanged) may cross something: the walk takes it
    kLaneSlow = 2,        // a step was taken and roulette or a cap is due (its free path is not drawn)
    kLaneFluoresced = 3,  // a step was taken, its capture done, and fluorophore `fired` fluoresced there:
                          // the walk finishes that interaction (fluoresce_with, scatter_and_survive)
};

struct LaneBlock {
    static constexpr int kSlots = 16;
    static constexpr int kMaxPlanes = 16;  // ClearSteps::kMaxPlanes
    static constexpr int kMaxTrials = 4;   // fluorophores a slot tries (PacketWalk::LoopTrials::kMax)

    // The packets: xoshiro128++ state (Blackman & Vigna 2021), scatterings in
    // the lanes (the frame is renormalised every 16th), steps taken since the
    // load and steps the caps allow.
    alignas(64) uint32_t s0[kSlots], s1[kSlots], s2[kSlots], s3[kSlots];
    alignas(64) uint32_t count[kSlots], steps[kSlots], room[kSlots];
    // Position relative to the zone's centre (scene units), the frame (t, b, n
    // = direction), weight (a factor of the weight handed over), the free path left (dimensionless), the deepest
    // point (scene units along entry_in, from the entry point), the clearance
    // budget (scene units). The weight captured is the walk's: the weight
    // handed over less the weight taken back.
    alignas(64) float qx[kSlots], qy[kSlots], qz[kSlots];
    alignas(64) float tx[kSlots], ty[kSlots], tz[kSlots], bx[kSlots], by[kSlots], bz[kSlots];
    alignas(64) float nx[kSlots], ny[kSlots], nz[kSlots];
    alignas(64) float w[kSlots], tau[kSlots], depth[kSlots], budget[kSlots];
    // The medium of each slot: 1 / (mu_t in scene units^-1), mua / mu_t, HG's
    // constants (MCML's form 1 - g^2, 1 - g, 2g, 1 + g^2, 1 / (2g); g itself
    // for the small-|g| form), and the roulette's threshold (as a factor of
    // the weight handed over).
    alignas(64) float inv_mut[kSlots], loss[kSlots];
    alignas(64) float hg0[kSlots], hg1[kSlots], hg2[kSlots], hg3[kSlots], hg_inv2g[kSlots], g[kSlots];
    alignas(64) int32_t small_g[kSlots];  // -1: |g| < 1/4, the form without cancellation
    alignas(64) float threshold[kSlots];
    // The zone: the ball (inner radius, its square), the per-step slack, and
    // the planes n . q - off > 0 (unused planes of a slot: n = 0, off = -1e30).
    alignas(64) float inner[kSlots], inner_r2[kSlots], slack[kSlots];
    alignas(64) float pnx[kMaxPlanes][kSlots], pny[kMaxPlanes][kSlots], pnz[kMaxPlanes][kSlots];
    alignas(64) float poff[kMaxPlanes][kSlots];
    // The entry point relative to the centre, and the entry direction (depth).
    alignas(64) float ex[kSlots], ey[kSlots], ez[kSlots], ix[kSlots], iy[kSlots], iz[kSlots];
    alignas(64) int32_t planes[kSlots];  // planes set for each slot (those above are n = 0, off = -1e30)
    // Spectral packets: fluoresce()'s trials at every interaction (seed §4),
    // fixed while the packet is in the lanes (its wavelength, so d under the
    // "eem" rule, changes only at an event, which ends its stay): how many
    // fluorophores it tries (0: none, as after its fluorescence under the
    // paper's rule), their d and c, the trials taken since the load, and the
    // fluorophore that fired (reason kLaneFluoresced).
    alignas(64) int32_t trials[kSlots];
    alignas(64) float trial_d[kMaxTrials][kSlots], trial_c[kMaxTrials][kSlots];
    alignas(64) uint32_t tried[kSlots];
    alignas(64) int32_t fired[kSlots];
    alignas(64) int32_t active[kSlots];  // -1: the slot steps
    alignas(64) int32_t reason[kSlots];  // LaneExit of a slot that left
    int n_planes = 0;                    // the largest plane count of any slot so far
    int max_trials = 0;                  // the largest trial count of any slot so far
    bool track_depth = false;            // the run records exits, so the lanes keep each packet's depth

    LaneBlock();  // no slot active, every plane unused
};

// Steps every active slot until one or more leave; returns the mask of the
// slots that left (bit k: slot k), with their reason set and active cleared.
// 0 when no slot is active.
uint32_t run_lanes(LaneBlock& block);

// The instruction set run_lanes uses: the widest this processor has, or
// ENDOPHOTON_LANE_ISA's ("sse2", "avx2", "avx512"; std::invalid_argument
// naming the variable and value for another, std::runtime_error when the
// processor lacks it). Read once.
LaneIsa lane_isa();
const char* lane_isa_name(LaneIsa isa);

// The kernels, one per instruction set (lane_steps_*.cpp).
uint32_t run_lanes_sse2(LaneBlock& block);
uint32_t run_lanes_avx2(LaneBlock& block);
uint32_t run_lanes_avx512(LaneBlock& block);

}  // namespace ep
