// default_config.hpp — the built-in run (config/sim_points.yaml, embedded at build time).
#pragma once

#include <string>

namespace mspace::kernel {
const char* default_config_text();
std::string default_config_name();
}  // namespace mspace::kernel
