// mspace/plugin_export.hpp — the one export of a plugin library.
//
// In exactly one source file of a plugin:
//
//   static mspace::PluginDescriptor describe() {
//     mspace::PluginDescriptor d;
//     d.name = "point"; d.kind = mspace::PluginKind::Feature; ...
//     d.factory = [](const mspace::PluginArgs& a) -> std::unique_ptr<mspace::PluginObject> {
//       return std::make_unique<PointType>(a); };
//     return d;
//   }
//   MSPACE_EXPORT_PLUGIN(describe)
//
// This exports two symbols: `mspace_abi_tag`, a plain C string the kernel
// reads and compares *before calling anything* in the library, and the
// Boost.DLL alias `mspace_plugin_descriptor` of a function returning the
// descriptor (with abi_tag filled in). No static initialiser registers
// anything, so the same code works when a plugin is linked directly.
#pragma once

#include <boost/config.hpp>
#include <boost/dll/alias.hpp>

#include "mspace/abi.hpp"
#include "mspace/plugin.hpp"

#define MSPACE_ABI_SYMBOL "mspace_abi_tag"
#define MSPACE_DESCRIPTOR_SYMBOL "mspace_plugin_descriptor"

#define MSPACE_EXPORT_PLUGIN(describe_fn)                                              \
  extern "C" BOOST_SYMBOL_EXPORT const char mspace_abi_tag[];                          \
  extern "C" BOOST_SYMBOL_EXPORT const char mspace_abi_tag[] = MSPACE_ABI_TAG;         \
  namespace mspace_plugin_export_ {                                                    \
  inline const ::mspace::PluginDescriptor* descriptor() {                              \
    static const ::mspace::PluginDescriptor d = [] {                                   \
      ::mspace::PluginDescriptor x = describe_fn();                                    \
      x.abi_tag = MSPACE_ABI_TAG;                                                      \
      return x;                                                                        \
    }();                                                                               \
    return &d;                                                                         \
  }                                                                                    \
  }                                                                                    \
  BOOST_DLL_ALIAS(mspace_plugin_export_::descriptor, mspace_plugin_descriptor)
