// Map files (kernel/src/persistence.cpp, docs/persistence.md): every in-tree
// feature type (point, wall, hline, pole and the SDK example doorway) at every
// reachable M-space dimension goes through its plugin's save() into map.bin
// and back through FeatureType::restore() bit for bit, dense information
// included; a restored feature fed the same measurements behaves exactly as
// the original; damaged, truncated and foreign files fail with errors that
// name the file, the feature and the plugin; and a run writes map.bin.
#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iterator>
#include <memory>
#include <string>
#include <vector>

#include "build_path.hpp"
#include "config.hpp"
#include "doorway_feature.hpp"
#include "hline_feature.hpp"
#include "logging.hpp"
#include "mspace/abi.hpp"
#include "mspace/conformance.hpp"
#include "mspace/transform.hpp"
#include "persistence.hpp"
#include "plugin_registry.hpp"
#include "point_feature.hpp"
#include "pole_feature.hpp"
#include "runner.hpp"
#include "slam.hpp"
#include "wall_feature.hpp"

namespace {

using namespace mspace;
using namespace mspace::kernel;

// ---------------------------------------------------------------- fixtures

template <class T>
std::shared_ptr<FeatureType> make_type(const std::vector<ParamSpec>& specs) {
  return std::make_shared<T>(PluginArgs{"t", Params::defaults(specs), nullptr});
}

/// The five in-tree feature types with their default parameters, as a run's slots.
std::vector<FeatureTypeSlot> all_types() {
  std::vector<FeatureTypeSlot> slots;
  auto add = [&](const std::string& instance, const std::string& plugin, std::shared_ptr<FeatureType> type) {
    FeatureTypeSlot s;
    s.instance = instance;
    s.plugin = plugin;
    s.type = std::move(type);
    slots.push_back(std::move(s));
  };
  add("points", "point", make_type<point::PointType>(point::PointType::param_specs()));
  add("walls", "wall", make_type<wall::WallType>(wall::WallType::param_specs()));
  add("lines", "hline", make_type<hline::HLineType>(hline::HLineType::param_specs()));
  add("trees", "pole", make_type<pole::PoleType>(pole::PoleType::param_specs()));
  add("doors", "doorway", make_type<doorway::DoorwayType>(doorway::DoorwayType::param_specs()));
  return slots;
}

std::filesystem::path scratch(const std::string& name) {
  const std::filesystem::path dir = std::filesystem::path(MSPACE_BINARY_DIR) / "test-output" / "persistence" /
                                    ::testing::UnitTest::GetInstance()->current_test_info()->name();
  std::filesystem::create_directories(dir);
  return dir / name;
}

SensorView view_at(const Pose6& x_ms, int k) {
  SensorView v;
  v.t = 0.1 * k;
  v.sensor = 0;
  v.x_ms = x_ms;
  v.x_ms[0] += 0.002 * k;  // the sensor creeps: later observations differ a little
  v.C_ms = Mat6::Identity() * 1e-6;
  v.path_distance = 0.1 * k;
  return v;
}

/// The sample's measurement, changed a little for observation k.
Measurement measurement_at(const Measurement& m, int k) {
  Measurement out = m;
  for (Eigen::Index i = 0; i < out.v.size(); ++i) out.v[i] += 1e-4 * std::sin(1.3 * k + 0.7 * static_cast<double>(i));
  return out;
}

/// Phases 3 and 4 of one step; an exception is an outcome too.
struct Outcome {
  bool threw = false;
  std::optional<Extension> extension;
};

Outcome observe(Feature& f, const Measurement& m, const SensorView& view) {
  Outcome o;
  try {
    f.add_dense_information(m, view);
    o.extension = f.extend(view);
  } catch (const std::exception&) {
    o.threw = true;
  }
  return o;
}

/// A feature of `type` with dense information: sample(dim, seed) and `feeds`
/// observations of its measurement (it may extend on the way).
struct Grown {
  std::unique_ptr<Feature> feature;
  FeatureSample sample;
};

Grown grow(const FeatureType& type, int dim, std::uint64_t seed, int feeds) {
  std::optional<FeatureSample> s = type.sample(dim, seed);
  EXPECT_TRUE(s && s->feature);
  Grown g;
  g.feature = std::move(s->feature);
  g.sample = std::move(*s);
  for (int k = 1; k <= feeds; ++k)
    observe(*g.feature, measurement_at(g.sample.measurement, k), view_at(g.sample.x_ms, k));
  return g;
}

/// Bitwise equality of two saved states (names, sizes and every double).
void expect_same_saved(const SavedFeature& a, const SavedFeature& b, const std::string& where) {
  EXPECT_EQ(a.mspace_dim, b.mspace_dim) << where;
  EXPECT_EQ(a.version, b.version) << where;
  EXPECT_TRUE(a.coords.size() == b.coords.size() && a.coords == b.coords) << where;
  EXPECT_TRUE(a.extra.size() == b.extra.size() && a.extra == b.extra) << where;
  ASSERT_EQ(a.arrays.size(), b.arrays.size()) << where;
  for (std::size_t i = 0; i < a.arrays.size(); ++i) {
    EXPECT_EQ(a.arrays[i].name, b.arrays[i].name) << where;
    const Eigen::MatrixXd &x = a.arrays[i].value, &y = b.arrays[i].value;
    EXPECT_TRUE(x.rows() == y.rows() && x.cols() == y.cols() && x == y) << where << " array " << a.arrays[i].name;
  }
}

bool same(const Eigen::MatrixXd& a, const Eigen::MatrixXd& b) {
  return a.rows() == b.rows() && a.cols() == b.cols() && a == b;
}

/// Everything observable of a feature must be bit-identical.
void expect_same_feature(const Feature& a, const Feature& b, const Pose6& x_ms, const Measurement& m,
                         const std::string& where) {
  EXPECT_TRUE(same(a.coords(), b.coords())) << where;
  EXPECT_EQ(a.mspace_dim(), b.mspace_dim()) << where;
  EXPECT_TRUE(same(a.B(), b.B())) << where;
  EXPECT_TRUE(same(a.B_dual(), b.B_dual())) << where;
  EXPECT_TRUE(same(a.gating_covariance(), b.gating_covariance())) << where;
  EXPECT_TRUE(same(a.symmetry_directions(), b.symmetry_directions())) << where;
  Innovation ia, ib;
  const bool oka = a.innovation(to_sensor_frame(a.layout(), a.coords(), x_ms), m, ia);
  const bool okb = b.innovation(to_sensor_frame(b.layout(), b.coords(), x_ms), m, ib);
  EXPECT_EQ(oka, okb) << where;
  if (oka && okb) {
    EXPECT_TRUE(same(ia.eta, ib.eta)) << where;
    EXPECT_TRUE(same(ia.J_eta_o, ib.J_eta_o)) << where;
    EXPECT_TRUE(same(ia.J_eta_v, ib.J_eta_v)) << where;
  }
}

/// One feature per (type, reachable dimension, seed, number of observations).
struct Case {
  int slot;
  int dim;
  std::uint64_t seed;
  int feeds;
  Grown grown;
};

std::vector<Case> every_case(const std::vector<FeatureTypeSlot>& slots) {
  std::vector<Case> cases;
  for (std::size_t t = 0; t < slots.size(); ++t)
    for (int dim : slots[t].type->reachable_dims())
      for (std::uint64_t seed : {3u, 4u})
        for (int feeds : {0, 1, 2, 5})
          cases.push_back({static_cast<int>(t), dim, seed, feeds, grow(*slots[t].type, dim, seed, feeds)});
  return cases;
}

std::string describe(const std::vector<FeatureTypeSlot>& slots, const Case& c) {
  return slots[static_cast<std::size_t>(c.slot)].plugin + " dim " + std::to_string(c.dim) + " seed " +
         std::to_string(c.seed) + " after " + std::to_string(c.feeds) + " observations";
}

/// A map holding every case's feature (ids 1, 2, …).
StoredMap map_of(const std::vector<FeatureTypeSlot>& slots, const std::vector<Case>& cases) {
  StoredMap map;
  map.abi_tag = sdk_abi_tag();
  map.run = "persistence test";
  map.robot_pose << 1.0, 2.0, 0.0, 0.3, 0.0, 0.0;
  for (const FeatureTypeSlot& s : slots) map.types.push_back({s.instance, s.plugin});
  std::int64_t id = 1;
  for (const Case& c : cases) {
    StoredFeature f;
    f.id = id++;
    f.type = c.slot;
    f.saved = c.grown.feature->save();
    for (int i = 0; i < f.saved.mspace_dim; ++i) f.state_idx.push_back(3 + 10 * static_cast<int>(f.id) + i);
    f.own_idx = f.state_idx;
    f.created_step = 7 * f.id;
    f.last_seen_step = 9 * f.id;
    f.last_seen_t = 0.1 * static_cast<double>(f.id) + 1e-17;
    f.times_matched = c.feeds;
    map.features.push_back(std::move(f));
  }
  return map;
}

std::string read_bytes(const std::filesystem::path& file) {
  std::ifstream in(file, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

void write_bytes(const std::filesystem::path& file, const std::string& bytes) {
  std::ofstream out(file, std::ios::binary | std::ios::trunc);
  out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
}

/// Runs `f`, which must throw a PersistenceError; returns it.
PersistenceError expect_error(const std::function<void()>& f) {
  try {
    f();
  } catch (const PersistenceError& e) {
    return e;
  }
  ADD_FAILURE() << "no PersistenceError";
  return PersistenceError("", "none");
}

// ---------------------------------------------------------------- round trip

TEST(Persistence, EveryTypeAndDimensionRoundTripsBitForBit) {
  const std::vector<FeatureTypeSlot> slots = all_types();
  const std::vector<Case> cases = every_case(slots);
  // Every type at every reachable dimension, and dense information present.
  for (std::size_t t = 0; t < slots.size(); ++t) {
    for (int dim : slots[t].type->reachable_dims()) {
      bool seen = false;
      for (const Case& c : cases)
        seen = seen || (c.slot == static_cast<int>(t) && c.grown.feature->mspace_dim() == dim);
      EXPECT_TRUE(seen) << slots[t].plugin << " dim " << dim;
    }
    bool dense = false;
    for (const Case& c : cases)
      dense = dense || (c.slot == static_cast<int>(t) && !c.grown.feature->save().arrays.empty());
    EXPECT_TRUE(dense) << slots[t].plugin << " never saved dense information";
  }

  const StoredMap map = map_of(slots, cases);
  const std::filesystem::path file = scratch("map.bin");
  write_map_file(file, map);
  const StoredMap back = read_map_file(file);
  EXPECT_EQ(back.format_version, kMapFormatVersion);
  EXPECT_EQ(back.abi_tag, sdk_abi_tag());
  EXPECT_EQ(back.run, map.run);
  EXPECT_TRUE(same(back.robot_pose, map.robot_pose));
  ASSERT_EQ(back.types.size(), slots.size());
  ASSERT_EQ(back.features.size(), cases.size());
  for (std::size_t i = 0; i < cases.size(); ++i) {
    const StoredFeature &a = map.features[i], &b = back.features[i];
    EXPECT_EQ(a.id, b.id);
    EXPECT_EQ(a.type, b.type);
    EXPECT_EQ(a.state_idx, b.state_idx);
    EXPECT_EQ(a.created_step, b.created_step);
    EXPECT_EQ(a.last_seen_step, b.last_seen_step);
    EXPECT_EQ(a.last_seen_t, b.last_seen_t);
    EXPECT_EQ(a.times_matched, b.times_matched);
    expect_same_saved(a.saved, b.saved, describe(slots, cases[i]) + " (file)");
  }

  const std::vector<RestoredFeature> restored = restore_features(back, file, slots);
  ASSERT_EQ(restored.size(), cases.size());
  for (std::size_t i = 0; i < cases.size(); ++i) {
    const Case& c = cases[i];
    const std::string where = describe(slots, c);
    EXPECT_EQ(restored[i].id, map.features[i].id);
    EXPECT_EQ(restored[i].type, c.slot);
    expect_same_feature(*c.grown.feature, *restored[i].feature, c.grown.sample.x_ms, c.grown.sample.measurement, where);
    expect_same_saved(c.grown.feature->save(), restored[i].feature->save(), where + " (restored)");
  }
  // Written atomically: no temporary file is left beside it.
  for (const auto& entry : std::filesystem::directory_iterator(file.parent_path()))
    EXPECT_EQ(entry.path().filename(), "map.bin");
}

// A restored feature is the same feature: fed the same next measurements it
// gives the same innovations, dense information, coordinates and extensions.
TEST(Persistence, RestoredFeaturesBehaveIdentically) {
  const std::vector<FeatureTypeSlot> slots = all_types();
  std::vector<Case> cases = every_case(slots);
  const std::filesystem::path file = scratch("map.bin");
  write_map_file(file, map_of(slots, cases));
  const std::vector<RestoredFeature> restored = restore_features(read_map_file(file), file, slots);
  ASSERT_EQ(restored.size(), cases.size());
  int extensions = 0;
  for (std::size_t i = 0; i < cases.size(); ++i) {
    Case& c = cases[i];
    Feature &a = *c.grown.feature, &b = *restored[i].feature;
    for (int k = c.feeds + 1; k <= c.feeds + 25; ++k) {
      const std::string where = describe(slots, c) + ", observation " + std::to_string(k);
      const Measurement m = measurement_at(c.grown.sample.measurement, k);
      const SensorView v = view_at(c.grown.sample.x_ms, k);
      const Outcome oa = observe(a, m, v), ob = observe(b, m, v);
      ASSERT_EQ(oa.threw, ob.threw) << where;
      ASSERT_EQ(oa.extension.has_value(), ob.extension.has_value()) << where;
      if (oa.extension) {
        ++extensions;
        EXPECT_EQ(oa.extension->new_dims, ob.extension->new_dims) << where;
        EXPECT_TRUE(same(oa.extension->J_sensor, ob.extension->J_sensor)) << where;
        EXPECT_TRUE(same(oa.extension->J_own, ob.extension->J_own)) << where;
        EXPECT_TRUE(same(oa.extension->C_new, ob.extension->C_new)) << where;
      }
      expect_same_feature(a, b, v.x_ms, m, where);
      // The estimator moves both the same way (eq. 24).
      if (a.mspace_dim() > 0) {
        const Eigen::VectorXd dx = Eigen::VectorXd::Constant(a.mspace_dim(), 1e-5 * std::cos(k));
        a.apply_perturbation(dx);
        b.apply_perturbation(dx);
      }
      if (oa.threw) break;
    }
    expect_same_saved(a.save(), b.save(), describe(slots, c) + " at the end");
  }
  EXPECT_GT(extensions, 20);  // the comparison went through extensions, not just idle updates
}

TEST(Persistence, SharedCoordinatesAndBookkeepingRoundTrip) {
  const std::vector<FeatureTypeSlot> slots = all_types();
  wall::WallConfig config;
  wall::WallFeature a(config, Eigen::Vector4d(0, 0, 4, 0), 2, {}), b(config, Eigen::Vector4d(4.1, 0.1, 4.1, 3), 2, {});
  const std::optional<JoinProposal> corner = a.propose_join(wall::kEnd, b, wall::kStart);
  ASSERT_TRUE(corner);
  a.share_block(wall::kEnd, corner->value);
  b.share_block(wall::kStart, corner->value);
  StoredMap map;
  map.abi_tag = sdk_abi_tag();
  map.types = {{"walls", "wall"}};
  StoredFeature fa, fb;
  fa.id = 11;
  fa.saved = a.save();
  fa.state_idx = {3, 4, 5};
  fa.own_idx = {3};
  fa.shared = {{wall::kEnd, 2}};
  fb.id = 12;
  fb.saved = b.save();
  fb.state_idx = {6, 4, 5};
  fb.own_idx = {6};
  fb.shared = {{wall::kStart, 2}};
  map.features = {fa, fb};
  map.shared = {{2, BlockKind::Point2D, {4, 5}, {{11, wall::kEnd}, {12, wall::kStart}}}};
  const std::filesystem::path file = scratch("map.bin");
  write_map_file(file, map);
  const StoredMap back = read_map_file(file);
  ASSERT_EQ(back.shared.size(), 1u);
  EXPECT_EQ(back.shared[0].id, 2);
  EXPECT_EQ(back.shared[0].kind, BlockKind::Point2D);
  EXPECT_EQ(back.shared[0].state_idx, (std::vector<int>{4, 5}));
  EXPECT_EQ(back.shared[0].members, map.shared[0].members);
  EXPECT_EQ(back.features[0].shared, fa.shared);
  EXPECT_EQ(back.features[1].own_idx, fb.own_idx);
  std::vector<FeatureTypeSlot> walls = {slots[1]};
  const std::vector<RestoredFeature> restored = restore_features(back, file, walls);
  ASSERT_EQ(restored.size(), 2u);
  const auto& ra = dynamic_cast<const wall::WallFeature&>(*restored[0].feature);
  EXPECT_EQ(ra.shared_ends(), a.shared_ends());
  EXPECT_EQ(ra.shared_length(), a.shared_length());
  EXPECT_TRUE(same(ra.B(), a.B()));
  EXPECT_TRUE(same(restored[1].feature->B_dual(), b.B_dual()));
}

// The conformance suite's save/restore checks pass for every in-tree type,
// the SDK example included (here in-process: the example is otherwise only
// built out of tree by the install test).
template <class T>
conformance::Report conformance_of(const std::string& name) {
  PluginDescriptor d;
  d.name = name;
  d.kind = PluginKind::Feature;
  d.abi_tag = sdk_abi_tag();
  d.description = "in-process copy of the " + name + " feature type";
  d.params = T::param_specs();
  d.factory = [](const PluginArgs& args) -> std::unique_ptr<PluginObject> { return std::make_unique<T>(args); };
  return conformance::check_plugin(d);
}

TEST(Persistence, ConformanceSaveRestoreChecksPassForEveryType) {
  const std::vector<conformance::Report> reports = {
      conformance_of<point::PointType>("point"), conformance_of<wall::WallType>("wall"),
      conformance_of<hline::HLineType>("hline"), conformance_of<pole::PoleType>("pole"),
      conformance_of<doorway::DoorwayType>("doorway")};
  for (const conformance::Report& r : reports) {
    for (const char* name : {"feature.save_restore", "feature.save_restore_state", "feature.save_restore_future"}) {
      const conformance::CheckResult* c = r.find(name);
      ASSERT_NE(c, nullptr) << r.plugin << " " << name;
      EXPECT_TRUE(c->passed && !c->skipped) << r.plugin << " " << name << ": " << c->note;
      EXPECT_EQ(c->worst, 0.0) << r.plugin << " " << name;  // bit for bit
    }
    EXPECT_TRUE(r.passed()) << r.plugin << " fails " << r.failures() << " conformance checks";
  }
}

// ---------------------------------------------------------------- errors

class PersistenceErrors : public ::testing::Test {
 protected:
  void SetUp() override {
    slots_ = all_types();
    cases_ = every_case(slots_);
    map_ = map_of(slots_, cases_);
    file_ = scratch("map.bin");
    write_map_file(file_, map_);
    bytes_ = read_bytes(file_);
  }
  /// Byte offset of the payload of the FEAT record of feature `id` (the
  /// frame is 24 bytes + its CRC; records follow the 12-byte file header).
  std::size_t payload_of(std::int64_t id) const {
    std::size_t at = 12;
    for (;;) {
      std::uint64_t length = 0;
      std::int64_t key = 0;
      std::memcpy(&key, bytes_.data() + at + 4, 8);
      std::memcpy(&length, bytes_.data() + at + 16, 8);
      if (bytes_.compare(at, 4, "FEAT") == 0 && key == id) return at + 28;
      at += 28 + length + 4;
    }
  }
  std::vector<FeatureTypeSlot> slots_;
  std::vector<Case> cases_;
  StoredMap map_;
  std::filesystem::path file_;
  std::string bytes_;
};

TEST_F(PersistenceErrors, TruncatedAnywhereIsAnErrorNamingTheFile) {
  const std::filesystem::path cut = scratch("cut.bin");
  int named_feature = 0;
  for (std::size_t size = 0; size < bytes_.size(); size += std::max<std::size_t>(1, bytes_.size() / 397)) {
    write_bytes(cut, bytes_.substr(0, size));
    const PersistenceError e = expect_error([&] { read_map_file(cut); });
    EXPECT_NE(std::string(e.what()).find(cut.string()), std::string::npos) << e.what();
    EXPECT_EQ(e.file(), cut);
    if (e.feature_id()) {
      ++named_feature;
      EXPECT_NE(std::string(e.what()).find("plugin '"), std::string::npos) << e.what();
    }
  }
  EXPECT_GT(named_feature, 100);  // cut inside a feature record: its id and plugin are named
  // Cut inside the payload of feature 9.
  const std::size_t at = payload_of(9);
  write_bytes(cut, bytes_.substr(0, at + 10));
  const PersistenceError e = expect_error([&] { read_map_file(cut); });
  EXPECT_EQ(e.feature_id(), std::optional<std::int64_t>(9));
  EXPECT_EQ(e.plugin(), slots_[static_cast<std::size_t>(map_.features[8].type)].plugin);
  EXPECT_NE(std::string(e.what()).find("truncated"), std::string::npos) << e.what();
  // Cut exactly before END: every record intact, the END missing.
  const std::size_t end = bytes_.rfind("END ");
  write_bytes(cut, bytes_.substr(0, end));
  EXPECT_NE(std::string(expect_error([&] { read_map_file(cut); }).what()).find("no END record"), std::string::npos);
}

TEST_F(PersistenceErrors, CorruptFeatureNamesFeatureAndPlugin) {
  const std::filesystem::path bad = scratch("corrupt.bin");
  for (std::int64_t id : {std::int64_t{1}, std::int64_t{20}, static_cast<std::int64_t>(cases_.size())}) {
    std::string b = bytes_;
    b[payload_of(id) + 40] ^= 0x10;  // one bit of the saved state
    write_bytes(bad, b);
    const PersistenceError e = expect_error([&] { read_map_file(bad); });
    EXPECT_EQ(e.feature_id(), std::optional<std::int64_t>(id));
    EXPECT_EQ(e.plugin(),
              slots_[static_cast<std::size_t>(map_.features[static_cast<std::size_t>(id - 1)].type)].plugin);
    EXPECT_NE(std::string(e.what()).find("CRC-32"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find(bad.string()), std::string::npos) << e.what();
  }
  std::string b = bytes_;
  b[12 + 2] ^= 0x01;  // the frame of HEAD
  write_bytes(bad, b);
  EXPECT_NE(std::string(expect_error([&] { read_map_file(bad); }).what()).find("frame"), std::string::npos);
  write_bytes(bad, "not a map at all, just text\n");
  EXPECT_NE(std::string(expect_error([&] { read_map_file(bad); }).what()).find("magic"), std::string::npos);
}

// Any damaged byte, anywhere, is caught: a PersistenceError, never a crash
// and never a silently different map.
TEST_F(PersistenceErrors, EveryFlippedByteIsCaught) {
  const std::filesystem::path bad = scratch("flipped.bin");
  int caught = 0, tried = 0;
  for (std::size_t at = 0; at < bytes_.size(); at += 1 + bytes_.size() / 600) {
    std::string b = bytes_;
    b[at] = static_cast<char>(b[at] ^ (1 << (at % 8)));
    write_bytes(bad, b);
    ++tried;
    try {
      read_map_file(bad);
      ADD_FAILURE() << "a flipped bit at byte " << at << " was not noticed";
    } catch (const PersistenceError& e) {
      ++caught;
      EXPECT_EQ(e.file(), bad);
    }
  }
  EXPECT_EQ(caught, tried);
  EXPECT_GT(tried, 500);
}

TEST_F(PersistenceErrors, OtherFormatOrAbiVersionIsRefused) {
  const std::filesystem::path other = scratch("other.bin");
  std::string b = bytes_;
  b[8] = static_cast<char>(kMapFormatVersion + 1);  // a format from the future
  write_bytes(other, b);
  const PersistenceError e = expect_error([&] { read_map_file(other); });
  EXPECT_NE(std::string(e.what()).find("format version " + std::to_string(kMapFormatVersion + 1)), std::string::npos)
      << e.what();

  // A map of format version 1 (no checkpoint records) still reads.
  b[8] = 1;
  write_bytes(other, b);
  EXPECT_EQ(read_map_file(other).features.size(), map_.features.size());

  StoredMap old = map_;
  old.abi_tag = "mspace-sdk2/gcc12/cxx11/eigen3.4/align16";
  write_map_file(other, old);
  const PersistenceError a = expect_error([&] { read_map_file(other); });
  EXPECT_NE(std::string(a.what()).find("mspace-sdk2"), std::string::npos) << a.what();
  EXPECT_NE(std::string(a.what()).find(sdk_abi_tag()), std::string::npos) << a.what();
}

TEST_F(PersistenceErrors, MissingPluginOrRefusedStateLoadsNothing) {
  const StoredMap map = read_map_file(file_);
  std::vector<FeatureTypeSlot> without_hline;
  for (const FeatureTypeSlot& s : slots_)
    if (s.plugin != "hline") without_hline.push_back(s);
  std::vector<RestoredFeature> restored;
  const PersistenceError e = expect_error([&] { restored = restore_features(map, file_, without_hline); });
  EXPECT_TRUE(restored.empty());
  EXPECT_EQ(e.plugin(), "hline");
  ASSERT_TRUE(e.feature_id());
  EXPECT_EQ(
      map.types[static_cast<std::size_t>(map.features[static_cast<std::size_t>(*e.feature_id() - 1)].type)].plugin,
      "hline");
  EXPECT_NE(std::string(e.what()).find("not loaded"), std::string::npos) << e.what();

  // A saved state the plugin refuses (a wall observation record of the wrong size).
  StoredMap broken = map_;
  StoredFeature* wall = nullptr;
  for (StoredFeature& f : broken.features)
    if (broken.types[static_cast<std::size_t>(f.type)].plugin == "wall" && f.saved.find("observations") && !wall)
      wall = &f;
  ASSERT_NE(wall, nullptr);
  wall->saved.put("observations", Eigen::MatrixXd::Zero(5, 1));
  write_map_file(file_, broken);
  const PersistenceError r = expect_error([&] { restored = restore_features(read_map_file(file_), file_, slots_); });
  EXPECT_TRUE(restored.empty());
  EXPECT_EQ(r.feature_id(), std::optional<std::int64_t>(wall->id));
  EXPECT_EQ(r.plugin(), "wall");
  EXPECT_NE(std::string(r.what()).find("observations"), std::string::npos) << r.what();

  // A plugin version the plugin does not read.
  StoredMap future = map_;
  future.features[0].saved.version = 99;
  write_map_file(file_, future);
  const PersistenceError v = expect_error([&] { restore_features(read_map_file(file_), file_, slots_); });
  EXPECT_EQ(v.feature_id(), std::optional<std::int64_t>(1));
  EXPECT_NE(std::string(v.what()).find("version 99"), std::string::npos) << v.what();
}

TEST_F(PersistenceErrors, FailedWriteLeavesTheOldFileWhole) {
  // The temporary file cannot be created (a directory has its name): the
  // write fails with the file named and the old map stays as it was.
  const std::filesystem::path temp = file_.string() + ".tmp-" + std::to_string(::getpid());
  std::filesystem::create_directories(temp / "x");
  StoredMap other = map_;
  other.run = "another run";
  const PersistenceError e = expect_error([&] { write_map_file(file_, other); });
  EXPECT_EQ(e.file(), file_);
  EXPECT_EQ(read_bytes(file_), bytes_);
  std::filesystem::remove_all(temp);
  // Writing is deterministic: the same map gives the same bytes.
  write_map_file(file_, map_);
  EXPECT_EQ(read_bytes(file_), bytes_);
  const std::filesystem::path blocker = scratch("blocker");
  write_bytes(blocker, "a file, not a directory");
  EXPECT_THROW(write_map_file(blocker / "map.bin", map_), std::exception);
}

// ---------------------------------------------------------------- a run

/// Runs `config_file` for `steps` steps with outputs, then reads its map.bin
/// back and restores every feature through the run's own feature types.
struct RunCheck {
  int tentative = 0, in_map = 0, shared = 0;
};

RunCheck check_run(const std::filesystem::path& config_file, std::int64_t steps) {
  set_log_level(LogLevel::Warn);
  PluginRegistry registry;
  registry.add_search_dir(MSPACE_PLUGIN_DIR);
  RunConfig config = load_config(config_file, registry);
  config.output.dir = scratch("run").string();
  config.output.picture = false;
  config.max_steps = steps;
  Slam slam(config, registry);
  RunOptions options;
  options.progress = false;
  run_to_end(slam, options);
  const std::filesystem::path file = std::filesystem::path(config.output.dir) / "map.bin";
  RunCheck out;
  EXPECT_TRUE(std::filesystem::exists(file));
  EXPECT_TRUE(std::filesystem::exists(std::filesystem::path(config.output.dir) / "map.yaml"));
  if (!std::filesystem::exists(file)) return out;
  const StoredMap map = read_map_file(file);
  EXPECT_EQ(map.run, config.name);
  EXPECT_TRUE(same(map.robot_pose, slam.pose()));
  EXPECT_EQ(map.features.size(), slam.features().size());
  if (map.features.size() != slam.features().size()) return out;
  const std::vector<RestoredFeature> restored = restore_features(map, file, slam.feature_types());
  for (std::size_t i = 0; i < restored.size(); ++i) {
    const MapFeature& mf = slam.features()[i];
    const StoredFeature& sf = map.features[i];
    EXPECT_EQ(restored[i].id, mf.id);
    EXPECT_EQ(sf.state_idx, mf.state_idx);
    EXPECT_EQ(sf.own_idx, mf.own_idx);
    EXPECT_EQ(sf.shared, mf.shared);
    EXPECT_EQ(sf.times_matched, mf.times_matched);
    expect_same_saved(mf.feature->save(), restored[i].feature->save(), "feature " + std::to_string(mf.id));
    EXPECT_TRUE(same(mf.feature->gating_covariance(), restored[i].feature->gating_covariance()));
    EXPECT_TRUE(same(mf.feature->B_dual(), restored[i].feature->B_dual()));
    (mf.feature->mspace_dim() == 0 ? out.tentative : out.in_map)++;
  }
  EXPECT_EQ(map.shared.size(), slam.shared_coordinates().size());
  for (std::size_t i = 0; i < std::min(map.shared.size(), slam.shared_coordinates().size()); ++i) {
    EXPECT_EQ(map.shared[i].id, slam.shared_coordinates()[i].id);
    EXPECT_EQ(map.shared[i].state_idx, slam.shared_coordinates()[i].state_idx);
    EXPECT_EQ(map.shared[i].members, slam.shared_coordinates()[i].members);
  }
  out.shared = static_cast<int>(map.shared.size());
  return out;
}

TEST(Persistence, RunWritesMapBinThatRestoresThroughThePlugins) {
  const RunCheck r = check_run(std::filesystem::path(MSPACE_SOURCE_DIR) / "config" / "sim_points.yaml", 400);
  EXPECT_GT(r.in_map, 5);
  EXPECT_GT(r.tentative, 0);
}

// Walls on real data: dense scan points, measured ends and shared corners.
TEST(Persistence, IntelWallsMapRestoresThroughThePlugins) {
  const std::filesystem::path data = std::filesystem::path(MSPACE_SOURCE_DIR).parent_path() / "shared" / "datasets";
  if (!std::filesystem::exists(data / "intel_lab" / "intel_910_scans.txt"))
    GTEST_SKIP() << "Intel Research Lab data not found in " << data / "intel_lab";
  setenv("MSPACE_DATA", data.c_str(), /*overwrite=*/0);
  const RunCheck r = check_run(std::filesystem::path(MSPACE_SOURCE_DIR) / "config" / "intel_walls.yaml", 300);
  EXPECT_GT(r.in_map, 10);
  EXPECT_GT(r.tentative, 0);
  EXPECT_GT(r.shared, 0);
}

}  // namespace
