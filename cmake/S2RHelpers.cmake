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
  target_compile_definitions(${name} PRIVATE
    S2R_DATA_DIR="${S2R_DATA_DIR}" S2R_SOURCE_DIR="${CMAKE_SOURCE_DIR}"
    S2R_BINARY_DIR="${CMAKE_BINARY_DIR}")
  s2r_warnings(${name})
  add_test(NAME ${name} COMMAND ${name})
  set(labels unit ${A_LABELS})
  if(A_LABELS)
    set(labels ${A_LABELS})
  endif()
  set_tests_properties(${name} PROPERTIES LABELS "${labels}" TIMEOUT 600
    ENVIRONMENT "LIBCAMERA_LOG_LEVELS=*:ERROR;LIBGL_ALWAYS_SOFTWARE=1")
endfunction()
