// The turntable, whatever drives it. The session code only knows this.
#pragma once

#include <string>

#include "core/result.h"

namespace s2r {

class Turntable {
 public:
  virtual ~Turntable() = default;
  // Define the current position as 0 degrees (or run a homing cycle where
  // the hardware has a switch).
  virtual Status home() = 0;
  // Declare the table to stand at `degrees` now, without moving it (after a
  // controller reset, e.g. when a killed capture resumes).
  virtual Status set_position(double degrees) = 0;
  // Absolute move; returns once the table is idle at `degrees` and settled.
  // Absolute targets make a retried or resumed move idempotent.
  virtual Status move_to(double degrees) = 0;
  virtual Result<double> position() = 0;
  virtual std::string describe() const = 0;
};

}  // namespace s2r
