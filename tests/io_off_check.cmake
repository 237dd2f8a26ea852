# The solver core without OpenVDB and MPI (ctest io.core_without_openvdb): configures Slurry with
# -DSLURRY_WITH_OPENVDB=OFF -DSLURRY_BUILD_MPI=OFF in a scratch directory, compiles the CLI's
# sources with OpenVDB-less and MPI-less branches there, and checks that no source of engine/,
# transfer/ or constitutive/ includes an OpenVDB or MPI header (but for the CLI's module and its
# MPI start), that the solver core includes no file format, and that engine/CMakeLists.txt names
# neither OpenVDB nor MPI.
#   cmake -DSOURCE=<slurry> -DWORK=<scratch dir> -P io_off_check.cmake
file(REMOVE_RECURSE ${WORK})
execute_process(COMMAND ${CMAKE_COMMAND} -S ${SOURCE} -B ${WORK} -G "Unix Makefiles" -DSLURRY_WITH_OPENVDB=OFF -DSLURRY_BUILD_MPI=OFF -DSLURRY_BUILD_TESTS=OFF
                        -DSLURRY_BUILD_BENCHMARKS=OFF -DSLURRY_BUILD_EXAMPLES=OFF -DCMAKE_BUILD_TYPE=Release
                RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
if(NOT rc EQUAL 0)
  message(FATAL_ERROR "configure with SLURRY_WITH_OPENVDB=OFF failed:\n${out}\n${err}")
endif()
file(READ ${WORK}/CMakeCache.txt cache)
if(cache MATCHES "OpenVDB_DIR|OpenVDB_INCLUDE_DIR|SLURRY_OPENVDB_MODULE_DIR")
  message(FATAL_ERROR "configure with SLURRY_WITH_OPENVDB=OFF looked for OpenVDB")
endif()
if(cache MATCHES "MPI_CXX_COMPILER|MPI_CXX_HEADER_DIR")
  message(FATAL_ERROR "configure with SLURRY_BUILD_MPI=OFF looked for MPI")
endif()
execute_process(COMMAND ${CMAKE_COMMAND} --build ${WORK}/engine --target cli/main.cpp.o cli/command.cpp.o cli/run_command.cpp.o
                RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
if(NOT rc EQUAL 0)
  message(FATAL_ERROR "the CLI's sources with OpenVDB- and MPI-less branches do not compile without them:\n${out}\n${err}")
endif()
file(GLOB_RECURSE core LIST_DIRECTORIES false ${SOURCE}/engine/* ${SOURCE}/transfer/* ${SOURCE}/constitutive/*)
foreach(f ${core})
  # OpenVDB and the pipeline outputs: only the CLI's module (pipeline.h, pipeline.cpp).
  file(STRINGS ${f} hits REGEX "#include [<\"](openvdb|slurry/io/surface\\.h|slurry/io/pipeline\\.h)")
  if(hits AND NOT f MATCHES "/engine/cli/pipeline\\.(h|cpp)$")
    message(FATAL_ERROR "${f} includes OpenVDB or the pipeline outputs: ${hits}")
  endif()
  # MPI: only the CLI's sources that start a session (under SLURRY_WITH_MPI).
  file(STRINGS ${f} hits REGEX "#include [<\"](mpi\\.h|slurry/mpi/)")
  if(hits AND NOT f MATCHES "/engine/cli/(main|command|run_command)\\.cpp$")
    message(FATAL_ERROR "${f} includes MPI or slurry::mpi: ${hits}")
  endif()
  # File formats: not the solver core (everything but run/, cli/ and the umbrella slurry.h).
  file(STRINGS ${f} hits REGEX "#include [<\"]slurry/io/")
  if(hits AND NOT f MATCHES "/engine/(cli/|src/run/|include/slurry/engine/run/|include/slurry/slurry\\.h$)")
    message(FATAL_ERROR "${f} is part of the solver core and includes a file format (slurry/io/): ${hits}")
  endif()
endforeach()
file(STRINGS ${SOURCE}/engine/CMakeLists.txt hits REGEX "OpenVDB|slurry::vdb|MPI")
if(hits)
  message(FATAL_ERROR "engine/CMakeLists.txt names OpenVDB, slurry::vdb or MPI: ${hits}")
endif()
file(REMOVE_RECURSE ${WORK})
message(STATUS "the core configures and the CLI compiles without OpenVDB and without MPI; the solver core includes no file format")
