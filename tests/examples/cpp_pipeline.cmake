# ctest cpp_pipeline_example: installs the package into PREFIX, builds examples/cpp against it as
# a separate project (find_package(Slurry), target slurry::slurry, nothing of the build tree) and
# runs the program, which checks what it reads (exit 0).
file(REMOVE_RECURSE ${PREFIX} ${WORK})
execute_process(COMMAND ${CMAKE_COMMAND} --install ${BUILD_DIR} --prefix ${PREFIX} RESULT_VARIABLE rc OUTPUT_QUIET)
if(NOT rc EQUAL 0)
  message(FATAL_ERROR "cmake --install ${BUILD_DIR} failed: ${rc}")
endif()
foreach(step "-S;${SOURCE};-B;${WORK};-DCMAKE_PREFIX_PATH=${PREFIX};-DCMAKE_BUILD_TYPE=Release" "--build;${WORK}")
  execute_process(COMMAND ${CMAKE_COMMAND} ${step} RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
  if(NOT rc EQUAL 0)
    message(FATAL_ERROR "cmake ${step} failed (${rc}):\n${out}\n${err}")
  endif()
endforeach()
execute_process(COMMAND ${WORK}/pipeline RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
message("${out}${err}")
if(NOT rc EQUAL 0)
  message(FATAL_ERROR "the pipeline example exited ${rc}")
endif()
