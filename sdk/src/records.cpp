// records.cpp — see mspace/records.hpp.
#include "mspace/records.hpp"

#include <charconv>
#include <cmath>
#include <stdexcept>

namespace mspace::records {
namespace {

bool is_blank(char c) { return c == ' ' || c == '\t' || c == '\r'; }

std::string_view trimmed(std::string_view s) {
  while (!s.empty() && is_blank(s.front())) s.remove_prefix(1);
  while (!s.empty() && is_blank(s.back())) s.remove_suffix(1);
  return s;
}

}  // namespace

std::vector<std::string_view> split(std::string_view record, char separator) {
  std::vector<std::string_view> out;
  if (separator == ' ') {
    std::size_t i = 0;
    while (i < record.size()) {
      while (i < record.size() && is_blank(record[i])) ++i;
      const std::size_t start = i;
      while (i < record.size() && !is_blank(record[i])) ++i;
      if (i > start) out.push_back(record.substr(start, i - start));
    }
    return out;
  }
  std::size_t start = 0;
  for (std::size_t i = 0; i <= record.size(); ++i)
    if (i == record.size() || record[i] == separator) {
      out.push_back(trimmed(record.substr(start, i - start)));
      start = i + 1;
    }
  return out;
}

bool parse_finite(std::string_view field, double& value) {
  const char* end = field.data() + field.size();
  const auto [ptr, ec] = std::from_chars(field.data(), end, value);
  return !field.empty() && ec == std::errc() && ptr == end && std::isfinite(value);
}

std::string at(const std::string& file, int line) { return file + ":" + std::to_string(line) + ": "; }

ParamSpec on_malformed_param() {
  return param_string("on_malformed", "error",
                      "a malformed data record (wrong width, a field that is not a finite number, time going "
                      "backwards or repeated) is an error naming file and line, or is skipped, logged and counted "
                      "in the summary's skipped_input_records",
                      {"error", "skip"});
}

MalformedRecords::MalformedRecords(const std::string& policy) : skip_(policy == "skip") {}

void MalformedRecords::report(const std::string& file, int line, const std::string& problem) {
  std::string message = at(file, line) + problem;
  if (!skip_) throw std::runtime_error(message);
  if (skipped_++ == 0) first_ = std::move(message);
}

}  // namespace mspace::records
