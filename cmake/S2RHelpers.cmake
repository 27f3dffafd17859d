# s2r_add_library(NAME SRCS ... PUBLIC_LINK ... PRIVATE_LINK ...)
# One library per stage folder. Sources include each other as "stage/file.h" from the
# repository root.
function(s2r_add_library name)
  cmake_parse_arguments(A "" "" "SRCS;PUBLIC_LINK;PRIVATE_LINK" ${ARGN})
  add_library(${name} STATIC ${A_SRCS})
  target_include_directories(${name} PUBLIC ${CMAKE_SOURCE_DIR})
  target_link_libraries(${name} PUBLIC ${A_PUBLIC_LINK} PRIVATE ${A_PRIVATE_LINK})
  s2r_warnings(${name})
endfunction()

function(s2r_warnings target)
  target_compile_options(${target} PRIVATE -Wall -Wextra -Wpedantic -Wno-missing-field-initializers)
  if(S2R_WERROR)
    target_compile_options(${target} PRIVATE -Werror)
  endif()
endfunction()

# s2r_test(NAME SRCS ... LINK ... [LABELS ...])  -> CTest test "NAME"
function(s2r_test name)
  cmake_parse_arguments(A "" "" "SRCS;LINK;LABELS" ${ARGN})
  add_executable(${name} ${A_SRCS})
  target_link_libraries(${name} PRIVATE ${A_LINK} GTest::gtest_main)
  # The build's paths by call (core/paths.h), not as literals: the test's
  # compile command is the same in every checkout, so ccache hits across them.
  target_compile_definitions(${name} PRIVATE
    "S2R_DATA_DIR=::s2r::build_data_dir()" "S2R_SOURCE_DIR=::s2r::build_source_dir()"
    "S2R_BINARY_DIR=::s2r::build_binary_dir()")
  target_compile_options(${name} PRIVATE -include core/paths.h)
  s2r_warnings(${name})
  add_test(NAME ${name} COMMAND ${name})
  set(labels unit ${A_LABELS})
  if(A_LABELS)
    set(labels ${A_LABELS})
  endif()
  set(env "LIBCAMERA_LOG_LEVELS=*:ERROR" "LIBGL_ALWAYS_SOFTWARE=1")
  set(timeout 900)
  if(S2R_SANITIZE)
    # Instrumented code runs 3-10x slower (the Ceres tests most).
    set(timeout 2400)
    # Third-party allocations kept for the process lifetime are suppressed. Mesa's
    # GL driver is unloaded before LeakSanitizer reports, leaving its allocations
    # unattributable, so OpenGL tests run with ASan/UBSan but without leak checks.
    if("gl" IN_LIST labels)
      list(APPEND env "LSAN_OPTIONS=detect_leaks=0")
    else()
      list(APPEND env "LSAN_OPTIONS=suppressions=${CMAKE_SOURCE_DIR}/cmake/lsan.supp:print_suppressions=0")
    endif()
    list(APPEND env "UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1")
  endif()
  # A clean checkout has no CTest cost data: start the long tests first, so
  # that the longest one is not the last to begin.
  set(cost 1)
  if("slow" IN_LIST labels)
    set(cost 100)
  elseif("data" IN_LIST labels)
    set(cost 10)
  endif()
  set_tests_properties(${name} PROPERTIES LABELS "${labels}" TIMEOUT ${timeout} ENVIRONMENT "${env}" COST ${cost})
endfunction()
