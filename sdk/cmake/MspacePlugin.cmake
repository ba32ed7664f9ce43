# mspace_add_plugin(NAME <name> SOURCES <files...> [LINK <targets...>])
#
# Builds the plugin library `libmspace-plugin-<name>.so` with the flags the
# kernel expects: a MODULE library, hidden visibility (only the two symbols of
# MSPACE_EXPORT_PLUGIN are exported), C++20 and the SDK's Eigen settings
# (through mspace::sdk; the ABI tag embedded by MSPACE_EXPORT_PLUGIN lets the
# kernel refuse a plugin built with another SDK, compiler or Eigen). The
# target is called `mspace_plugin_<name>`.
#
# Variables read (all optional):
#   MSPACE_PLUGIN_OUTPUT_DIR   folder for the library (e.g. one folder to point
#                              `mspace --plugin-dir` or MSPACE_PLUGIN_PATH at)
#   MSPACE_PLUGIN_INSTALL_DIR  if set, the plugin is installed there with an
#                              RPATH to the SDK two levels up (in-tree plugins:
#                              lib/mspace/plugins → lib)
# Out of tree: find_package(mspace CONFIG REQUIRED) includes this file.
function(mspace_add_plugin)
  cmake_parse_arguments(ARG "" "NAME" "SOURCES;LINK" ${ARGN})
  if(NOT ARG_NAME OR NOT ARG_SOURCES)
    message(FATAL_ERROR "mspace_add_plugin: NAME and SOURCES are required")
  endif()
  set(target mspace_plugin_${ARG_NAME})
  add_library(${target} MODULE ${ARG_SOURCES})
  target_link_libraries(${target} PRIVATE mspace::sdk ${ARG_LINK})
  if(TARGET mspace_warnings)
    target_link_libraries(${target} PRIVATE mspace_warnings)
  endif()
  set_target_properties(${target} PROPERTIES
    PREFIX "lib"
    OUTPUT_NAME "mspace-plugin-${ARG_NAME}"
    CXX_VISIBILITY_PRESET hidden
    VISIBILITY_INLINES_HIDDEN ON
    CXX_STANDARD 20
    CXX_STANDARD_REQUIRED ON)
  if(DEFINED MSPACE_PLUGIN_OUTPUT_DIR)
    set_target_properties(${target} PROPERTIES LIBRARY_OUTPUT_DIRECTORY ${MSPACE_PLUGIN_OUTPUT_DIR})
  endif()
  if(DEFINED MSPACE_PLUGIN_INSTALL_DIR)
    set_target_properties(${target} PROPERTIES INSTALL_RPATH "$ORIGIN/../..")
    install(TARGETS ${target} LIBRARY DESTINATION ${MSPACE_PLUGIN_INSTALL_DIR})
  endif()
endfunction()
