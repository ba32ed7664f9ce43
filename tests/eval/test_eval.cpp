// Tests of `mspace eval` (kernel/src/eval_command.hpp) on small synthetic
// files whose answers are known in closed form, the bad files a user can give
// it, and the command line tool itself.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <numbers>
#include <sstream>
#include <string>
#include <sys/wait.h>

#include "build_path.hpp"
#include "eval_command.hpp"

namespace mspace::kernel {
namespace {

namespace fs = std::filesystem;
constexpr double kDeg = std::numbers::pi / 180.0;

class Eval : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() /
           ("mspace_eval_" + std::string(::testing::UnitTest::GetInstance()->current_test_info()->name()));
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }

  fs::path write(const std::string& name, const std::string& text) const {
    const fs::path file = dir_ / name;
    std::ofstream(file) << text;
    return file;
  }

  /// The message of the std::runtime_error `f` throws ("" if none).
  template <class F>
  static std::string error_of(F f) {
    try {
      f();
    } catch (const std::runtime_error& e) {
      return e.what();
    }
    return "";
  }

  fs::path dir_;
};

std::string tum_line(double t, double x, double y, double yaw) {
  char buf[200];
  std::snprintf(buf, sizeof buf, "%.6f %.9f %.9f 0 0 0 %.12f %.12f\n", t, x, y, std::sin(yaw / 2), std::cos(yaw / 2));
  return buf;
}

// ---- reading ---------------------------------------------------------------

TEST_F(Eval, ReadsTumAndPlanarFilesWithTheirHeadings) {
  const fs::path tum = write("a.tum", "# t x y z qx qy qz qw\n\n" + tum_line(2.0, 1.0, 2.0, 30 * kDeg) +
                                          tum_line(1.0, -1.0, 0.5, -170 * kDeg));
  const auto poses = read_trajectory_file(tum);
  ASSERT_EQ(poses.size(), 2u);
  EXPECT_DOUBLE_EQ(poses[0].t, 1.0);  // sorted by time
  EXPECT_NEAR(poses[0].pose[kX], -1.0, 1e-12);
  EXPECT_NEAR(poses[0].pose[kTheta], -170 * kDeg, 1e-9);
  EXPECT_NEAR(poses[1].pose[kTheta], 30 * kDeg, 1e-9);
  EXPECT_NEAR(poses[1].pose[kY], 2.0, 1e-12);

  const fs::path planar = write("b.txt", "# t x y theta\n5 1 2 3.5\n");
  const auto p = read_trajectory_file(planar);
  ASSERT_EQ(p.size(), 1u);
  EXPECT_NEAR(p[0].pose[kTheta], 3.5 - 2 * std::numbers::pi, 1e-12);  // wrapped
}

TEST_F(Eval, BadTrajectoryFilesNameTheFileAndLine) {
  struct Case {
    std::string name, text, expected;
  };
  const Case cases[] = {
      {"width.tum", "# header\n0 0 0 0 0 0 0 1\n1 0 0 0 0 0 1\n", "width.tum:3: expected 8 fields"},
      {"five.tum", "0 1 2 3 4\n", "five.tum:1: expected a TUM pose"},
      {"nan.txt", "0 0 0 0\n1 nan 0 0\n", "nan.txt:2: field 2 ('nan') is not a finite number"},
      {"text.txt", "0 0 0 0\n\n1 0 zero 0\n", "text.txt:3: field 3 ('zero')"},
      {"quat.tum", "0 0 0 0 1 0 0 1\n", "quat.tum:1: the quaternion"},
      {"empty.tum", "# only a header\n", "empty.tum: no pose"},
  };
  for (const Case& c : cases) {
    const fs::path file = write(c.name, c.text);
    const std::string message = error_of([&] { read_trajectory_file(file); });
    EXPECT_NE(message.find(c.expected), std::string::npos) << c.name << ": " << message;
  }
  const std::string missing = error_of([&] { read_trajectory_file(dir_ / "absent.tum"); });
  EXPECT_NE(missing.find("absent.tum: cannot open"), std::string::npos) << missing;
}

// ---- ATE -------------------------------------------------------------------

// The reference is the square (±1, ±1); the estimate is it scaled by 1.1,
// turned by 30° and moved by (5, −2). The SE(2) alignment undoes the turn and
// the move but not the scale, so every corner is 0.1·√2 m off.
TEST_F(Eval, AteOfAScaledSquareIsKnown) {
  const double corners[4][2] = {{1, 1}, {-1, 1}, {-1, -1}, {1, -1}};
  std::string ref = "# t x y theta\n", est;
  const double c = std::cos(30 * kDeg), s = std::sin(30 * kDeg);
  for (int i = 0; i < 4; ++i) {
    const double x = corners[i][0], y = corners[i][1];
    ref += std::to_string(i) + " " + std::to_string(x) + " " + std::to_string(y) + " 0\n";
    est += tum_line(i, 1.1 * (c * x - s * y) + 5, 1.1 * (s * x + c * y) - 2, 30 * kDeg);
  }
  EvalOptions o;
  o.estimate = write("est.tum", est);
  o.reference = write("ref.txt", ref);
  const EvalResult r = evaluate_files(o);
  ASSERT_TRUE(r.ate);
  EXPECT_EQ(r.ate->matched, 4u);
  EXPECT_NEAR(r.ate->ate_rmse, 0.1 * std::sqrt(2.0), 1e-6);
  EXPECT_NEAR(r.ate->ate_median, 0.1 * std::sqrt(2.0), 1e-6);
  EXPECT_NEAR(r.ate->ate_max, 0.1 * std::sqrt(2.0), 1e-6);
  EXPECT_FALSE(r.relations_all);
}

// Reference poses between two estimate poses are paired with the estimate
// interpolated there, when those are at most max_gap apart; none paired is an
// error, not a zero.
TEST_F(Eval, AtePairsByTimeAndRefusesDisjointTimes) {
  EvalOptions o;
  o.estimate = write("est.txt", "0 0 0 0\n2 2 0 0\n");
  o.reference = write("ref.txt", "1 1 0 0\n1.5 1.5 0 0\n");
  std::string message = error_of([&] { evaluate_files(o); });  // the estimate's poses are 2 s apart
  EXPECT_NE(message.find("at most 1.000000 s apart"), std::string::npos) << message;
  o.max_gap = 2.5;
  const EvalResult r = evaluate_files(o);
  EXPECT_EQ(r.ate->matched, 2u);
  EXPECT_NEAR(r.ate->ate_rmse, 0.0, 1e-12);

  o.reference = write("late.txt", "100 1 0 0\n101 1.5 0 0\n");
  message = error_of([&] { evaluate_files(o); });
  EXPECT_NE(message.find("no pose of the reference"), std::string::npos) << message;
  EXPECT_NE(message.find("late.txt"), std::string::npos) << message;
}

// ---- relations -------------------------------------------------------------

// The robot drives along x at 0.5 m/s, a pose a second for 120 s; from t = 100
// on the estimate is 0.3 m off sideways. Short relations (i, i+1): only
// (99, 100) errs, by 0.3 m; the three long ones (0, 100), (10, 110), (20, 120)
// all do.
TEST_F(Eval, RelationsAreSplitIntoShortAndLongWithKnownErrors) {
  std::string est, rel = "# t1 t2 x y z roll pitch yaw\n";
  for (int i = 0; i <= 120; ++i) est += tum_line(i, 0.5 * i, i >= 100 ? 0.3 : 0.0, 0.0);
  for (int i = 0; i < 120; ++i) rel += std::to_string(i) + " " + std::to_string(i + 1) + " 0.5 0 0 0 0 0\n";
  for (int i : {0, 10, 20}) rel += std::to_string(i) + " " + std::to_string(i + 100) + " 50 0 0 0 0 0\n";
  rel += "500 501 0.5 0 0 0 0 0\n";  // outside the estimate: counted, not scored
  EvalOptions o;
  o.estimate = write("est.tum", est);
  o.relations = write("rel.relations", rel);
  const EvalResult r = evaluate_files(o);
  ASSERT_TRUE(r.relations_all && r.relations_short && r.relations_long);
  EXPECT_FALSE(r.ate);
  EXPECT_EQ(r.relations_all->total, 124u);
  EXPECT_EQ(r.relations_all->matched, 123u);
  EXPECT_NEAR(r.relations_all->translation.mean, 4 * 0.3 / 123, 1e-9);
  EXPECT_EQ(r.relations_short->total, 121u);
  EXPECT_EQ(r.relations_short->matched, 120u);
  EXPECT_NEAR(r.relations_short->translation.mean, 0.3 / 120, 1e-9);
  // Population std of one 0.3 among 120: sqrt(0.09/120 − (0.3/120)²).
  EXPECT_NEAR(r.relations_short->translation.std, std::sqrt(0.09 / 120 - std::pow(0.3 / 120, 2)), 1e-9);
  EXPECT_EQ(r.relations_long->matched, 3u);
  EXPECT_NEAR(r.relations_long->translation.mean, 0.3, 1e-9);
  EXPECT_NEAR(r.relations_long->translation.std, 0.0, 1e-9);
  EXPECT_NEAR(r.relations_long->rotation_deg.mean, 0.0, 1e-6);

  // A longer threshold moves them all to the short ones.
  o.long_seconds = 150;
  const EvalResult r2 = evaluate_files(o);
  EXPECT_EQ(r2.relations_long->matched, 0u);
  EXPECT_EQ(r2.relations_short->matched, 123u);
}

TEST_F(Eval, RelationsThatMissTheEstimateAndBadRelationFilesAreErrors) {
  EvalOptions o;
  o.estimate = write("est.txt", "0 0 0 0\n1 1 0 0\n");
  o.relations = write("far.relations", "10 11 1 0 0 0 0 0\n");
  std::string message = error_of([&] { evaluate_files(o); });
  EXPECT_NE(message.find("none of the 1 relations of"), std::string::npos) << message;

  // Stamps 0.01 s off: outside the default tolerance (1e-4 s), inside 0.02 s.
  o.relations = write("off.relations", "0.01 1.01 1 0 0 0 0 0\n");
  EXPECT_NE(error_of([&] { evaluate_files(o); }), "");
  o.relations_max_dt = 0.02;
  EXPECT_EQ(evaluate_files(o).relations_all->matched, 1u);

  o.relations = write("bad.relations", "# ok\n0 1 1 0 0 0 0 0\n0 1 1 0 0 0 0\n");
  message = error_of([&] { evaluate_files(o); });
  EXPECT_NE(message.find("bad.relations:3:"), std::string::npos) << message;

  o.relations.clear();
  message = error_of([&] { evaluate_files(o); });
  EXPECT_NE(message.find("nothing to evaluate"), std::string::npos) << message;
}

// ---- the command line tool -------------------------------------------------

struct Output {
  int exit_code = -1;
  std::string text;  ///< stdout and stderr
};

Output run_mspace(const std::string& args) {
  Output out;
  FILE* pipe = popen((std::string(MSPACE_EXE) + " " + args + " 2>&1").c_str(), "r");
  if (pipe == nullptr) return out;
  char buf[4096];
  for (std::size_t n; (n = std::fread(buf, 1, sizeof buf, pipe)) > 0;) out.text.append(buf, n);
  const int status = pclose(pipe);
  out.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  return out;
}

TEST_F(Eval, CommandPrintsAndWritesTheFigures) {
  std::string est, ref, rel;
  for (int i = 0; i <= 70; ++i) {
    est += tum_line(i, 0.5 * i, i >= 65 ? 0.2 : 0.0, 0.0);
    ref += std::to_string(i) + " " + std::to_string(0.5 * i) + " 0 0\n";
  }
  rel = "0 1 0.5 0 0 0 0 0\n0 65 32.5 0 0 0 0 0\n";
  const fs::path e = write("est.tum", est), f = write("ref.txt", ref), r = write("rel.relations", rel);
  const fs::path yaml = dir_ / "eval.yaml";
  const Output out = run_mspace("eval " + e.string() + " --reference " + f.string() + " --relations " + r.string() +
                                " --yaml " + yaml.string());
  ASSERT_EQ(out.exit_code, 0) << out.text;
  EXPECT_NE(out.text.find("71 reference poses paired"), std::string::npos) << out.text;
  EXPECT_NE(out.text.find("long (≥ 60 s) (1 of 1 matched): translation 0.2 ± 0 m"), std::string::npos) << out.text;
  std::ifstream in(yaml);
  std::stringstream written;
  written << in.rdbuf();
  EXPECT_NE(written.str().find("relations_long_translation_mean_m: 0.2\n"), std::string::npos) << written.str();
  EXPECT_NE(written.str().find("relations_short_translation_mean_m: 0\n"), std::string::npos) << written.str();
  EXPECT_NE(written.str().find("ate_matched: 71\n"), std::string::npos) << written.str();
}

TEST_F(Eval, CommandFailsWithTheFileAndLineOfABadFile) {
  const fs::path bad = write("bad.tum", "0 0 0 0 0 0 0 1\n1 0 0 x 0 0 0 1\n");
  const fs::path rel = write("rel.relations", "0 1 0 0 0 0 0 0\n");
  Output out = run_mspace("eval " + bad.string() + " --relations " + rel.string());
  EXPECT_EQ(out.exit_code, 1) << out.text;
  EXPECT_NE(out.text.find("bad.tum:2: field 4 ('x') is not a finite number"), std::string::npos) << out.text;
  out = run_mspace("eval " + bad.string());
  EXPECT_EQ(out.exit_code, 1) << out.text;
  EXPECT_NE(out.text.find("nothing to evaluate"), std::string::npos) << out.text;
}

}  // namespace
}  // namespace mspace::kernel
