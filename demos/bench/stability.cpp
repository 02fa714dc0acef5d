#include "stability.hpp"
