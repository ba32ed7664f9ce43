// numeric_table.cpp — see numeric_table.hpp.
#include "numeric_table.hpp"

#include <charconv>
#include <cmath>
#include <fstream>
#include <sstream>
#include <stdexcept>
#include <string_view>

namespace mspace::victoria_park {
namespace {

bool is_space(char c) { return c == ' ' || c == '\t' || c == '\r'; }

/// Splits a line into its fields (runs of non-blank characters).
std::vector<std::string_view> fields(std::string_view line) {
  std::vector<std::string_view> out;
  std::size_t i = 0;
  while (i < line.size()) {
    while (i < line.size() && is_space(line[i])) ++i;
    const std::size_t start = i;
    while (i < line.size() && !is_space(line[i])) ++i;
    if (i > start) out.push_back(line.substr(start, i - start));
  }
  return out;
}

/// The whole field as a finite double, or false.
bool parse_double(std::string_view field, double& value) {
  const char* end = field.data() + field.size();
  const auto [ptr, ec] = std::from_chars(field.data(), end, value);
  return ec == std::errc() && ptr == end && std::isfinite(value);
}

}  // namespace

void fail_at(const std::filesystem::path& file, int line, const std::string& problem) {
  throw std::runtime_error(file.string() + ":" + std::to_string(line) + ": " + problem);
}

std::vector<NumericRow> read_numeric_table(const std::filesystem::path& file, int columns, const std::string& what) {
  std::ifstream in(file);
  if (!in) throw std::runtime_error(file.string() + ": cannot open (" + what + " expected)");
  std::vector<NumericRow> rows;
  std::string text;
  int line = 0;
  while (std::getline(in, text)) {
    ++line;
    const std::vector<std::string_view> f = fields(text);
    if (f.empty() || f.front().front() == '#') continue;
    if (static_cast<int>(f.size()) != columns) {
      fail_at(file, line, "expected " + std::to_string(columns) + " numbers (" + what + "), found " +
                              std::to_string(f.size()) + " fields");
    }
    NumericRow row{line, std::vector<double>(static_cast<std::size_t>(columns))};
    for (int c = 0; c < columns; ++c) {
      if (!parse_double(f[c], row.values[c])) {
        fail_at(file, line, "field " + std::to_string(c + 1) + " '" + std::string(f[c]) +
                                "' is not a finite number (" + what + ")");
      }
    }
    rows.push_back(std::move(row));
  }
  return rows;
}

}  // namespace mspace::victoria_park
