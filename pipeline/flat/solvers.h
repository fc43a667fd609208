// Solvers for the radiosity system M B = E with M = I - diag(rho) F, one per RGB channel:
//   B_i = E_i + rho_i * sum_j F_ij B_j
// All iterative solvers stop when the relative residual ||E - M B|| / ||E|| (2-norm over
// patches and channels) falls below the tolerance, and report it at every iteration.
#pragma once
#include <cstdint>
#include <functional>
#include <string>
#include <utility>
#include <vector>

#include "pipeline/flat/links.h"
#include "pipeline/core/vecmath.h"

namespace hirad {

struct RadiositySystem {
    const LinkMatrix* links = nullptr;  // may be null for progressive refinement on the fly
    std::vector<double> area;
    std::vector<RGB> reflectance;
    std::vector<RGB> emission;
    uint32_t size() const { return static_cast<uint32_t>(area.size()); }
};

struct IterationReport {
    uint64_t iteration;  // sweeps for Jacobi / Gauss-Seidel, shots for shooting methods
    double residual;     // relative residual of the current solution
    uint32_t shooter;    // patch shot (shooting methods), else UINT32_MAX
};

struct SolverOptions {
    double tolerance = 1e-4;
    uint64_t max_iterations = 1000000;
    // Called after every iteration; return false to stop early.
    std::function<bool(const IterationReport&)> on_iteration;
};

struct Solution {
    std::vector<RGB> radiosity;    // B, W/m^2
    uint64_t iterations = 0;
    double residual = 0;           // final relative residual
    bool converged = false;
    std::vector<double> residual_history;
};

// H = F B: incident flux density (irradiance, W/m^2) at each patch.
std::vector<RGB> gather(const RadiositySystem& system, const std::vector<RGB>& radiosity);
double relative_residual(const RadiositySystem& system, const std::vector<RGB>& radiosity);

// Dense LU (Eigen) on the full matrix: O(n^3), for verifying the others on small scenes.
Solution solve_direct(const RadiositySystem& system);
Solution solve_jacobi(const RadiositySystem& system, const SolverOptions& options);
// Sequential by nature: each update uses the ones before it in the same sweep.
Solution solve_gauss_seidel(const RadiositySystem& system, const SolverOptions& options);
// Southwell: relax the patch with the largest unshot power (residual x area) first.
Solution solve_southwell(const RadiositySystem& system, const SolverOptions& options);

// Progressive refinement (Cohen et al. 1988): Southwell's iteration where the couplings of
// the shooter are computed when it first shoots (form factors on the fly) and cached.
// Every `snapshot_every` shots the display radiosity B + rho * ambient is handed to `snapshot`.
struct ProgressiveOptions : SolverOptions {
    uint64_t snapshot_every = 0;
    std::function<void(uint64_t shot, const std::vector<RGB>& display)> snapshot;
};
using CouplingRow = std::function<void(uint32_t, std::vector<std::pair<uint32_t, float>>&)>;
Solution solve_progressive(const RadiositySystem& system, const CouplingRow& couplings_of,
                           const ProgressiveOptions& options, uint64_t* rows_computed = nullptr);

}  // namespace hirad
