// config/README.md claims to document every key: each key the loader accepts
// (accepted_keys(), from the lists the loader checks against) must appear in
// its "## Keys" block, at the right place in the hierarchy.
#include <gtest/gtest.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <set>
#include <string>
#include <utility>
#include <vector>

#include "config.hpp"

namespace {

/// "a: {b: 1, c: [x, y]}" → {"b", "c"}: the keys of a flow map (top level).
std::vector<std::string> flow_keys(const std::string& flow) {
  std::vector<std::string> keys;
  int depth = 0;
  std::string element;
  auto flush = [&] {
    const auto colon = element.find(':');
    if (colon != std::string::npos) {
      std::string key = element.substr(0, colon);
      key.erase(0, key.find_first_not_of(' '));
      key.erase(key.find_last_not_of(' ') + 1);
      if (!key.empty()) keys.push_back(key);
    }
    element.clear();
  };
  for (const char c : flow) {
    if (c == '{' || c == '[') {
      if (depth++ == 0 && c == '{') continue;
    } else if (c == '}' || c == ']') {
      if (--depth == 0) break;
    } else if (c == ',' && depth == 1) {
      flush();
      continue;
    }
    if (depth >= 1 && !(depth == 1 && (c == '{' || c == '['))) element += c;
  }
  flush();
  return keys;
}

/// The dotted keys of the YAML block under "## Keys" in config/README.md,
/// from indentation (block maps) and {…} values (flow maps); comments skipped.
std::set<std::string> documented_keys() {
  std::ifstream in(std::filesystem::path(MSPACE_SOURCE_DIR) / "config" / "README.md");
  EXPECT_TRUE(in.good());
  std::set<std::string> keys;
  std::vector<std::pair<std::size_t, std::string>> stack;  // (indent, key)
  bool in_section = false, in_block = false;
  for (std::string line; std::getline(in, line);) {
    if (line.rfind("## ", 0) == 0) in_section = line == "## Keys";
    if (!in_section) continue;
    if (line.rfind("```", 0) == 0) {
      if (in_block) break;  // the first block only
      in_block = true;
      continue;
    }
    if (!in_block) continue;
    const std::size_t indent = line.find_first_not_of(' ');
    if (indent == std::string::npos || line[indent] == '#') continue;
    const std::size_t colon = line.find(':', indent);
    if (colon == std::string::npos) continue;
    const std::string key = line.substr(indent, colon - indent);
    while (!stack.empty() && stack.back().first >= indent) stack.pop_back();
    std::string path;
    for (const auto& [i, k] : stack) path += k + ".";
    path += key;
    keys.insert(path);
    std::string value = line.substr(colon + 1);
    value = value.substr(0, value.find('#'));
    const std::size_t brace = value.find('{');
    if (brace != std::string::npos)
      for (const std::string& k : flow_keys(value.substr(brace))) keys.insert(path + "." + k);
    stack.emplace_back(indent, key);
  }
  return keys;
}

TEST(ConfigDocs, FlowKeysAreFound) {
  const std::vector<std::string> expected = {"pose", "sigma"};
  EXPECT_EQ(flow_keys("{pose: [x, y, z], sigma: [6 numbers]}"), expected);
}

TEST(ConfigDocs, EveryAcceptedKeyIsDocumentedInConfigReadme) {
  const std::set<std::string> documented = documented_keys();
  ASSERT_GT(documented.size(), 20u) << "the ## Keys block of config/README.md was not found or not parsed";
  const std::vector<std::string> accepted = mspace::kernel::accepted_keys();
  ASSERT_GT(accepted.size(), 40u);
  for (const std::string& key : accepted)
    EXPECT_TRUE(documented.count(key) == 1) << "config/README.md does not document '" << key << "'";
}

}  // namespace
