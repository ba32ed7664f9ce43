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
  // Only an extension from a dimension > 0 (the planar 2 → 3) has a J_own to check.
  EXPECT_TRUE(passed(r, "feature.extension_J_own"));
  EXPECT_TRUE(passed(r, "feature.save_restore"));
  EXPECT_TRUE(passed(r, "feature.save_restore_future"));
}

TEST(Conformance, WrongJacobianSignFailsTheJacobianChecks) {
  const conformance::Report r = check("broken_sign", MSPACE_CONFORMANCE_FIXTURE_DIR);
  EXPECT_FALSE(r.passed());
  EXPECT_FALSE(passed(r, "feature.J_eta_o"));
  EXPECT_FALSE(passed(r, "feature.J_eta_xp"));
  // J_ηo = −∂h/∂x_o: the error is 2·max|J| / max(1, max|J|), in (1, 2].
  EXPECT_GT(r.find("feature.J_eta_o")->worst, 1.0);
  EXPECT_LT(r.find("feature.J_eta_o")->worst, 2.0 + 1e-6);
  EXPECT_TRUE(passed(r, "feature.B_Bdual_identity"));
  EXPECT_TRUE(passed(r, "feature.J_eta_v"));
}

// B̃ = 2·B_dual fails eq. 12 and, since the point's 2 → 3 extension gives
// J_own with respect to δx_p,old (which B̃ maps to x_f), the extension's J_own
// too: the doubled B̃ doubles the measured ∂z_new/∂δx_p,old. Nothing else.
TEST(Conformance, NonDualBFailsEquation12AndTheExtensionThroughIt) {
  const conformance::Report r = check("broken_dual", MSPACE_CONFORMANCE_FIXTURE_DIR);
  EXPECT_FALSE(r.passed());
  const conformance::CheckResult* dual = r.find("feature.B_Bdual_identity");
  ASSERT_NE(dual, nullptr);
  EXPECT_FALSE(dual->passed);
  EXPECT_DOUBLE_EQ(dual->worst, 1.0);  // B·B̃ = 2·I
  const conformance::CheckResult* own = r.find("feature.extension_J_own");
  ASSERT_NE(own, nullptr);
  EXPECT_FALSE(own->passed);
  EXPECT_TRUE(passed(r, "feature.J_eta_o"));
  EXPECT_TRUE(passed(r, "feature.J_eta_v"));
  EXPECT_TRUE(passed(r, "feature.J_eta_xp"));  // J_ηo J_of B̃ agrees with apply_perturbation's B̃
  EXPECT_EQ(r.failures(), 2);
}

TEST(Conformance, JunitListsEveryCheckAndFailure) {
  const conformance::Report r = check("broken_dual", MSPACE_CONFORMANCE_FIXTURE_DIR);
  std::ostringstream xml;
  conformance::write_junit({r}, xml);
  EXPECT_NE(xml.str().find("<testsuite name=\"broken_dual\" tests=\"" + std::to_string(r.checks.size()) +
                           "\" failures=\"2\""),
            std::string::npos);
  EXPECT_NE(xml.str().find("name=\"feature.B_Bdual_identity\"><failure"), std::string::npos);
}

TEST(Conformance, PluginNameOfFile) {
  EXPECT_EQ(kernel::plugin_name_of_file("/x/libmspace-plugin-point.so"), "point");
  EXPECT_EQ(kernel::plugin_name_of_file("/x/libpoint.so"), "");
}

}  // namespace
