// numeric_table.hpp — reading whitespace-separated numeric text files, one
// record per line, with errors that name the file and the line.
#pragma once

#include <filesystem>
#include <string>
#include <vector>

#include "mspace/records.hpp"

namespace mspace::victoria_park {

/// One data line: its 1-based line number and its numbers.
struct NumericRow {
  int line = 0;
  std::vector<double> values;
};

/// Reads `file`: blank lines and lines starting with '#' are skipped, Windows
/// line ends are accepted, separators are spaces and tabs. Every other line
/// must hold exactly `columns` finite numbers; a line that does not is
/// reported to `malformed` ("<file>:<line>: <problem>": an error, or a counted
/// skip). Throws std::runtime_error "<file>: cannot open" when unreadable.
/// `what` names the columns in messages, e.g. "time_ms speed steering".
std::vector<NumericRow> read_numeric_table(const std::filesystem::path& file, int columns, const std::string& what,
                                           records::MalformedRecords& malformed);

/// Throws std::runtime_error "<file>:<line>: <problem>".
[[noreturn]] void fail_at(const std::filesystem::path& file, int line, const std::string& problem);

}  // namespace mspace::victoria_park
