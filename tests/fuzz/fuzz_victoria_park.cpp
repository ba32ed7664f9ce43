// libFuzzer harness: the three Victoria Park readers on the same input.
#include "fuzz_support.hpp"
#include "victoria_park/victoria_park.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  namespace vp = mspace::victoria_park;
  const auto file = mspace::fuzz::write_input("vp.txt", data, size);
  for (const char* policy : {"error", "skip"}) {
    mspace::records::MalformedRecords m(policy);
    mspace::fuzz::expect_documented_errors_only([&] { vp::read_dead_reckoning(file, m); });
    mspace::fuzz::expect_documented_errors_only([&] { vp::read_detections(file, m); });
  }
  mspace::fuzz::expect_documented_errors_only([&] { vp::read_gps(file); });
  return 0;
}
