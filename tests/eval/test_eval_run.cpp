// `mspace eval` on the files a run wrote gives the figures of the run's own
// summary: the ATE of trajectory.tum against ground_truth.tum and the
// relations of the configuration's relations file. A short config/sim_building
// run on the building tests/evo generates.
#include <gtest/gtest.h>

#include <cstdlib>
#include <filesystem>
#include <sstream>
#include <string>
#include <yaml-cpp/yaml.h>

#include "build_path.hpp"

namespace {

namespace fs = std::filesystem;

TEST(EvalRun, SameFiguresAsTheRunSummary) {
  const fs::path building = EVAL_BUILDING;
  if (!fs::exists(building / "building.clf"))
    GTEST_SKIP() << "no generated building in " << building << " (CTest fixture evo_sim_building_data)";
  const fs::path out = fs::path(EVAL_OUT) / "sim_building";
  fs::remove_all(out);
  fs::create_directories(out);
  std::ostringstream run;
  run << "cd '" << MSPACE_SOURCE_DIR << "' && MSPACE_SIM_BUILDING='" << building.string() << "' '" << MSPACE_EXE
      << "' run config/sim_building.yaml --out '" << out.string() << "' --max-steps 600 --quiet > '"
      << (out / "run.log").string() << "' 2>&1";
  ASSERT_EQ(std::system(run.str().c_str()), 0) << run.str();
  std::ostringstream eval;
  eval << "'" << MSPACE_EXE << "' eval '" << (out / "trajectory.tum").string() << "' --reference '"
       << (out / "ground_truth.tum").string() << "' --relations '" << (building / "building.relations").string()
       << "' --yaml '" << (out / "eval.yaml").string() << "' > '" << (out / "eval.log").string() << "' 2>&1";
  ASSERT_EQ(std::system(eval.str().c_str()), 0) << eval.str();

  const YAML::Node summary = YAML::LoadFile((out / "summary.yaml").string());
  const YAML::Node figures = YAML::LoadFile((out / "eval.yaml").string());
  const double ate = summary["ground_truth"]["ate_rmse_m"].as<double>();
  EXPECT_NEAR(figures["ate_rmse_m"].as<double>(), ate, 1e-6 * ate);
  EXPECT_EQ(figures["ate_matched"].as<std::size_t>(), summary["ground_truth"]["poses_compared"].as<std::size_t>());
  const YAML::Node rel = summary["relations"];
  ASSERT_TRUE(rel) << "the run's summary has no relations";
  EXPECT_EQ(figures["relations_all_matched"].as<std::size_t>(), rel["matched"].as<std::size_t>());
  const double mean = rel["translation_m"]["mean"].as<double>();
  EXPECT_GT(rel["matched"].as<std::size_t>(), 10u);
  EXPECT_NEAR(figures["relations_all_translation_mean_m"].as<double>(), mean, 1e-5 * mean);
  EXPECT_NEAR(figures["relations_all_rotation_mean_deg"].as<double>(), rel["rotation_deg"]["mean"].as<double>(),
              1e-5 * rel["rotation_deg"]["mean"].as<double>() + 1e-9);
  // Short and long relations partition all of them.
  EXPECT_EQ(figures["relations_short_matched"].as<std::size_t>() + figures["relations_long_matched"].as<std::size_t>(),
            rel["matched"].as<std::size_t>());
}

}  // namespace
