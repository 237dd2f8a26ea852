# ctest install_examples: installs the examples component into PREFIX and runs two installed
# examples that read meshes through relative paths ("../meshes/"), for one frame each: the FEM
# ball (a TetGen mesh) and the mesh snowball (OBJ files).
file(REMOVE_RECURSE ${PREFIX})
execute_process(COMMAND ${CMAKE_COMMAND} --install ${BUILD_DIR} --prefix ${PREFIX} --component examples
  RESULT_VARIABLE rc OUTPUT_QUIET)
if(NOT rc EQUAL 0)
  message(FATAL_ERROR "cmake --install --component examples failed: ${rc}")
endif()
foreach(name fem_ball_3d mesh_snowball_3d)
  set(scene ${PREFIX}/share/slurry/examples/${name}.json)
  if(NOT EXISTS ${scene})
    message(FATAL_ERROR "${name}.json was not installed under ${PREFIX}/share/slurry/examples")
  endif()
  foreach(args "validate;${scene}" "run;-q;${scene};--frames;1;--out;${PREFIX}/${name}")
    execute_process(COMMAND ${CLI} ${args} RESULT_VARIABLE rc ERROR_VARIABLE err OUTPUT_QUIET)
    if(NOT rc EQUAL 0)
      message(FATAL_ERROR "slurry ${args} exited ${rc}: ${err}")
    endif()
  endforeach()
  if(NOT EXISTS ${PREFIX}/${name}/frame_0001.ply)
    message(FATAL_ERROR "the installed example ${name} wrote no frame 1")
  endif()
endforeach()
