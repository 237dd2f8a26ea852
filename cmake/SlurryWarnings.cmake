# Warnings as an INTERFACE target linked PRIVATE by our own targets only, so that
# projects embedding Slurry do not inherit our flags.
add_library(slurry_warnings INTERFACE)
target_compile_options(slurry_warnings INTERFACE
  $<$<CXX_COMPILER_ID:GNU,Clang>:-Wall -Wextra -Wpedantic> $<$<CXX_COMPILER_ID:GNU>:-Wno-maybe-uninitialized>)
add_library(slurry_native INTERFACE)
if(SLURRY_NATIVE)
  include(CheckCXXCompilerFlag)
  check_cxx_compiler_flag(-march=native SLURRY_HAS_MARCH_NATIVE)
  if(SLURRY_HAS_MARCH_NATIVE)
    target_compile_options(slurry_native INTERFACE -march=native)
    # GCC 12 reports -Warray-bounds inside its own AVX-512 intrinsics when it vectorizes Eigen's
    # fixed-capacity dynamic vectors (the implicit update's 9x9 blocks): a false positive on code
    # that never reads past the capacity. Silenced for our targets only.
    target_compile_options(slurry_native INTERFACE $<$<CXX_COMPILER_ID:GNU>:-Wno-array-bounds>)
  else()
    message(STATUS "Slurry: the compiler does not take -march=native; building for its default target")
  endif()
endif()
