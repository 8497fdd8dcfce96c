// The lane kernel (lane_kernel.h) at 4 lanes, for processors with SSE2; lane_steps.cpp
// calls it where the processor has the instruction set. CMakeLists.txt gives this file its flags.
#include "lane_kernel.h"

namespace ep {

uint32_t run_lanes_sse2(LaneBlock& block) { return run_lanes_w<4>(block); }

}  // namespace ep
