#include "sinew/force.hpp"

namespace sinew {

Index Force::remove_elements_touching(std::span<const std::uint8_t> removed) {
  (void)removed;
  fail(name(), ": cannot remove elements (the force does not implement Force::remove_elements_touching)");
}

}  // namespace sinew
