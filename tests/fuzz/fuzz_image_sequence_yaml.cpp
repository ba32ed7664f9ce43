// libFuzzer harness: image_sequence's camera.yaml and laser.yaml readers.
#include "fuzz_support.hpp"
#include "image_sequence/image_sequence.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  namespace is = mspace::image_sequence;
  static const std::string csv = [] {
    const auto f = mspace::fuzz::scratch() / "laser.csv";
    std::ofstream(f) << "0,1,2,3\n0.1,1,2,3\n";
    return f.string();
  }();
  const std::string file = mspace::fuzz::write_input("description.yaml", data, size).string();
  mspace::fuzz::expect_documented_errors_only([&] { is::read_camera_yaml(file); });
  mspace::records::MalformedRecords m;
  mspace::fuzz::expect_documented_errors_only([&] { is::read_laser(file, csv, m); });
  return 0;
}
