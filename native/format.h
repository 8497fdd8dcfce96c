// Number formatting for error messages: "%g", the same as Python's f"{v:g}"
// in python/endophoton/spectra.py, so both sides print a value identically.
#pragma once
#include <cstdio>
#include <string>

namespace ep {

inline std::string format_g(double v) {
    char buf[64];
    std::snprintf(buf, sizeof buf, "%g", v);
    return buf;
}

}  // namespace ep
