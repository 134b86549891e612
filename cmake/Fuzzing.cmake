# RIM_FUZZ: libFuzzer targets for hostile input (tests/fuzz; docs/security.md, "Fuzzing").
#   ON   clang only. Every rim library is compiled with libFuzzer's coverage instrumentation and
#        AddressSanitizer + UndefinedBehaviorSanitizer; tests/fuzz builds one fuzzer per target and
#        registers it under the ctest label `fuzz`, run for RIM_FUZZ_SECONDS each. Nothing else is
#        registered, so `ctest -L fuzz` is the whole test run of such a build.
#   OFF  (default) tests/fuzz builds the same harnesses with a replay main that runs every file of
#        their corpora once: `fuzz_<name>_replay` tests under the label `unit`, with any compiler.
option(RIM_FUZZ "Build the libFuzzer targets (clang, ASan, UBSan)" OFF)
set(RIM_FUZZ_SECONDS 60 CACHE STRING "Seconds each fuzz target runs under ctest -L fuzz")

if(NOT RIM_FUZZ)
  return()
endif()
if(NOT CMAKE_CXX_COMPILER_ID MATCHES "Clang")
  message(FATAL_ERROR "RIM_FUZZ=ON needs clang (libFuzzer ships with it), not "
                      "${CMAKE_CXX_COMPILER_ID}: configure with CC=clang CXX=clang++ "
                      "(Debian packages clang and libclang-rt-14-dev); see tests/fuzz/run.sh")
endif()
if(RIM_SANITIZE)
  message(FATAL_ERROR "RIM_FUZZ=ON brings its own sanitizers (ASan + UBSan); leave RIM_SANITIZE "
                      "empty in a fuzzing build")
endif()
# fuzzer-no-link: coverage feedback from the libraries too, not only from the harnesses, without
# linking libFuzzer's main into every executable. -fno-sanitize-recover: undefined behaviour is a
# crash that the fuzzer records, not a message it scrolls past. Line tables make reports readable.
add_compile_options(-fsanitize=fuzzer-no-link,address,undefined -fno-sanitize-recover=undefined
                    -fno-omit-frame-pointer -gline-tables-only)
add_link_options(-fsanitize=address,undefined)
message(STATUS "RIM_FUZZ=ON: libFuzzer targets, ${RIM_FUZZ_SECONDS} s each (ctest -L fuzz)")
