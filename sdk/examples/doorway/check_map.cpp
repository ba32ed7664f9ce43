// check_map.cpp — compares a run's map with the simulator's ground truth.
//
//   doorway_check_map CONFIG.yaml OUT_DIR TOLERANCE_M
//
// Reads the true doorways from the `doorways: [...]` line of the run's
// configuration, the mapped doorways from OUT_DIR/map.yaml and the ATE from
// OUT_DIR/summary.yaml. Passes (exit 0) when every true doorway has exactly
// one mapped doorway (dimension ≥ 3) whose jambs are within TOLERANCE_M, at
// least one doorway reached dimension 4, and the ATE RMSE is below TOLERANCE_M.
#include <cmath>
#include <fstream>
#include <iostream>
#include <regex>
#include <sstream>
#include <string>
#include <vector>

namespace {

std::string read(const std::string& file) {
  std::ifstream in(file);
  if (!in) throw std::runtime_error("cannot read " + file);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

std::vector<double> numbers(const std::string& list) {
  std::vector<double> out;
  std::stringstream s(list);
  std::string item;
  while (std::getline(s, item, ',')) out.push_back(std::stod(item));
  return out;
}

struct Door {
  double x1, y1, x2, y2;
  int dim;
};

double jamb_error(const Door& a, const Door& b) {
  return std::max(std::hypot(a.x1 - b.x1, a.y1 - b.y1), std::hypot(a.x2 - b.x2, a.y2 - b.y2));
}

}  // namespace

int main(int argc, char** argv) {
  if (argc != 4) {
    std::cerr << "usage: doorway_check_map CONFIG.yaml OUT_DIR TOLERANCE_M\n";
    return 2;
  }
  const double tol = std::stod(argv[3]);
  std::smatch m;
  const std::string config = read(argv[1]);
  if (!std::regex_search(config, m, std::regex(R"(doorways:\s*\[([^\]]*)\])"))) {
    std::cerr << "no doorways: [...] in " << argv[1] << "\n";
    return 2;
  }
  const std::vector<double> t = numbers(m[1]);
  std::vector<Door> truth;
  for (std::size_t i = 0; i + 3 < t.size(); i += 4) truth.push_back({t[i], t[i + 1], t[i + 2], t[i + 3], 4});

  // map.yaml: each feature has "plugin: doorway", "coords: [...]" and "mspace_dim: N" in this order.
  const std::string map = read(std::string(argv[2]) + "/map.yaml");
  const std::regex feature(R"(plugin:\s*doorway\s[\s\S]*?coords:\s*\[([^\]]*)\][\s\S]*?mspace_dim:\s*(\d+))");
  std::vector<Door> mapped;
  for (std::sregex_iterator it(map.begin(), map.end(), feature), end; it != end; ++it) {
    const std::vector<double> c = numbers((*it)[1]);
    const int dim = std::stoi((*it)[2]);
    if (c.size() == 4 && dim >= 3) mapped.push_back({c[0], c[1], c[2], c[3], dim});
  }

  bool ok = true;
  int full = 0;
  for (const Door& d : mapped) full += d.dim == 4 ? 1 : 0;
  for (const Door& d : truth) {
    int matches = 0;
    double best = INFINITY;
    for (const Door& e : mapped) {
      best = std::min(best, jamb_error(d, e));
      matches += jamb_error(d, e) < tol ? 1 : 0;
    }
    std::cout << "doorway (" << d.x1 << ", " << d.y1 << ")–(" << d.x2 << ", " << d.y2 << "): nearest mapped jamb error "
              << best << " m, " << matches << " match(es)\n";
    ok = ok && matches == 1;
  }
  std::cout << mapped.size() << " doorways mapped (" << full << " with the width estimated)\n";
  ok = ok && mapped.size() == truth.size() && full > 0;

  const std::string summary = read(std::string(argv[2]) + "/summary.yaml");
  if (!std::regex_search(summary, m, std::regex(R"(ate_rmse_m:\s*([0-9.eE+-]+))"))) {
    std::cerr << "no ate_rmse_m in summary.yaml\n";
    return 1;
  }
  const double ate = std::stod(m[1]);
  std::cout << "ATE RMSE " << ate << " m (tolerance " << tol << ")\n";
  ok = ok && ate < tol;
  std::cout << (ok ? "PASS" : "FAIL") << "\n";
  return ok ? 0 : 1;
}
