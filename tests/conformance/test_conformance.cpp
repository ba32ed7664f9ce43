// The conformance suite itself: the in-tree plugins pass, and the broken
// fixtures fail exactly the checks they break.
#include <gtest/gtest.h>

#include <sstream>
#include <string>

#include "check.hpp"
#include "mspace/conformance.hpp"
#include "plugin_registry.hpp"

namespace {

using namespace mspace;

conformance::Report check(const std::string& name, const std::string& dir) {
  kernel::PluginRegistry registry;
  registry.add_search_dir(dir);
  const auto plugin = registry.load(name);
  return conformance::check_plugin(*plugin->descriptor);
}

bool passed(const conformance::Report& r, const std::string& check) {
  const conformance::CheckResult* c = r.find(check);
  EXPECT_NE(c, nullptr) << check;
  return c != nullptr && c->passed && !c->skipped;
}

TEST(Conformance, PointPassesEveryCheck) {
  const conformance::Report r = check("point", MSPACE_PLUGIN_DIR);
  EXPECT_TRUE(r.passed());
  EXPECT_TRUE(passed(r, "feature.J_eta_o"));
  EXPECT_TRUE(passed(r, "feature.extension_J_sensor"));
  EXPECT_TRUE(passed(r, "feature.save_restore"));
}

TEST(Conformance, WrongJacobianSignFailsTheJacobianChecks) {
  const conformance::Report r = check("broken_sign", MSPACE_CONFORMANCE_FIXTURE_DIR);
  EXPECT_FALSE(r.passed());
  EXPECT_FALSE(passed(r, "feature.J_eta_o"));
  EXPECT_FALSE(passed(r, "feature.J_eta_xp"));
  // J_ηo = −∂h/∂x_o: each row's error is 2·max|J_i| / max|J_i| = 2.
  EXPECT_NEAR(r.find("feature.J_eta_o")->worst, 2.0, 1e-4);
  EXPECT_TRUE(passed(r, "feature.B_Bdual_identity"));
  EXPECT_TRUE(passed(r, "feature.J_eta_v"));
}

TEST(Conformance, NonDualBFailsEquation12Only) {
  const conformance::Report r = check("broken_dual", MSPACE_CONFORMANCE_FIXTURE_DIR);
  EXPECT_FALSE(r.passed());
  const conformance::CheckResult* dual = r.find("feature.B_Bdual_identity");
  ASSERT_NE(dual, nullptr);
  EXPECT_FALSE(dual->passed);
  EXPECT_DOUBLE_EQ(dual->worst, 1.0);  // B·B̃ = 2·I
  EXPECT_TRUE(passed(r, "feature.J_eta_o"));
  EXPECT_TRUE(passed(r, "feature.J_eta_v"));
  EXPECT_EQ(r.failures(), 1);
}

TEST(Conformance, PointExercisesTheExtensionAndGatingChecks) {
  const conformance::Report r = check("point", MSPACE_PLUGIN_DIR);
  for (const char* name : {"feature.extension_reached", "feature.extension_C_new", "feature.gating_covariance"})
    EXPECT_TRUE(passed(r, name)) << name;
  EXPECT_LT(r.find("feature.extension_C_new")->worst, 1e-6);
  EXPECT_LT(r.find("feature.gating_covariance")->worst, 1e-6);
}

// Wall ends (2 → 3 → 4) and hline positions (1 → 3) extend only from
// observations that differ (real ends, a baseline): sample_observation()
// provides them, so these extensions are checked instead of skipped.
TEST(Conformance, MovingObservationsReachEveryDimension) {
  for (const char* type : {"wall", "hline"}) {
    const conformance::Report r = check(type, MSPACE_PLUGIN_DIR);
    EXPECT_TRUE(r.passed()) << type;
    EXPECT_TRUE(passed(r, "feature.extension_reached")) << type;
    EXPECT_TRUE(passed(r, "feature.extension_J_own")) << type;
    EXPECT_TRUE(passed(r, "feature.extension_C_new")) << type;
    EXPECT_EQ(r.find("feature.extension_reached")->note.find(": 0/"), std::string::npos) << type;
  }
}

TEST(Conformance, InflatedCnewFailsTheCovarianceCheck) {
  const conformance::Report r = check("broken_cnew", MSPACE_CONFORMANCE_FIXTURE_DIR);
  const conformance::CheckResult* c = r.find("feature.extension_C_new");
  ASSERT_NE(c, nullptr);
  EXPECT_FALSE(c->passed);
  EXPECT_NEAR(c->worst, 49.0, 1e-3);  // every generalised eigenvalue is 50
  EXPECT_TRUE(passed(r, "feature.extension_C_new_spd"));  // what used to be the only check
  EXPECT_TRUE(passed(r, "feature.extension_J_sensor"));
  EXPECT_EQ(r.failures(), 1);
}

TEST(Conformance, NoExtensionFailsInsteadOfSkipping) {
  const conformance::Report r = check("broken_never", MSPACE_CONFORMANCE_FIXTURE_DIR);
  const conformance::CheckResult* c = r.find("feature.extension_reached");
  ASSERT_NE(c, nullptr);
  EXPECT_FALSE(c->passed);
  EXPECT_FALSE(c->skipped);
  EXPECT_EQ(c->worst, 1.0);  // dim 0 → 3 never happens
  EXPECT_NE(c->note.find("from dim 0: 0/8"), std::string::npos) << c->note;
  EXPECT_EQ(r.failures(), 1);
}

TEST(Conformance, InflatedGatingCovarianceFails) {
  const conformance::Report r = check("broken_gating", MSPACE_CONFORMANCE_FIXTURE_DIR);
  const conformance::CheckResult* c = r.find("feature.gating_covariance");
  ASSERT_NE(c, nullptr);
  EXPECT_FALSE(c->passed);
  EXPECT_NEAR(c->worst, 49.0, 1e-3);
  EXPECT_EQ(r.failures(), 1);
}

// η, J_ηo and J_ηv are all ~1e-6: the old tolerance (1e-5 × max(1, |J|))
// passed the wrong sign (error 2e-6·|J| < 1e-5). Per row, relative to
// max(|J_i|, kRowFloor = 1e-3), the error is 2e-6·|J_i|/1e-3 ≈ 2e-3: 200× the
// tolerance (rows above the floor are compared fully relatively: 2).
TEST(Conformance, SmallJacobiansAreComparedRelativeToTheirSize) {
  const conformance::Report r = check("broken_small", MSPACE_CONFORMANCE_FIXTURE_DIR);
  const conformance::CheckResult* c = r.find("feature.J_eta_o");
  ASSERT_NE(c, nullptr);
  EXPECT_FALSE(c->passed);
  EXPECT_GT(c->worst, 100 * c->tolerance);
  EXPECT_TRUE(passed(r, "feature.J_eta_v"));          // consistently scaled: right
  EXPECT_TRUE(passed(r, "feature.sample_consistent"));  // NIS does not see the units
}

TEST(Conformance, CostsSayWhatIsAnalytic) {
  const conformance::Report r = check("point", MSPACE_PLUGIN_DIR);
  ASSERT_EQ(r.costs.size(), 2u);
  const conformance::Cost& inn = r.costs[0];
  EXPECT_EQ(inn.function, "innovation");
  EXPECT_TRUE(inn.numeric.empty());
  EXPECT_EQ(inn.analytic, (std::vector<std::string>{"J_eta_o", "J_eta_v"}));
  EXPECT_GT(inn.micros, 0.0);
  EXPECT_GT(inn.micros_by_differences, inn.micros);
  EXPECT_EQ(r.costs[1].function, "extend from dim 0");
  EXPECT_EQ(r.costs[1].analytic, (std::vector<std::string>{"J_sensor"}));
}

TEST(Conformance, JunitListsEveryCheckAndFailure) {
  const conformance::Report r = check("broken_dual", MSPACE_CONFORMANCE_FIXTURE_DIR);
  std::ostringstream xml;
  conformance::write_junit({r}, xml);
  EXPECT_NE(xml.str().find("<testsuite name=\"broken_dual\" tests=\"" + std::to_string(r.checks.size()) +
                           "\" failures=\"1\""),
            std::string::npos);
  EXPECT_NE(xml.str().find("name=\"feature.B_Bdual_identity\"><failure"), std::string::npos);
}

TEST(Conformance, PluginNameOfFile) {
  EXPECT_EQ(kernel::plugin_name_of_file("/x/libmspace-plugin-point.so"), "point");
  EXPECT_EQ(kernel::plugin_name_of_file("/x/libpoint.so"), "");
}

}  // namespace
