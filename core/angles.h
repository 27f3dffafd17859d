#pragma once
// Angle units shared by every stage.

#include <numbers>

namespace s2r {

// Radians in one degree: multiply degrees by it, divide radians by it.
inline constexpr double kDeg = std::numbers::pi / 180.0;

}  // namespace s2r
