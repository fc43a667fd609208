// Checks every solver makes, so that a non-finite number is never handed on (to the
// outputs, to the next round) and a diverging solve stops at once instead of running to its
// iteration limit.
#pragma once
#include <cmath>
#include <cstdint>
#include <sstream>
#include <stdexcept>
#include <string>

namespace hirad {

// A solve whose residual stopped being a finite number: its radiosity is NaN or infinite.
struct NonFiniteError : std::runtime_error {
    using std::runtime_error::runtime_error;
};

// Throws NonFiniteError naming the solver, the step and the value when `residual` is NaN or
// infinite.
inline void require_finite_residual(const std::string& solver, double residual, uint64_t step,
                                    const char* step_name = "iteration") {
    if (std::isfinite(residual)) return;
    std::ostringstream msg;
    msg << solver << ": the residual is " << residual << " at " << step_name << " " << step
        << ": the radiosity is no longer finite (a NaN or infinite emission, reflectance or coupling, or a"
           " reflectance of 1 or more that makes the solve diverge); stopped, nothing was written";
    throw NonFiniteError(msg.str());
}

}  // namespace hirad
