# RIM_SANITIZE: an instrumented build of every rim target, for finding memory errors, undefined
# behaviour and data races in rim's own code (docs/testing.md, "Sanitizers").
#   address  AddressSanitizer + LeakSanitizer + UndefinedBehaviorSanitizer
#   thread   ThreadSanitizer
# Third-party libraries (libtorch, gRPC, protobuf, Draco, ...) are Debian's uninstrumented shared
# libraries; what the runtimes report inside them is suppressed by tests/sanitizers/*.supp.
set(RIM_SANITIZE "" CACHE STRING "Sanitizer build: empty (none), address (ASan+UBSan) or thread")
set_property(CACHE RIM_SANITIZE PROPERTY STRINGS "" address thread)
# Tests take longer under a sanitizer: rim_adapt_tests_to_sanitizer() multiplies their TIMEOUTs
# by this.
set(RIM_SANITIZE_TIMEOUT_SCALE 1)

# Called at the end of tests/CMakeLists.txt; does nothing without RIM_SANITIZE. For the tests added
# in the calling directory: multiplies each TIMEOUT by RIM_SANITIZE_TIMEOUT_SCALE (ctest's default
# of 1500 s for those without one), and disables deploy_dockerfiles, which checks the packages of
# production binaries and so fails on purpose for ones linked to the sanitizer runtimes. Tests found
# by gtest_discover_tests are not known at configure time; tests/sanitizers/run.sh gives them a
# scaled --timeout.
function(rim_adapt_tests_to_sanitizer)
  if(RIM_SANITIZE STREQUAL "")
    return()
  endif()
  get_property(tests DIRECTORY PROPERTY TESTS)
  foreach(test IN LISTS tests)
    get_test_property(${test} TIMEOUT timeout)
    if(NOT timeout)
      set(timeout 1500)
    endif()
    math(EXPR timeout "${timeout} * ${RIM_SANITIZE_TIMEOUT_SCALE}")
    set_tests_properties(${test} PROPERTIES TIMEOUT ${timeout})
  endforeach()
  if(TEST deploy_dockerfiles)
    set_tests_properties(deploy_dockerfiles PROPERTIES DISABLED TRUE)
  endif()
endfunction()

if(RIM_SANITIZE STREQUAL "")
  return()
elseif(RIM_SANITIZE STREQUAL "address")
  # -fno-sanitize-recover: undefined behaviour fails the test instead of printing and going on.
  set(_rim_sanitize_flags -fsanitize=address,undefined -fno-sanitize-recover=undefined)
  set(RIM_SANITIZE_TIMEOUT_SCALE 3)
elseif(RIM_SANITIZE STREQUAL "thread")
  set(_rim_sanitize_flags -fsanitize=thread)
  set(RIM_SANITIZE_TIMEOUT_SCALE 5)
else()
  message(FATAL_ERROR "RIM_SANITIZE='${RIM_SANITIZE}': expected empty, 'address' (ASan+UBSan) "
                      "or 'thread' (TSan)")
endif()
if(NOT CMAKE_CXX_COMPILER_ID STREQUAL "GNU" AND NOT CMAKE_CXX_COMPILER_ID MATCHES "Clang")
  message(FATAL_ERROR "RIM_SANITIZE needs GCC or Clang, not ${CMAKE_CXX_COMPILER_ID}")
endif()
# Frame pointers give the runtimes' fast unwinder whole stacks in reports.
list(APPEND _rim_sanitize_flags -fno-omit-frame-pointer)
add_compile_options(${_rim_sanitize_flags})
add_link_options(${_rim_sanitize_flags})
list(JOIN _rim_sanitize_flags " " _rim_sanitize_flags_text)
message(STATUS "RIM_SANITIZE=${RIM_SANITIZE}: ${_rim_sanitize_flags_text}")

# The runtimes' default options, suppression files included, compiled into every executable
# (tests/sanitizers/default_options.cc.in) rather than set in the environment: they then also reach
# the test binaries that gtest_discover_tests runs at build time, and the rim_server, rimctl and
# rim_sim processes that tests start. ASAN_OPTIONS, TSAN_OPTIONS, ... still override them.
set(RIM_SANITIZER_SUPP_DIR "${PROJECT_SOURCE_DIR}/tests/sanitizers")
configure_file("${RIM_SANITIZER_SUPP_DIR}/default_options.cc.in"
               "${PROJECT_BINARY_DIR}/rim_sanitizer_default_options.cc" @ONLY)

# Runs at the end of the top-level CMakeLists.txt, once every target exists.
function(_rim_add_sanitizer_defaults dir)
  get_property(targets DIRECTORY "${dir}" PROPERTY BUILDSYSTEM_TARGETS)
  foreach(target IN LISTS targets)
    get_target_property(type ${target} TYPE)
    if(type STREQUAL "EXECUTABLE")
      target_sources(${target} PRIVATE "${PROJECT_BINARY_DIR}/rim_sanitizer_default_options.cc")
    endif()
  endforeach()
  get_property(subdirs DIRECTORY "${dir}" PROPERTY SUBDIRECTORIES)
  foreach(subdir IN LISTS subdirs)
    _rim_add_sanitizer_defaults("${subdir}")
  endforeach()
endfunction()
cmake_language(DEFER CALL _rim_add_sanitizer_defaults "${PROJECT_SOURCE_DIR}")
