// The lane kernel (lane_kernel.h) at 8 lanes, for processors with AVX2; lane_steps.cpp
// calls it where the processor has the instruction set. CMakeLists.txt gives this file its flags.
#include "lane_kernel.h"

namespace ep {

uint32_t run_lanes_avx2(LaneBlock& block) { return run_lanes_w<8>(block); }

}  // namespace ep
