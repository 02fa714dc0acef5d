# Shared by tests/package/check.cmake and tests/readme/check.cmake: an outside project built against
# an installed sinew, as find_package(sinew) users build theirs.

# Installs the sinew built in BUILD_DIR into WORK_DIR/prefix, then configures and builds the CMake
# project in SOURCE into WORK_DIR/build against it. WHAT names the project in the failure messages.
function(sinew_build_outside_project BUILD_DIR SOURCE WORK_DIR WHAT)
  execute_process(COMMAND ${CMAKE_COMMAND} --install "${BUILD_DIR}" --prefix "${WORK_DIR}/prefix"
                  OUTPUT_QUIET RESULT_VARIABLE rc)
  if(rc)
    message(FATAL_ERROR "install failed")
  endif()
  execute_process(COMMAND ${CMAKE_COMMAND} -S "${SOURCE}" -B "${WORK_DIR}/build"
                          -DCMAKE_PREFIX_PATH=${WORK_DIR}/prefix -DCMAKE_BUILD_TYPE=Release RESULT_VARIABLE rc)
  if(rc)
    message(FATAL_ERROR "configuring ${WHAT} failed")
  endif()
  execute_process(COMMAND ${CMAKE_COMMAND} --build "${WORK_DIR}/build" RESULT_VARIABLE rc)
  if(rc)
    message(FATAL_ERROR "building ${WHAT} failed (see above)")
  endif()
endfunction()
