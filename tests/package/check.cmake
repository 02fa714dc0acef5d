# Installs the built sinew into a scratch prefix, configures and builds tests/package against it, and
# runs the result. Arguments: -DBUILD_DIR=... -DSOURCE_DIR=... -DWORK_DIR=...
include("${CMAKE_CURRENT_LIST_DIR}/outside_project.cmake")
file(REMOVE_RECURSE "${WORK_DIR}")
sinew_build_outside_project("${BUILD_DIR}" "${SOURCE_DIR}/tests/package" "${WORK_DIR}" "the outside project")
execute_process(COMMAND "${WORK_DIR}/build/consumer" WORKING_DIRECTORY "${WORK_DIR}" RESULT_VARIABLE rc)
if(rc)
  message(FATAL_ERROR "the outside project's program failed")
endif()
