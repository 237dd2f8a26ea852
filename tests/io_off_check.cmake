# The solver core without OpenVDB and MPI (ctest io.core_without_openvdb): configures Slurry with
# -DSLURRY_WITH_OPENVDB=OFF -DSLURRY_BUILD_MPI=OFF in a scratch directory, compiles the CLI's
# main.cpp there (the one source with IO-less and MPI-less branches), and checks that no source
# of the core (engine/, transfer/, constitutive/) includes an OpenVDB or MPI header and that the
# core's link interface names neither.
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
execute_process(COMMAND ${CMAKE_COMMAND} --build ${WORK}/engine --target cli/main.cpp.o
                RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
if(NOT rc EQUAL 0)
  message(FATAL_ERROR "the CLI's main.cpp does not compile without slurry::io:\n${out}\n${err}")
endif()
file(GLOB_RECURSE core LIST_DIRECTORIES false ${SOURCE}/engine/* ${SOURCE}/transfer/* ${SOURCE}/constitutive/*)
foreach(f ${core})
  if(f MATCHES "/engine/cli/pipeline\\.(h|cpp)$")
    continue()  # the CLI's io part, compiled only with slurry::io
  endif()
  file(STRINGS ${f} hits REGEX "#include [<\"](openvdb|slurry/io/|mpi\\.h|slurry/mpi/)")
  if(hits AND NOT f MATCHES "/engine/cli/main\\.cpp$")  # main.cpp includes slurry/mpi/ under SLURRY_WITH_MPI only
    message(FATAL_ERROR "${f} includes OpenVDB, MPI, slurry::io or slurry::mpi: ${hits}")
  endif()
endforeach()
file(STRINGS ${SOURCE}/engine/CMakeLists.txt hits REGEX "OpenVDB|slurry::io|MPI")
if(hits)
  message(FATAL_ERROR "engine/CMakeLists.txt names OpenVDB, MPI or slurry::io: ${hits}")
endif()
file(REMOVE_RECURSE ${WORK})
message(STATUS "the core configures and the CLI compiles without OpenVDB and without MPI")
