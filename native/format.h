// Number formatting for error messages: "%g" (as Python's f"{v:g}" prints
// a number, so a message reads the same whichever side it comes from).
#pragma once
#include <cmath>
#include <cstdio>
#include <string>

namespace ep {

inline std::string format_g(double v) {
    if (std::isnan(v)) return "nan";  // printf gives "-nan" for a NaN with its sign bit set; Python never does
    char buf[64];
    std::snprintf(buf, sizeof buf, "%g", v);
    return buf;
}

}  // namespace ep
