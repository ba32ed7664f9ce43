// libFuzzer harness: image_sequence's CSV and TUM readers on the same input
// (frames.csv, odometry.csv, laser.csv with a fixed laser.yaml, groundtruth.tum).
#include "fuzz_support.hpp"
#include "image_sequence/image_sequence.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  namespace is = mspace::image_sequence;
  static const std::string yaml = [] {
    const auto f = mspace::fuzz::scratch() / "laser.yaml";
    std::ofstream(f) << "beams: 3\nfirst_bearing_deg: -10\nbearing_step_deg: 10\nmax_range: 8\n"
                        "mount: [0, 0, 0, 0, 0, 0]\n";
    return f.string();
  }();
  const std::string file = mspace::fuzz::write_input("data.csv", data, size).string();
  for (const char* policy : {"error", "skip"}) {
    mspace::records::MalformedRecords m(policy);
    mspace::fuzz::expect_documented_errors_only([&] { is::read_frames_csv(file, mspace::fuzz::scratch(), m); });
    mspace::fuzz::expect_documented_errors_only([&] { is::read_odometry_csv(file, m); });
    mspace::fuzz::expect_documented_errors_only([&] { is::read_laser(yaml, file, m); });
  }
  mspace::fuzz::expect_documented_errors_only([&] { is::read_tum(file); });
  return 0;
}
