# Helpers shared by every module.

# exoview_test(NAME SOURCES... LIBS ...): a GoogleTest binary registered with ctest.
# Tests get the lavapipe ICD so a machine with a GPU behaves the same as CI.
function(exoview_test name)
  cmake_parse_arguments(T "" "TIMEOUT" "SOURCES;LIBS;LABELS" ${ARGN})
  add_executable(${name} ${T_SOURCES})
  target_link_libraries(${name} PRIVATE ${T_LIBS} GTest::gtest GTest::gtest_main GTest::gmock)
  if(NOT T_TIMEOUT)
    set(T_TIMEOUT 600)
  endif()
  gtest_discover_tests(${name}
    DISCOVERY_TIMEOUT 60
    PROPERTIES TIMEOUT ${T_TIMEOUT}
      ENVIRONMENT "EXOVIEW_SHARED_DIR=${CMAKE_SOURCE_DIR}/../shared;VK_DRIVER_FILES=/usr/share/vulkan/icd.d/lvp_icd.x86_64.json;VK_ICD_FILENAMES=/usr/share/vulkan/icd.d/lvp_icd.x86_64.json")
endfunction()

# exoview_bench(NAME SOURCES... LIBS ...): a benchmark binary (not run by ctest).
function(exoview_bench name)
  cmake_parse_arguments(B "" "" "SOURCES;LIBS" ${ARGN})
  add_executable(${name} ${B_SOURCES})
  target_link_libraries(${name} PRIVATE ${B_LIBS})
endfunction()
