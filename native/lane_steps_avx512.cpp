// The lane kernel (lane_kernel.h) at 16 lanes, for processors with AVX-512 (F, VL, DQ); lane_steps.cpp
// calls it where the processor has the instruction set. CMakeLists.txt gives this file its flags.
#include "lane_kernel.h"

namespace ep {

uint32_t run_lanes_avx512(LaneBlock& block) { return run_lanes_w<16>(block); }

}  // namespace ep
