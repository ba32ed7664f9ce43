// mspace/abi.hpp — the SDK ABI tag.
//
// Every plugin library embeds the tag of the SDK headers it was compiled against
// (see plugin_export.hpp). The kernel compares it with its own before calling
// anything in the library and refuses a mismatch, because the interfaces in
// these headers pass C++ classes, std::string/std::vector and Eigen matrices by
// reference: a plugin built with another SDK version, another standard library
// ABI or another Eigen alignment would corrupt memory instead of failing.
#pragma once

#include <Eigen/Core>

// The major version changes with every change of the plugin interfaces'
// layout (2: DataSource::recorded_mounts; 3, all from one session:
// SavedFeature::arrays and SavedFeature::version, the dense information of
// map files; Estimator::wants_problem and relinearize, mspace/problem.hpp,
// EkfFilter in the SDK library; DataStep::odometry_covariance;
// FeatureType::sample_observation, so that the conformance suite can drive
// extensions that need a moving sensor; 4, from one session: PluginObject::
// has_state, state_version, save_state and restore_state with
// mspace/state.hpp, for checkpoints; FactorKind::Coincidence and
// NonlinearProblem::loop_closures, loop closing by map matching;
// 5, s5-sdk: Extractor::sample_scene with SampleScene and mspace/scene.hpp,
// FeatureType::from_true_shape — the extractor ↔ feature contract check;
// Feature::drawing with FeatureDrawing/DrawingItem — the picture hook;
// CekfFilter in the SDK library, mspace/cekf_filter.hpp, for the smoother's
// running filter). Minor versions add without changing any layout (5.1:
// DrawingItem::Kind::Direction, direction_item and
// FeatureDrawing::direction_only — a kernel of 5.0 would draw nothing for a
// Direction item; 6: Feature::absorb, the merge of a feature mapped twice;
// 6.1: Estimator::set_unobservable may also be given every state row, after a
// re-linearisation).
#define MSPACE_SDK_VERSION_MAJOR 6
#define MSPACE_SDK_VERSION_MINOR 1

#define MSPACE_ABI_STR2(x) #x
#define MSPACE_ABI_STR(x) MSPACE_ABI_STR2(x)

#if defined(__clang__)
#define MSPACE_ABI_COMPILER "clang" MSPACE_ABI_STR(__clang_major__)
#elif defined(__GNUC__)
#define MSPACE_ABI_COMPILER "gcc" MSPACE_ABI_STR(__GNUC__)
#else
#define MSPACE_ABI_COMPILER "cc"
#endif

#if defined(_GLIBCXX_USE_CXX11_ABI) && _GLIBCXX_USE_CXX11_ABI
#define MSPACE_ABI_STDLIB "cxx11"
#else
#define MSPACE_ABI_STDLIB "cxx98"
#endif

/// The tag: SDK major version, compiler family/major, libstdc++ string ABI,
/// Eigen version, Eigen's maximum static alignment (which changes the layout
/// of fixed-size Eigen members such as Pose6) and Eigen's heap scheme
/// (EIGEN_MALLOC_ALREADY_ALIGNED: 1 = glibc's malloc, 0 = Eigen's own aligned
/// allocator, which frees a block through an offset stored before it). A
/// matrix allocated under one scheme and freed under the other corrupts the
/// heap, and Eigen switches scheme by itself under AddressSanitizer, so the
/// SDK's CMake package fixes it to 0 (sdk/CMakeLists.txt) and the tag makes a
/// plugin compiled otherwise fail to load with a clear message.
#define MSPACE_ABI_TAG                                                          \
  "mspace-sdk" MSPACE_ABI_STR(MSPACE_SDK_VERSION_MAJOR) "/" MSPACE_ABI_COMPILER \
  "/" MSPACE_ABI_STDLIB "/eigen" MSPACE_ABI_STR(EIGEN_WORLD_VERSION) "."       \
  MSPACE_ABI_STR(EIGEN_MAJOR_VERSION) "/align" MSPACE_ABI_STR(EIGEN_MAX_STATIC_ALIGN_BYTES) \
  "/heap" MSPACE_ABI_STR(EIGEN_MALLOC_ALREADY_ALIGNED)

namespace mspace {
/// The ABI tag the calling code was compiled with.
inline const char* sdk_abi_tag() { return MSPACE_ABI_TAG; }
/// The ABI tag the SDK library loaded at run time was compiled with: code
/// that links the library (the Python module, a host program) compares it
/// with sdk_abi_tag() to fail clearly instead of corrupting memory after an
/// upgrade of one but not the other.
const char* sdk_library_abi_tag();
}  // namespace mspace
