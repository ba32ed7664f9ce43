// numeric_table.cpp — see numeric_table.hpp.
#include "numeric_table.hpp"

#include <fstream>
#include <stdexcept>
#include <string_view>

namespace mspace::victoria_park {

void fail_at(const std::filesystem::path& file, int line, const std::string& problem) {
  throw std::runtime_error(records::at(file.string(), line) + problem);
}

std::vector<NumericRow> read_numeric_table(const std::filesystem::path& file, int columns, const std::string& what,
                                           records::MalformedRecords& malformed) {
  std::ifstream in(file);
  if (!in) throw std::runtime_error(file.string() + ": cannot open (" + what + " expected)");
  std::vector<NumericRow> rows;
  std::string text;
  int line = 0;
  while (std::getline(in, text)) {
    ++line;
    const std::vector<std::string_view> f = records::split(text);
    if (f.empty() || f.front().front() == '#') continue;
    if (static_cast<int>(f.size()) != columns) {
      malformed.report(file.string(), line,
                       "expected " + std::to_string(columns) + " numbers (" + what + "), found " +
                           std::to_string(f.size()) + " fields");
      continue;
    }
    NumericRow row{line, std::vector<double>(static_cast<std::size_t>(columns))};
    bool ok = true;
    for (int c = 0; c < columns && ok; ++c) {
      ok = records::parse_finite(f[c], row.values[c]);
      if (!ok)
        malformed.report(file.string(), line,
                         "field " + std::to_string(c + 1) + " '" + std::string(f[c]) + "' is not a finite number (" +
                             what + ")");
    }
    if (ok) rows.push_back(std::move(row));
  }
  return rows;
}

}  // namespace mspace::victoria_park
