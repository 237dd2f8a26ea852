# Warnings as an INTERFACE target linked PRIVATE by our own targets only, so that
# projects embedding Slurry do not inherit our flags.
add_library(slurry_warnings INTERFACE)
target_compile_options(slurry_warnings INTERFACE
  $<$<CXX_COMPILER_ID:GNU,Clang>:-Wall -Wextra -Wpedantic -Wno-maybe-uninitialized>)
add_library(slurry_native INTERFACE)
if(SLURRY_NATIVE)
  target_compile_options(slurry_native INTERFACE -march=native)
endif()
