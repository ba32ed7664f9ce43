// The conformance suite itself: the in-tree plugins pass, and the broken
// fixtures fail exactly the checks they break.
#include <gtest/gtest.h>

#include <sstream>
#include <string>

#include <cmath>
#include <numbers>

#include "build_path.hpp"
#include "check.hpp"
#include "mspace/conformance.hpp"
#include "mspace/feature.hpp"
#include "mspace/numeric.hpp"
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
  // J_ηo = −∂h/∂x_o: each row's error is 2·max|J_i| / max|J_i| = 2.
  EXPECT_NEAR(r.find("feature.J_eta_o")->worst, 2.0, 1e-4);
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
  // One per dimension below the largest (a point with dims {0, 3}: 1).
  EXPECT_GE(c->worst, 1.0);
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
  ASSERT_GE(r.costs.size(), 2u);  // innovation, then one "extend from dim D" per dimension that extends
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
                           "\" failures=\"2\""),
            std::string::npos);
  EXPECT_NE(xml.str().find("name=\"feature.B_Bdual_identity\"><failure"), std::string::npos);
}

// ---------------------------------------------------------------- numeric helpers

// f(x) = (x0² x1, sin x1 / x0): central differences with a relative step
// match the analytic Jacobian to ~1e-9 even at x0 = 1e3.
TEST(NumericJacobian, MatchesTheAnalyticJacobianAtEveryScale) {
  for (double scale : {1e-3, 1.0, 1e3}) {
    const Eigen::Vector2d x(scale, 0.7);
    const mspace::NumericFunction f = [](const Eigen::VectorXd& y, Eigen::VectorXd& out) {
      out = Eigen::Vector2d(y[0] * y[0] * y[1], std::sin(y[1]) / y[0]);
      return true;
    };
    Eigen::Matrix2d analytic;
    analytic << 2 * x[0] * x[1], x[0] * x[0], -std::sin(x[1]) / (x[0] * x[0]), std::cos(x[1]) / x[0];
    mspace::NumericOptions o;
    o.scale = x.cwiseAbs();
    const Eigen::MatrixXd J = mspace::numeric_jacobian(mspace::NumericJacobian::other, f, x, o);
    for (int i = 0; i < 2; ++i)
      EXPECT_LT((J.row(i) - analytic.row(i)).cwiseAbs().maxCoeff(), 1e-8 * analytic.row(i).cwiseAbs().maxCoeff())
          << "scale " << scale << " row " << i;
  }
}

// A bearing residual at ±π: without angle_rows the jump of 2π gives a slope
// of ~5e5; with it, the true slope −1.
TEST(NumericJacobian, AngleRowsAreDifferencedWrapped) {
  const mspace::Residual bearing = [](const Eigen::VectorXd& x_o, const Eigen::VectorXd& v, Eigen::VectorXd& eta) {
    eta = Eigen::VectorXd::Constant(1, mspace::wrap_angle(std::atan2(x_o[1], x_o[0]) - v[0]));
    return true;
  };
  const Eigen::Vector2d x_o(1.0, 0.0);
  const Eigen::VectorXd v = Eigen::VectorXd::Constant(1, std::numbers::pi);
  mspace::Innovation wrapped, raw;
  mspace::NumericOptions o;
  o.angle_rows = {0};
  ASSERT_TRUE(mspace::numeric_innovation(bearing, x_o, v, wrapped, mspace::kNumericBoth, o));
  ASSERT_TRUE(mspace::numeric_innovation(bearing, x_o, v, raw));
  EXPECT_NEAR(wrapped.J_eta_v(0, 0), -1.0, 1e-8);
  EXPECT_NEAR(wrapped.J_eta_o(0, 1), 1.0, 1e-8);  // ∂atan2(y, x)/∂y = x/r² = 1
  EXPECT_GT(std::abs(raw.J_eta_v(0, 0)), 1e4);
}

// Only the requested Jacobians are differenced, and the usage is recorded.
TEST(NumericJacobian, RecordsWhatItComputed) {
  const mspace::Residual r = [](const Eigen::VectorXd& x_o, const Eigen::VectorXd& v, Eigen::VectorXd& eta) {
    eta = x_o.head(2) - v;
    return true;
  };
  mspace::reset_numeric_usage();
  mspace::Innovation inn;
  inn.J_eta_v = -Eigen::MatrixXd::Identity(2, 2);
  ASSERT_TRUE(mspace::numeric_innovation(r, Eigen::Vector3d(1, 2, 3), Eigen::Vector2d(0.5, 0.5), inn,
                                         mspace::kNumericEtaO));
  EXPECT_EQ(inn.J_eta_o.rows(), 2);
  EXPECT_EQ(inn.J_eta_o.cols(), 3);
  EXPECT_NEAR(inn.J_eta_o(1, 1), 1.0, 1e-9);
  EXPECT_NEAR(inn.J_eta_o(0, 2), 0.0, 1e-12);
  EXPECT_EQ(mspace::numeric_usage(mspace::NumericJacobian::eta_o).calls, 1);
  EXPECT_EQ(mspace::numeric_usage(mspace::NumericJacobian::eta_o).evaluations, 1 + 2 * 3);
  EXPECT_EQ(mspace::numeric_usage(mspace::NumericJacobian::eta_v).calls, 0);
  mspace::reset_numeric_usage();
  EXPECT_EQ(mspace::numeric_usage(mspace::NumericJacobian::eta_o).calls, 0);
}

// Where one side cannot be evaluated, the one-sided difference is used;
// where neither can, an exception says so.
TEST(NumericJacobian, FallsBackToOneSidedDifferences) {
  const mspace::NumericFunction sqrt_f = [](const Eigen::VectorXd& x, Eigen::VectorXd& out) {
    if (x[0] < 1.0) return false;
    out = Eigen::VectorXd::Constant(1, std::sqrt(x[0]));
    return true;
  };
  const Eigen::MatrixXd J = mspace::numeric_jacobian(mspace::NumericJacobian::other, sqrt_f, Eigen::VectorXd::Ones(1));
  EXPECT_NEAR(J(0, 0), 0.5, 1e-5);
  const mspace::NumericFunction only_at_one = [](const Eigen::VectorXd& x, Eigen::VectorXd& out) {
    out = x;
    return x[0] == 1.0;
  };
  EXPECT_THROW(mspace::numeric_jacobian(mspace::NumericJacobian::other, only_at_one, Eigen::VectorXd::Ones(1)),
               std::runtime_error);
}

// ---- The extractor ↔ feature contract (check_pair, mspace/scene.hpp) ----

conformance::Report check_pair(const std::string& extractor, const std::string& feature,
                               const conformance::Options& options = {}) {
  kernel::PluginRegistry registry;
  registry.add_search_dir(MSPACE_PLUGIN_DIR);
  registry.add_search_dir(MSPACE_CONFORMANCE_FIXTURE_DIR);
  const auto e = registry.load(extractor);
  const auto f = registry.load(feature);
  return conformance::check_pair(*e->descriptor, *f->descriptor, options);
}

TEST(ConformancePair, InTreeExtractorsAgreeWithTheirFeatureTypes) {
  for (const auto& [extractor, feature] : std::vector<std::pair<std::string, std::string>>{
           {"range_bearing", "point"}, {"tree_detections", "pole"}, {"laser_poles", "pole"}, {"laser_lines", "wall"},
           {"lamps", "point"}}) {
    SCOPED_TRACE(extractor + " + " + feature);
    const conformance::Report r = check_pair(extractor, feature);
    std::ostringstream text;
    conformance::print_report(r, text);
    EXPECT_TRUE(r.passed()) << text.str();
    EXPECT_TRUE(passed(r, "pair.kinds"));
    EXPECT_TRUE(passed(r, "pair.truth_innovation"));
    EXPECT_TRUE(passed(r, "pair.truth_found"));
  }
}

TEST(ConformancePair, CreatedFeaturesPredictTheirMeasurement) {
  // Point and pole enter the estimator from repeated detections at one pose.
  EXPECT_TRUE(passed(check_pair("range_bearing", "point"), "pair.created_innovation"));
  EXPECT_TRUE(passed(check_pair("laser_poles", "pole"), "pair.created_innovation"));
}

// The ceiling-line scenes (light strips) with a 0.5° Hough step; at the
// default 2° the extractor misses an edge of the first scene (see
// tests/conformance/CMakeLists.txt).
TEST(ConformancePair, CeilingLinesAgreeWithTheHorizontalLine) {
  conformance::Options options;
  options.params = {{"hough_theta_deg", "0.5"}};
  const conformance::Report r = check_pair("ceiling_lines", "hline", options);
  std::ostringstream text;
  conformance::print_report(r, text);
  EXPECT_TRUE(r.passed()) << text.str();
  EXPECT_TRUE(passed(r, "pair.kinds"));
  EXPECT_TRUE(passed(r, "pair.truth_innovation"));
  EXPECT_TRUE(passed(r, "pair.truth_found"));
}

// The lamps with the image's v axis flipped: well formed alone, wrong with
// the point type (the true lamps do not predict its bearings).
TEST(ConformancePair, FlippedLampsFail) {
  EXPECT_TRUE(check("broken_lamps", MSPACE_CONFORMANCE_FIXTURE_DIR).passed());
  const conformance::Report r = check_pair("broken_lamps", "point");
  EXPECT_FALSE(r.passed());
  EXPECT_FALSE(passed(r, "pair.truth_innovation"));
  EXPECT_TRUE(passed(r, "pair.kinds"));
}

TEST(ConformancePair, FlippedBearingFails) {
  // Alone the flipped extractor is a well-formed extractor…
  EXPECT_TRUE(check("broken_bearing", MSPACE_CONFORMANCE_FIXTURE_DIR).passed());
  // …with the point feature type it is not: the true points do not predict
  // its bearings, and the points it reports are not where the points are.
  const conformance::Report r = check_pair("broken_bearing", "point");
  EXPECT_FALSE(r.passed());
  EXPECT_FALSE(passed(r, "pair.truth_innovation"));
  EXPECT_FALSE(passed(r, "pair.truth_found"));
  EXPECT_TRUE(passed(r, "pair.kinds"));
  // Created from its own measurement the point is self-consistent: a round
  // trip through one plugin cannot see the flip.
  EXPECT_TRUE(passed(r, "pair.created_innovation"));
}

TEST(ConformancePair, MissingHalvesSkipWithAReason) {
  // An extractor without a sample scene.
  const conformance::Report r = check_pair("no_scene", "point");
  const conformance::CheckResult* c = r.find("pair.truth_innovation");
  ASSERT_NE(c, nullptr);
  EXPECT_TRUE(c->skipped);
  EXPECT_NE(c->note.find("sample_scene"), std::string::npos) << c->note;
  // A pole scene given to the wall type: the wall builds nothing from a cylinder.
  const conformance::Report w = check_pair("laser_poles", "wall");
  const conformance::CheckResult* cw = w.find("pair.truth_innovation");
  ASSERT_NE(cw, nullptr);
  EXPECT_TRUE(cw->skipped);
  EXPECT_NE(cw->note.find("vertical_cylinder"), std::string::npos) << cw->note;
}

TEST(ConformancePair, WrongKindsAreRefused) {
  const conformance::Report r = check_pair("point", "range_bearing");
  EXPECT_FALSE(r.passed());
  EXPECT_FALSE(passed(r, "pair.kinds"));
}

// ---- The drawing hook (Feature::drawing) of the SDK example ----

TEST(Drawing, DoorwayDrawsItsJambsAndOpening) {
  kernel::PluginRegistry registry;
  registry.add_search_dir(std::string(MSPACE_CONFORMANCE_FIXTURE_DIR) + "/doorway");
  const auto plugin = registry.load("doorway");
  PluginArgs args;
  args.params = Params::defaults(plugin->descriptor->params);
  const std::unique_ptr<PluginObject> object = plugin->descriptor->factory(args);
  const auto& type = static_cast<const FeatureType&>(*object);
  const std::optional<FeatureSample> s = type.sample(3, 7);
  ASSERT_TRUE(s.has_value());
  const std::optional<FeatureDrawing> d = s->feature->drawing();
  ASSERT_TRUE(d.has_value());
  ASSERT_EQ(d->items.size(), 3u);
  const Eigen::VectorXd& x = s->feature->coords();
  for (int jamb = 0; jamb < 2; ++jamb) {  // a closed square about each jamb
    const DrawingItem& post = d->items[static_cast<std::size_t>(jamb)];
    EXPECT_EQ(post.kind, DrawingItem::Kind::Polygon);
    EXPECT_EQ(post.points.cols(), 4);
    EXPECT_LT((post.points.rowwise().mean() - x.segment<2>(2 * jamb)).norm(), 1e-12);
  }
  const DrawingItem& opening = d->items[2];
  EXPECT_EQ(opening.kind, DrawingItem::Kind::Segments);
  EXPECT_EQ(opening.label, "door");
  EXPECT_LT((opening.points.col(0) - x.segment<2>(0)).norm(), 1e-12);
  EXPECT_LT((opening.points.col(1) - x.segment<2>(2)).norm(), 1e-12);
}

TEST(Conformance, PluginNameOfFile) {
  EXPECT_EQ(kernel::plugin_name_of_file("/x/libmspace-plugin-point.so"), "point");
  EXPECT_EQ(kernel::plugin_name_of_file("/x/libpoint.so"), "");
}

}  // namespace
