// mspace/records.hpp — what every data reader shares: splitting a text record
// into fields, reading a field as a finite number, and the `on_malformed`
// policy (docs/reliability.md, "Strict readers").
//
// A data reader checks each record's width against its header or its first
// record and every numeric field for finiteness; a record that fails is an
// error "file:line: problem", or — when the source's `on_malformed` parameter
// is `skip` — it is left out, counted (DataSource::skipped_records, the run
// summary's skipped_input_records) and the first problem is kept for the log.
// Files used only to evaluate a run (ground truth, relations) are always
// strict: skipping in them would quietly change a metric.
#pragma once

#include <cstddef>
#include <string>
#include <string_view>
#include <vector>

#include "mspace/params.hpp"

namespace mspace::records {

/// The fields of a record: runs of characters between separators. With
/// separator ' ' any run of spaces, tabs and '\r' separates (and empty fields
/// do not exist); with another separator (e.g. ',') every separator ends a
/// field, so "1,,2" has an empty middle field, and each field is trimmed of
/// blanks.
std::vector<std::string_view> split(std::string_view record, char separator = ' ');

/// The whole field as a finite double (no NaN, no infinity, no trailing
/// characters); false otherwise.
bool parse_finite(std::string_view field, double& value);

/// "file:line: ".
std::string at(const std::string& file, int line);

/// The `on_malformed` parameter every reading source declares alike.
ParamSpec on_malformed_param();

/// The policy of one source: error (throw) or skip (count).
class MalformedRecords {
 public:
  /// `policy`: the value of on_malformed ("error" or "skip").
  explicit MalformedRecords(const std::string& policy = "error");
  /// A malformed record: throws std::runtime_error("file:line: problem")
  /// when failing, else counts it (and keeps the first message).
  void report(const std::string& file, int line, const std::string& problem);
  bool skipping() const { return skip_; }
  std::size_t skipped() const { return skipped_; }
  /// "file:line: problem" of the first skipped record (empty: none).
  const std::string& first_problem() const { return first_; }

 private:
  bool skip_ = false;
  std::size_t skipped_ = 0;
  std::string first_;
};

}  // namespace mspace::records
