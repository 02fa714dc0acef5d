# Every ```cpp block of README.md compiles as written, and a block with a main() runs and exits 0.
# Each block is its own translation unit, built as an outside project against the installed sinew
# (sinew::bullet and sinew::mesh), like tests/package. The first block must also appear verbatim in
# SAME_AS (demos/hello.cpp), so the README shows the program the build ships.
# Arguments: -DREADME=... -DSAME_AS=... -DBUILD_DIR=... -DWORK_DIR=...
cmake_minimum_required(VERSION 3.25)
file(REMOVE_RECURSE "${WORK_DIR}")
file(READ "${README}" text)

# Walk the file with string(FIND) rather than a list of regex matches: code holds ';' and '[', which
# CMake lists would split or refuse to split.
set(blocks 0)
set(targets "")
set(rest "${text}")
while(TRUE)
  string(FIND "${rest}" "```cpp\n" start)
  if(start EQUAL -1)
    break()
  endif()
  math(EXPR start "${start} + 7")
  string(SUBSTRING "${rest}" ${start} -1 rest)
  string(FIND "${rest}" "\n```" end)
  if(end EQUAL -1)
    message(FATAL_ERROR "${README}: a ```cpp block is not closed")
  endif()
  string(SUBSTRING "${rest}" 0 ${end} code)
  string(SUBSTRING "${rest}" ${end} -1 rest)
  math(EXPR blocks "${blocks} + 1")
  file(WRITE "${WORK_DIR}/src/block_${blocks}.cpp" "${code}\n")
  if(blocks EQUAL 1 AND SAME_AS)
    file(READ "${SAME_AS}" same)
    string(FIND "${same}" "${code}" found)
    if(found EQUAL -1)
      message(FATAL_ERROR "README.md's first ```cpp block is not a verbatim part of ${SAME_AS}")
    endif()
  endif()
  string(FIND "${code}" "int main(" has_main)
  if(has_main EQUAL -1)
    string(APPEND targets "add_library(block_${blocks} OBJECT block_${blocks}.cpp)\n")
  else()
    string(APPEND targets "add_executable(block_${blocks} block_${blocks}.cpp)\n")
    list(APPEND programs block_${blocks})
  endif()
  string(APPEND targets "target_link_libraries(block_${blocks} PRIVATE sinew::bullet sinew::mesh)\n")
endwhile()
if(blocks EQUAL 0)
  message(FATAL_ERROR "${README} has no ```cpp block")
endif()
message(STATUS "${README}: ${blocks} C++ block(s)")

file(WRITE "${WORK_DIR}/src/CMakeLists.txt"
     "cmake_minimum_required(VERSION 3.25)\nproject(sinew_readme LANGUAGES CXX)\n"
     "find_package(sinew REQUIRED)\n${targets}")
include("${CMAKE_CURRENT_LIST_DIR}/../package/outside_project.cmake")
sinew_build_outside_project("${BUILD_DIR}" "${WORK_DIR}/src" "${WORK_DIR}"
                            "the ```cpp blocks of ${README} (one per file in ${WORK_DIR}/src)")
foreach(program IN LISTS programs)
  execute_process(COMMAND "${WORK_DIR}/build/${program}" WORKING_DIRECTORY "${WORK_DIR}" RESULT_VARIABLE rc)
  if(rc)
    message(FATAL_ERROR "${program} (block ${program} of ${README}) exited with ${rc}")
  endif()
endforeach()
