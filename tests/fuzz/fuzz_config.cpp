// libFuzzer harness: the configuration loader (kernel/src/config.cpp) with
// the plugins of the built-in default (built in the same tree, so their ABI
// tag matches): parsing, validation against the plugins' parameter lists,
// environment expansion.
#include "config.hpp"
#include "fuzz_support.hpp"
#include "plugin_registry.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  static mspace::kernel::PluginRegistry registry;
  static const bool ready = (registry.add_search_dir(MSPACE_PLUGIN_DIR), true);
  (void)ready;
  const std::string text(reinterpret_cast<const char*>(data), size);
  mspace::fuzz::expect_documented_errors_only([&] { mspace::kernel::parse_config(text, "fuzz.yaml", registry); });
  return 0;
}
