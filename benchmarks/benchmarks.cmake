foreach(b bench_svd bench_mpm_step bench_implicit bench_fem bench_sleep)
  if(EXISTS ${CMAKE_CURRENT_SOURCE_DIR}/${b}.cpp)
    slurry_add_benchmark(${b} ${b}.cpp)
  endif()
endforeach()
if(EXISTS ${CMAKE_CURRENT_SOURCE_DIR}/bench_flip.cpp)
  slurry_add_benchmark(bench_flip bench_flip.cpp)
  target_compile_definitions(bench_flip PRIVATE SLURRY_EXAMPLES_DIR="${PROJECT_SOURCE_DIR}/examples/scenes")
endif()
if(EXISTS ${CMAKE_CURRENT_SOURCE_DIR}/bench_pressure.cpp)
  slurry_add_benchmark(bench_pressure bench_pressure.cpp)
endif()
# The speed-against-accuracy study (benchmarks/tradeoff/README.md): a plain program, not a
# Google Benchmark; its reduced version is a ctest test in the label "accuracy", run by CI
# (about 25 s on 2 cores): error bounds, observed orders and the presets' order.
if(EXISTS ${CMAKE_CURRENT_SOURCE_DIR}/tradeoff/tradeoff.cpp)
  add_executable(tradeoff tradeoff/tradeoff.cpp)
  target_link_libraries(tradeoff PRIVATE slurry::slurry slurry_warnings slurry_native)
  set_target_properties(tradeoff PROPERTIES RUNTIME_OUTPUT_DIRECTORY ${PROJECT_BINARY_DIR}/bin)
  if(SLURRY_BUILD_TESTS)
    add_test(NAME tradeoff_reduced
             COMMAND tradeoff --reduced --check --jobs 2 --out ${CMAKE_CURRENT_BINARY_DIR}/tradeoff_reduced)
    set_tests_properties(tradeoff_reduced PROPERTIES LABELS accuracy PROCESSORS 2 TIMEOUT 900
                         ENVIRONMENT "OMP_NUM_THREADS=1")
  endif()
endif()
# Scaling over MPI processes (run under mpirun).
if(SLURRY_BUILD_MPI AND EXISTS ${CMAKE_CURRENT_SOURCE_DIR}/bench_mpi.cpp)
  slurry_add_benchmark(bench_mpi bench_mpi.cpp)
  target_link_libraries(bench_mpi PRIVATE slurry::mpi)
endif()
# Slurry against the 88-line MLS-MPM reference's high-resolution set-up.
if(EXISTS ${CMAKE_CURRENT_SOURCE_DIR}/bench_mls88.cpp)
  slurry_add_benchmark(bench_mls88 bench_mls88.cpp)
  target_compile_definitions(bench_mls88 PRIVATE SLURRY_BENCH_SCENES_DIR="${CMAKE_CURRENT_SOURCE_DIR}/scenes")
endif()
# Surfacing a frame of the 3D FLIP dam break against simulating one (needs slurry::vdb).
if(TARGET slurry_vdb AND EXISTS ${CMAKE_CURRENT_SOURCE_DIR}/bench_surface.cpp)
  slurry_add_benchmark(bench_surface bench_surface.cpp)
  target_link_libraries(bench_surface PRIVATE slurry::vdb)
  target_compile_definitions(bench_surface PRIVATE SLURRY_EXAMPLES_DIR="${PROJECT_SOURCE_DIR}/examples/scenes")
endif()
