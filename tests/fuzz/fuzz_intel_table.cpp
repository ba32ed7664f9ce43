// libFuzzer harness: the carmen_log reader on the Intel merged table.
#include "carmen_reader.hpp"
#include "fuzz_support.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const auto file = mspace::fuzz::write_input("table.txt", data, size);
  for (bool skip : {false, true}) {
    mspace::carmen_log::ReaderOptions o;
    o.format = mspace::carmen_log::Format::Table;
    o.skip_malformed = skip;
    mspace::fuzz::expect_documented_errors_only([&] { mspace::carmen_log::read_log(file, o); });
  }
  return 0;
}
