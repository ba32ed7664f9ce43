// libFuzzer harness: the carmen_log reader on CARMEN logs (CLF, GMapping).
#include "carmen_reader.hpp"
#include "fuzz_support.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const auto file = mspace::fuzz::write_input("log.clf", data, size);
  for (bool skip : {false, true}) {
    mspace::carmen_log::ReaderOptions o;
    o.format = mspace::carmen_log::Format::Carmen;
    o.skip_malformed = skip;
    o.no_return_range = 0.0;  // from the log: exercises the detection
    mspace::fuzz::expect_documented_errors_only([&] { mspace::carmen_log::read_log(file, o); });
  }
  return 0;
}
