# sinew_build_options: the compile and link flags of sinew's own targets, as an INTERFACE target that
# each of them links PRIVATE. Nothing here is global: a project that embeds sinew with
# add_subdirectory keeps its own flags, and the installed sinew:: targets carry none of these (the
# libraries link it through $<BUILD_INTERFACE:...>).
add_library(sinew_build_options INTERFACE)

# Determinism: no fused multiply-add contraction, so results do not depend on what the compiler
# chooses to fuse; warnings on and treated seriously.
target_compile_options(sinew_build_options INTERFACE -Wall -Wextra -Wpedantic -Wshadow -ffp-contract=off)

# Release speed with assertions kept: sinew's invariants stay checked in every build. CMake's Release
# flags are "-O3 -DNDEBUG"; these come after them on the command line, and GCC and Clang take the
# last -O and process -D/-U in order, so sinew compiles at -O2 without NDEBUG (the level at which
# tests/state_hashes.txt was recorded), whatever the cache says.
target_compile_options(sinew_build_options INTERFACE $<$<CONFIG:Release>:-O2> -UNDEBUG)

if(SINEW_SANITIZE)
  target_compile_options(sinew_build_options INTERFACE -fsanitize=address,undefined -fno-sanitize-recover=all
                                                       -fno-omit-frame-pointer)
  target_link_options(sinew_build_options INTERFACE -fsanitize=address,undefined)
endif()

# Eigen's per-coefficient index checks cost about 30% of the step; the sanitizer build keeps them
# (SINEW_EIGEN_CHECKS). Every sinew translation unit must agree on this, tests included.
if(NOT SINEW_EIGEN_CHECKS)
  target_compile_definitions(sinew_build_options INTERFACE EIGEN_NO_DEBUG)
endif()
