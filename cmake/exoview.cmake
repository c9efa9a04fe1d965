# Helpers shared by every module.

# Environment of every test: where ../shared is, and the lavapipe ICD so a machine with a GPU
# behaves the same as CI. In sanitizer builds the lavapipe driver is preloaded (after the ASan
# runtime, which must come first): Mesa's driver is otherwise dlclose()d before LeakSanitizer
# runs, and its own small allocations show up as unattributable leaks from "<unknown module>".
set(EXOVIEW_TEST_ENV
  "EXOVIEW_SHARED_DIR=${CMAKE_SOURCE_DIR}/../shared"
  "VK_DRIVER_FILES=/usr/share/vulkan/icd.d/lvp_icd.x86_64.json"
  "VK_ICD_FILENAMES=/usr/share/vulkan/icd.d/lvp_icd.x86_64.json")
if(EXOVIEW_SANITIZE)
  execute_process(COMMAND ${CMAKE_CXX_COMPILER} -print-file-name=libasan.so
    OUTPUT_VARIABLE EXOVIEW_ASAN_RUNTIME OUTPUT_STRIP_TRAILING_WHITESPACE)
  find_file(EXOVIEW_LVP_DRIVER libvulkan_lvp.so PATHS /usr/lib/x86_64-linux-gnu NO_DEFAULT_PATH)
  if(EXOVIEW_LVP_DRIVER)
    list(APPEND EXOVIEW_TEST_ENV "LD_PRELOAD=${EXOVIEW_ASAN_RUNTIME} ${EXOVIEW_LVP_DRIVER}")
  endif()
  list(APPEND EXOVIEW_TEST_ENV "UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1")
endif()

# exoview_test(NAME SOURCES... LIBS ...): a GoogleTest binary registered with ctest.
# Tests get the lavapipe ICD so a machine with a GPU behaves the same as CI.
function(exoview_test name)
  cmake_parse_arguments(T "" "TIMEOUT" "SOURCES;LIBS;LABELS" ${ARGN})
  add_executable(${name} ${T_SOURCES})
  target_link_libraries(${name} PRIVATE ${T_LIBS} GTest::gtest GTest::gtest_main GTest::gmock)
  if(NOT T_TIMEOUT)
    set(T_TIMEOUT 600)
  endif()
  if(EXOVIEW_SANITIZE)
    # Unoptimised ASan/UBSan builds run the numeric tests 50-200x slower (refinement: ~15 min).
    math(EXPR T_TIMEOUT "${T_TIMEOUT} * 5")
  endif()
  # One ctest entry per test binary (gtest prints every case and the failures in full). Not
  # gtest_discover_tests: its PROPERTIES pass a list-valued ENVIRONMENT through a post-build
  # script that splits it, so only the first variable reached the tests.
  add_test(NAME ${name} COMMAND ${name} --gtest_color=no)
  set_tests_properties(${name} PROPERTIES
    TIMEOUT ${T_TIMEOUT}
    ENVIRONMENT "${EXOVIEW_TEST_ENV}")
endfunction()

# exoview_binary(NAME SOURCES... LIBS ...): a program a user runs (server, clients, tools,
# benchmarks). Every one is recorded in the global property EXOVIEW_BINARIES, so the flags test
# can check that each of them follows the common conventions (common/cli).
function(exoview_binary name)
  cmake_parse_arguments(B "" "" "SOURCES;LIBS" ${ARGN})
  add_executable(${name} ${B_SOURCES})
  target_link_libraries(${name} PRIVATE ${B_LIBS})
  set_property(GLOBAL APPEND PROPERTY EXOVIEW_BINARIES ${name})
endfunction()

# exoview_bench(NAME SOURCES... LIBS ...): a benchmark binary (not run by ctest).
function(exoview_bench name)
  exoview_binary(${name} ${ARGN})
endfunction()
