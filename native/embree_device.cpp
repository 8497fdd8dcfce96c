#include "embree_device.h"

#include <cstdlib>
#include <stdexcept>

namespace ep {

std::string embree_config(const std::string& base) {
    const char* isa = std::getenv("ENDOPHOTON_EMBREE_ISA");
    if (!isa) return base;
    const std::string v(isa);
    for (const char* known : {"sse2", "sse4.2", "avx", "avx2", "avx512"})
        if (v == known) return base.empty() ? "max_isa=" + v : base + ",max_isa=" + v;
    throw std::invalid_argument("ENDOPHOTON_EMBREE_ISA = '" + v +
                                "' must be one of sse2, sse4.2, avx, avx2, avx512 (or unset: Embree's best)");
}

RTCDevice new_embree_device(const std::string& base) {
    const std::string config = embree_config(base);
    RTCDevice device = rtcNewDevice(config.c_str());
    if (!device) throw std::runtime_error("Embree: rtcNewDevice failed (configuration '" + config + "')");
    return device;
}

}  // namespace ep
