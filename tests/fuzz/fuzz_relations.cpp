// libFuzzer harness: the relations reader (kernel/src/relations.cpp).
#include "fuzz_support.hpp"
#include "relations.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const auto file = mspace::fuzz::write_input("run.relations", data, size);
  mspace::fuzz::expect_documented_errors_only([&] { mspace::kernel::read_relations(file); });
  return 0;
}
