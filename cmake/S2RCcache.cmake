# ccache for every checkout at once: paths under the source tree are hashed
# relative to it and the build folder is left out of the hash, so a fresh
# clone elsewhere (CI's) hits what another checkout compiled. No compile
# command may hold a checkout's absolute path for this to work (core/paths.h).
# s2r_use_ccache(SOURCE_ROOT)
function(s2r_use_ccache root)
  find_program(CCACHE_PROGRAM ccache)
  if(CCACHE_PROGRAM)
    # The sloppiness lets ccache cache compiles that use the tests'
    # precompiled header (they also pass -fpch-preprocess, S2RHelpers.cmake).
    set(launcher ${CMAKE_COMMAND} -E env CCACHE_BASEDIR=${root} CCACHE_NOHASHDIR=1
        CCACHE_SLOPPINESS=pch_defines,time_macros ${CCACHE_PROGRAM})
    set(CMAKE_CXX_COMPILER_LAUNCHER ${launcher} PARENT_SCOPE)
    set(CMAKE_C_COMPILER_LAUNCHER ${launcher} PARENT_SCOPE)
  endif()
endfunction()
