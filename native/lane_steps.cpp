// Which lane kernel runs (lane_block.h): the widest instruction set of this
// processor, or the one ENDOPHOTON_LANE_ISA names. All give the same bits,
// so the choice changes the speed only (tests/python/test_lanes.py runs
// each).
#include <cstdlib>
#include <stdexcept>
#include <string>

#include "lane_block.h"

namespace ep {

namespace {

bool has(LaneIsa isa) {
    switch (isa) {
        case LaneIsa::kAvx512:
            return __builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512vl") &&
                   __builtin_cpu_supports("avx512dq");
        case LaneIsa::kAvx2:
            return __builtin_cpu_supports("avx2");
        case LaneIsa::kSse2:
            return true;
    }
    return false;
}

LaneIsa choose() {
    const char* v = std::getenv("ENDOPHOTON_LANE_ISA");
    if (!v) return has(LaneIsa::kAvx512) ? LaneIsa::kAvx512 : has(LaneIsa::kAvx2) ? LaneIsa::kAvx2 : LaneIsa::kSse2;
    for (LaneIsa isa : {LaneIsa::kSse2, LaneIsa::kAvx2, LaneIsa::kAvx512}) {
        if (std::string(v) != lane_isa_name(isa)) continue;
        if (!has(isa))
            throw std::runtime_error(std::string("ENDOPHOTON_LANE_ISA = '") + v + "': this processor lacks " + v);
        return isa;
    }
    throw std::invalid_argument(std::string("ENDOPHOTON_LANE_ISA = '") + v +
                                "' must be one of sse2, avx2, avx512 (or unset: the widest this processor has)");
}

}  // namespace

LaneBlock::LaneBlock() {
    for (int k = 0; k < kSlots; ++k) {
        active[k] = 0, reason[k] = 0, planes[k] = 0, trials[k] = 0, tried[k] = 0, fired[k] = 0;
        for (int j = 0; j < kMaxTrials; ++j) trial_d[j][k] = trial_c[j][k] = 0;
        for (int j = 0; j < kMaxPlanes; ++j) pnx[j][k] = pny[j][k] = pnz[j][k] = 0, poff[j][k] = -1e30f;
    }
}

const char* lane_isa_name(LaneIsa isa) {
    switch (isa) {
        case LaneIsa::kSse2:
            return "sse2";
        case LaneIsa::kAvx2:
            return "avx2";
        case LaneIsa::kAvx512:
            return "avx512";
    }
    return "?";
}

LaneIsa lane_isa() {
    static const LaneIsa isa = choose();
    return isa;
}

uint32_t run_lanes(LaneBlock& block) {
    switch (lane_isa()) {
        case LaneIsa::kAvx512:
            return run_lanes_avx512(block);
        case LaneIsa::kAvx2:
            return run_lanes_avx2(block);
        case LaneIsa::kSse2:
            break;
    }
    return run_lanes_sse2(block);
}

}  // namespace ep
