# ctest pipeline_module: the CLI opens the effects-pipeline module (engine/cli/pipeline.h) only
# for a scene that asks for its outputs. Checks that
# - the CLI itself does not link OpenVDB (no libopenvdb among its NEEDED entries);
# - a scene without pipeline outputs runs with the module missing;
# - a scene with them, and `slurry surface`, stop with exit code 3 and an error naming the path
#   when the module is missing, before writing anything;
# - with the module in place, the scene writes its VDB points and surfaces.
# Arguments: CLI, MODULE (its built path), SCENES (examples/scenes), WORK (a scratch folder).
file(REMOVE_RECURSE ${WORK})
execute_process(COMMAND readelf -d ${CLI} OUTPUT_VARIABLE dynamic RESULT_VARIABLE rc)
if(NOT rc EQUAL 0)
  message(FATAL_ERROR "readelf -d ${CLI} failed: ${rc}")
endif()
if(dynamic MATCHES "libopenvdb")
  message(FATAL_ERROR "the slurry CLI links OpenVDB directly; only its pipeline module should:\n${dynamic}")
endif()
if(NOT EXISTS ${MODULE})
  message(FATAL_ERROR "the pipeline module ${MODULE} was not built")
endif()

set(missing ${WORK}/no_such_module.so)
set(with_outputs ${SCENES}/mesh_snowball_3d.json)
set(without_outputs ${SCENES}/jelly_cubes_2d.json)
execute_process(COMMAND ${CMAKE_COMMAND} -E env SLURRY_PIPELINE_MODULE=${missing}
                        ${CLI} run -q ${without_outputs} --frames 1 --out ${WORK}/plain
  RESULT_VARIABLE rc ERROR_VARIABLE err OUTPUT_QUIET)
if(NOT rc EQUAL 0 OR NOT EXISTS ${WORK}/plain/frame_0001.ply)
  message(FATAL_ERROR "a scene without pipeline outputs needed the module (exit ${rc}): ${err}")
endif()
foreach(args "run;-q;${with_outputs};--frames;1;--out;${WORK}/missing" "surface;-q;${WORK}/plain")
  execute_process(COMMAND ${CMAKE_COMMAND} -E env SLURRY_PIPELINE_MODULE=${missing} ${CLI} ${args}
    RESULT_VARIABLE rc ERROR_VARIABLE err OUTPUT_QUIET)
  string(FIND "${err}" "${missing}: cannot load slurry's effects-pipeline module" at)
  if(NOT rc EQUAL 3 OR at EQUAL -1)
    message(FATAL_ERROR "slurry ${args} without its module: expected exit 3 and an error naming ${missing}, got ${rc}: ${err}")
  endif()
endforeach()
if(EXISTS ${WORK}/missing)
  message(FATAL_ERROR "the run without its module wrote ${WORK}/missing")
endif()
execute_process(COMMAND ${CLI} run -q ${with_outputs} --frames 1 --out ${WORK}/outputs
  RESULT_VARIABLE rc ERROR_VARIABLE err OUTPUT_QUIET)
foreach(f frame_0001.ply points_0001.vdb surface_0001.vdb surface_0001.obj)
  if(NOT rc EQUAL 0 OR NOT EXISTS ${WORK}/outputs/${f})
    message(FATAL_ERROR "with the module: expected ${f} (exit ${rc}): ${err}")
  endif()
endforeach()
