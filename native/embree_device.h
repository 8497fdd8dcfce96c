// The engine's Embree devices, and the one setting a user may add to them.
//
// Embree picks its traversal and intersection kernels by the processor
// (SSE2 to AVX-512). The engine refines every hit distance in double itself
// (scene.cpp, collect_filter), but which triangles Embree offers near an edge
// is its float kernels' decision. ENDOPHOTON_EMBREE_ISA caps the kernels
// (Embree's max_isa: sse2, sse4.2, avx, avx2 or avx512), so that one machine
// can run as an older one does: tests/python/test_isa_bits.py runs the
// oldest x86-64 that way and finds the same bits.
#pragma once
#include <embree3/rtcore.h>

#include <string>

namespace ep {

// Embree's configuration string: `base` (e.g. "threads=1"; may be empty),
// with the kernels' cap from ENDOPHOTON_EMBREE_ISA when it is set. Throws
// std::invalid_argument naming the variable and its value when the value is
// not one of the five.
std::string embree_config(const std::string& base);

// rtcNewDevice(embree_config(base)); throws std::runtime_error if Embree
// cannot make it.
RTCDevice new_embree_device(const std::string& base);

}  // namespace ep
