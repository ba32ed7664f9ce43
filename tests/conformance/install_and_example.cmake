# install_and_example.cmake — run by CTest (test `install_and_example`):
#   1. installs the build tree BUILD_DIR into a fresh prefix under WORK_DIR;
#   2. configures and builds sdk/examples/doorway against that prefix only;
#   3. checks the example's plugins with the installed `mspace check` (the
#      doorway also with its numeric Jacobians, mspace/numeric.hpp);
#   4. runs the example's YAML through the installed, unchanged `mspace`
#      (its SHA-256 is compared before and after), the example's plugins
#      found through MSPACE_PLUGIN_PATH and the installed ones without it;
#   5. compares the map and trajectory with the simulator's ground truth.
cmake_minimum_required(VERSION 3.25)
foreach(var BUILD_DIR SOURCE_DIR WORK_DIR)
  if(NOT DEFINED ${var})
    message(FATAL_ERROR "${var} is not set")
  endif()
endforeach()
string(TIMESTAMP start "%s")
set(prefix ${WORK_DIR}/prefix)
set(example_src ${SOURCE_DIR}/sdk/examples/doorway)
set(example_build ${WORK_DIR}/example-build)
file(REMOVE_RECURSE ${prefix} ${example_build} ${WORK_DIR}/out)

function(step name)
  message(STATUS "[install_and_example] ${name}")
  execute_process(COMMAND ${ARGN} RESULT_VARIABLE rc)
  if(NOT rc EQUAL 0)
    message(FATAL_ERROR "[install_and_example] ${name} failed (${rc})")
  endif()
endfunction()

# No environment leaks: plugins and libraries must be found through RPATHs
# and the installed layout only.
set(clean_env ${CMAKE_COMMAND} -E env --unset=MSPACE_PLUGIN_PATH --unset=LD_LIBRARY_PATH)
set(mspace ${prefix}/bin/mspace)

step("install" ${CMAKE_COMMAND} --install ${BUILD_DIR} --prefix ${prefix})
file(SHA256 ${mspace} sha_before)
step("installed plugins" ${clean_env} ${mspace} plugins)

find_program(ccache ccache)
set(launcher)
if(ccache)
  set(launcher -DCMAKE_CXX_COMPILER_LAUNCHER=${ccache})
endif()
step("configure example" ${CMAKE_COMMAND} -S ${example_src} -B ${example_build} -G Ninja
     -DCMAKE_BUILD_TYPE=Release -DCMAKE_PREFIX_PATH=${prefix} -DCMAKE_FIND_USE_PACKAGE_REGISTRY=OFF ${launcher})
file(STRINGS ${example_build}/CMakeCache.txt mspace_dir REGEX "^mspace_DIR:")
if(NOT mspace_dir MATCHES "${prefix}/")
  message(FATAL_ERROR "the example found mspace outside the prefix: ${mspace_dir}")
endif()
step("build example" ${CMAKE_COMMAND} --build ${example_build} -j2)

set(plugins ${example_build}/plugins)
step("check example plugins" ${clean_env} ${mspace} check
     ${plugins}/libmspace-plugin-doorway.so ${plugins}/libmspace-plugin-doorway_jambs.so
     ${plugins}/libmspace-plugin-doorway_sim.so --junit ${WORK_DIR}/check_doorway.xml)
step("check the doorway with numeric Jacobians" ${clean_env} ${mspace} check
     ${plugins}/libmspace-plugin-doorway.so --param jacobians=numeric --junit ${WORK_DIR}/check_doorway_numeric.xml)
step("run example" ${clean_env} MSPACE_PLUGIN_PATH=${plugins}
     ${mspace} run ${example_src}/doorway.yaml --out ${WORK_DIR}/out --quiet)
step("compare with ground truth" ${example_build}/doorway_check_map ${example_src}/doorway.yaml ${WORK_DIR}/out 0.05)

file(SHA256 ${mspace} sha_after)
if(NOT sha_before STREQUAL sha_after)
  message(FATAL_ERROR "the installed mspace changed (${sha_before} → ${sha_after})")
endif()
string(TIMESTAMP end "%s")
math(EXPR seconds "${end} - ${start}")
message(STATUS "[install_and_example] passed in ${seconds} s; mspace sha256 ${sha_after} unchanged")
