// Plugin discovery, loading, ABI checks, instantiation and error reporting,
// on the fixture plugins in MSPACE_FIXTURE_DIR.
#include <dlfcn.h>

#include <cstdlib>
#include <filesystem>
#include <stdexcept>
#include <string>

#include <gtest/gtest.h>

#include "build_path.hpp"
#include "mspace/abi.hpp"
#include "mspace/extractor.hpp"
#include "plugin_registry.hpp"

namespace fs = std::filesystem;
using mspace::kernel::PluginError;
using mspace::kernel::PluginRegistry;

namespace {

const fs::path kFixtureDir = MSPACE_FIXTURE_DIR;

fs::path fixture_file(const std::string& name) { return kFixtureDir / ("libmspace-plugin-" + name + ".so"); }

/// A registry that sees only the fixture plugins.
std::unique_ptr<PluginRegistry> fixture_registry() {
  auto registry = std::make_unique<PluginRegistry>();
  registry->add_search_dir(kFixtureDir);
  return registry;
}

/// The message of the PluginError that `f` throws ("" if it throws none).
template <class F>
std::string plugin_error(F&& f) {
  try {
    f();
  } catch (const PluginError& e) {
    return e.what();
  }
  ADD_FAILURE() << "expected a PluginError";
  return "";
}

/// Whether the dynamic loader currently has `file` loaded (RTLD_NOLOAD does not load it).
bool is_loaded(const fs::path& file) {
  void* handle = dlopen(file.c_str(), RTLD_NOW | RTLD_NOLOAD);
  if (handle == nullptr) return false;
  dlclose(handle);  // drop the reference RTLD_NOLOAD took
  return true;
}

mspace::PluginArgs args_for(const std::string& instance) {
  mspace::PluginArgs args;
  args.instance_name = instance;
  return args;
}

/// A scratch directory removed at the end of the test.
class TempDir {
 public:
  explicit TempDir(const std::string& name) : path_(fs::temp_directory_path() / name) {
    fs::remove_all(path_);
    fs::create_directories(path_);
  }
  ~TempDir() { fs::remove_all(path_); }
  const fs::path& path() const { return path_; }

 private:
  fs::path path_;
};

}  // namespace

TEST(PluginRegistry, DiscoversPluginsByFileNameWithoutLoadingThem) {
  auto registry = fixture_registry();
  const std::vector<std::string> expected = {"badabi",       "good",         "misnamed",    "notaplugin",
                                             "otherheap",    "stub_estimator", "stub_feature", "stub_motion",
                                             "stub_source",  "throwing"};
  EXPECT_EQ(registry->known_names(), expected);
  EXPECT_FALSE(is_loaded(fixture_file("good")));
  EXPECT_FALSE(is_loaded(fixture_file("badabi")));
}

TEST(PluginRegistry, LoadsOnlyTheRequestedLibraryAndCachesIt) {
  auto registry = fixture_registry();
  auto good = registry->load("good");
  EXPECT_EQ(good->descriptor->name, "good");
  EXPECT_EQ(good->descriptor->kind, mspace::PluginKind::Extractor);
  EXPECT_EQ(good->descriptor->abi_tag, MSPACE_ABI_TAG);
  EXPECT_EQ(good->descriptor->params.size(), 6u);
  EXPECT_EQ(good->path, fixture_file("good"));
  EXPECT_TRUE(is_loaded(fixture_file("good")));
  EXPECT_FALSE(is_loaded(fixture_file("throwing")));
  EXPECT_EQ(registry->load("good").get(), good.get());
}

TEST(PluginRegistry, UnknownNameListsKnownPluginsAndSearchedDirs) {
  auto registry = fixture_registry();
  EXPECT_EQ(plugin_error([&] { registry->load("nope"); }),
            "unknown plugin 'nope'; known plugins: badabi, good, misnamed, notaplugin, otherheap, stub_estimator, "
            "stub_feature, stub_motion, stub_source, throwing (searched: " +
                kFixtureDir.string() + ")");
}

TEST(PluginRegistry, RefusesAnotherAbiTagBeforeCallingTheLibrary) {
  auto registry = fixture_registry();
  // badabi's descriptor function aborts, so getting here at all shows it was not called.
  EXPECT_EQ(plugin_error([&] { registry->load("badabi"); }),
            "plugin library '" + fixture_file("badabi").string() +
                "' was built for SDK ABI 'mspace-sdk0/gcc4/cxx98/eigen3.2/align16' but this mspace expects '" +
                MSPACE_ABI_TAG + "'; rebuild the plugin against this SDK");
}

TEST(PluginRegistry, RefusesAPluginCompiledWithAnotherEigenHeapScheme) {
  // otherheap is this SDK's headers and MSPACE_EXPORT_PLUGIN with glibc's malloc
  // as Eigen's allocator: only the heap part of the tag differs, and that is
  // enough to refuse it (its descriptor aborts if called).
  std::string expected = MSPACE_ABI_TAG;
  ASSERT_EQ(expected.substr(expected.size() - 6), "/heap0");
  std::string other = expected.substr(0, expected.size() - 1) + "1";
  EXPECT_EQ(plugin_error([&] { auto registry = fixture_registry(); registry->load("otherheap"); }),
            "plugin library '" + fixture_file("otherheap").string() + "' was built for SDK ABI '" + other +
                "' but this mspace expects '" + expected + "'; rebuild the plugin against this SDK");
}

TEST(PluginRegistry, RefusesALibraryWithoutTheAbiSymbol) {
  auto registry = fixture_registry();
  EXPECT_EQ(plugin_error([&] { registry->load("notaplugin"); }),
            "'" + fixture_file("notaplugin").string() + "' is not an mspace plugin (no mspace_abi_tag symbol)");
}

TEST(PluginRegistry, RefusesADescriptorNameThatDiffersFromTheFileName) {
  auto registry = fixture_registry();
  EXPECT_EQ(plugin_error([&] { registry->load("misnamed"); }),
            "'" + fixture_file("misnamed").string() +
                "' describes plugin 'othername' but its file name says 'misnamed'; name the file "
                "libmspace-plugin-othername.so");
}

TEST(PluginRegistry, LoadAllCollectsTheFailures) {
  auto registry = fixture_registry();
  std::vector<std::string> errors;
  std::vector<std::string> loaded;
  for (const auto& plugin : registry->load_all(&errors)) loaded.push_back(plugin->descriptor->name);
  const std::vector<std::string> expected = {"good",        "stub_estimator", "stub_feature",
                                             "stub_motion", "stub_source",    "throwing"};
  EXPECT_EQ(loaded, expected);
  ASSERT_EQ(errors.size(), 4u);  // badabi, misnamed, notaplugin, otherheap, in name order
  EXPECT_NE(errors[0].find("SDK ABI"), std::string::npos) << errors[0];
  EXPECT_NE(errors[1].find("othername"), std::string::npos) << errors[1];
  EXPECT_NE(errors[2].find("no mspace_abi_tag symbol"), std::string::npos) << errors[2];
  EXPECT_NE(errors[3].find("/heap1"), std::string::npos) << errors[3];
  EXPECT_THROW(fixture_registry()->load_all(nullptr), PluginError);
}

TEST(PluginRegistry, FirstSearchDirWins) {
  TempDir dir("mspace_test_first_dir_wins");
  fs::copy_file(fixture_file("good"), dir.path() / "libmspace-plugin-good.so");
  PluginRegistry registry;
  registry.add_search_dir(dir.path());
  registry.add_search_dir(kFixtureDir);
  EXPECT_EQ(registry.load("good")->path, dir.path() / "libmspace-plugin-good.so");
  EXPECT_EQ(registry.known_names().size(), 10u);
}

TEST(PluginRegistry, PluginFileTakesItsNameFromTheDescriptor) {
  TempDir dir("mspace_test_plugin_file");
  const fs::path file = dir.path() / "my_build_of_good.so";
  fs::copy_file(fixture_file("good"), file);
  PluginRegistry registry;
  registry.add_plugin_file(file);
  EXPECT_EQ(registry.known_names(), std::vector<std::string>{"good"});
  EXPECT_EQ(registry.load("good")->path, file);
}

TEST(PluginRegistry, PluginFileFailsAtOnce) {
  PluginRegistry registry;
  EXPECT_EQ(plugin_error([&] { registry.add_plugin_file(fixture_file("notaplugin")); }),
            "'" + fixture_file("notaplugin").string() + "' is not an mspace plugin (no mspace_abi_tag symbol)");
  EXPECT_EQ(plugin_error([&] { registry.add_plugin_file("/no/such/plugin.so"); }),
            "plugin file '/no/such/plugin.so' does not exist");
}

TEST(PluginRegistry, DefaultSearchDirsPutTheEnvironmentFirst) {
  ASSERT_EQ(setenv("MSPACE_PLUGIN_PATH", "/opt/a:/opt/b::", 1), 0);
  const std::vector<fs::path> dirs = PluginRegistry::default_search_dirs();
  unsetenv("MSPACE_PLUGIN_PATH");
  ASSERT_EQ(dirs.size(), 3u);
  EXPECT_EQ(dirs[0], "/opt/a");
  EXPECT_EQ(dirs[1], "/opt/b");
  // This test runs from <build>/bin, beside <build>/lib/mspace/plugins.
  EXPECT_EQ(dirs[2], (fs::path(MSPACE_BINARY_DIR) / "lib/mspace/plugins").lexically_normal());
  EXPECT_EQ(PluginRegistry::default_search_dirs().size(), 1u);
}

TEST(PluginRegistry, CreatePassesParametersAndChecksTheKind) {
  auto registry = fixture_registry();
  mspace::PluginArgs args = args_for("laser");
  args.params.set("gain", 2.0);
  args.params.set("count", std::int64_t{4});
  args.params.set("offset", std::vector<double>{0.5, 0.0});
  auto extractor = registry->create<mspace::Extractor>("good", mspace::PluginKind::Extractor, args);
  std::vector<mspace::Measurement> out;
  extractor->extract(mspace::SensorReading{}, out);
  ASSERT_EQ(out.size(), 1u);
  EXPECT_EQ(out[0].v(0), 2.0 * 4 + 0.5);

  EXPECT_EQ(plugin_error([&] {
              registry->create<mspace::PluginObject>("good", mspace::PluginKind::Feature, args_for("walls"));
            }),
            "walls: plugin 'good' is an extractor, but a feature is needed here");
}

TEST(PluginRegistry, ThrowingFactoryIsReportedWithInstancePluginAndLibrary) {
  auto registry = fixture_registry();
  EXPECT_EQ(plugin_error([&] {
              registry->create<mspace::Extractor>("throwing", mspace::PluginKind::Extractor, args_for("laser"));
            }),
            "laser (plugin 'throwing', library '" + fixture_file("throwing").string() + "'): factory failed: boom");
}

TEST(PluginRegistry, FactoryReturningNothingIsAnError) {
  auto registry = fixture_registry();
  EXPECT_EQ(plugin_error([&] {
              registry->create<mspace::PluginObject>("stub_feature", mspace::PluginKind::Feature, args_for("pts"));
            }),
            "pts (plugin 'stub_feature', library '" + fixture_file("stub_feature").string() +
                "'): factory failed: it returned no object");
}

TEST(PluginRegistry, ObjectKeepsItsLibraryLoadedAfterTheRegistryIsGone) {
  auto registry = fixture_registry();
  mspace::PluginArgs args = args_for("laser");
  args.params = mspace::Params::defaults(registry->load("good")->descriptor->params);
  std::shared_ptr<mspace::Extractor> extractor =
      registry->create<mspace::Extractor>("good", mspace::PluginKind::Extractor, args);
  registry.reset();
  ASSERT_TRUE(is_loaded(fixture_file("good")));
  std::vector<mspace::Measurement> out;
  extractor->extract(mspace::SensorReading{}, out);  // virtual call into the library
  ASSERT_EQ(out.size(), 1u);
  EXPECT_EQ(out[0].kind, "good");
  EXPECT_EQ(out[0].v(0), 1.5 * 3 + 0.0);  // the defaults: gain 1.5, count 3, offset [0, 0]
  extractor.reset();
  EXPECT_FALSE(is_loaded(fixture_file("good")));
}

TEST(PluginRegistry, GuardedNamesTheCallThatFailed) {
  auto registry = fixture_registry();
  auto good = registry->load("good");
  EXPECT_EQ(mspace::kernel::guarded("laser", *good, "extract", [] { return 7; }), 7);
  EXPECT_EQ(plugin_error([&] {
              mspace::kernel::guarded("laser", *good, "extract", []() -> int { throw std::out_of_range("row 3"); });
            }),
            "laser (plugin 'good', library '" + fixture_file("good").string() + "'): extract failed: row 3");
  EXPECT_EQ(
      plugin_error([&] { mspace::kernel::guarded("laser", *good, "extract", [] { throw 42; }); }),
      "laser (plugin 'good', library '" + fixture_file("good").string() + "'): extract failed: unknown exception");
}
