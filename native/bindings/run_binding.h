// What the run bindings share: the options dict -> RunConfig, the RunResult ->
// result dict, and the cancel token (module.cpp defines them; distributed.cpp
// uses them for the distributed run).
#pragma once
#include <pybind11/pybind11.h>

#include <atomic>

#include "engine.h"

namespace ep {

struct CancelToken {
    std::atomic<bool> flag{false};
};

// Throws std::invalid_argument naming an unknown option or a bad value.
RunConfig run_config_from_options(const pybind11::dict& opts);
// Moves the records out of `r`.
pybind11::dict run_result_dict(RunResult& r, const Scene& scene, const RunConfig& c);

// Registers UnitReducer, trace_units and unit_plan (distributed.cpp).
void register_distributed(pybind11::module_& m);

}  // namespace ep
