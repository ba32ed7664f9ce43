// fuzz_support.hpp — what every libFuzzer harness of tests/fuzz shares.
//
// The readers take file names, so each input is written to a file private to
// the process (in $TMPDIR) and the reader is called on it. A reader may
// refuse an input only with the errors its interface documents —
// std::runtime_error or std::invalid_argument with a message; anything else
// (another exception, a crash, a sanitizer report) is a finding.
#pragma once

#include <unistd.h>

#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <stdexcept>
#include <string>

namespace mspace::fuzz {

/// A scratch folder for this process (made once).
inline const std::filesystem::path& scratch() {
  static const std::filesystem::path dir = [] {
    const char* tmp = std::getenv("TMPDIR");
    std::filesystem::path d =
        std::filesystem::path(tmp != nullptr ? tmp : "/tmp") / ("mspace-fuzz-" + std::to_string(::getpid()));
    std::filesystem::create_directories(d);
    return d;
  }();
  return dir;
}

/// Writes the input to scratch()/name and returns the path.
inline std::filesystem::path write_input(const std::string& name, const std::uint8_t* data, std::size_t size) {
  const std::filesystem::path file = scratch() / name;
  std::ofstream(file, std::ios::binary).write(reinterpret_cast<const char*>(data), static_cast<std::streamsize>(size));
  return file;
}

/// Runs a reader; the documented refusals are fine, the rest propagates.
template <class F>
void expect_documented_errors_only(F&& read) {
  try {
    read();
  } catch (const std::runtime_error&) {
  } catch (const std::invalid_argument&) {
  }
}

}  // namespace mspace::fuzz
