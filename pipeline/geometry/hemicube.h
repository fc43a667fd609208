// The hemicube (Cohen and Greenberg 1985): a second, independent way to compute form
// factors. Around a point on the receiving patch, the five faces of a half cube are
// software z-buffers; every patch is projected onto them, the nearest patch wins each cell,
// and F(dA -> A_j) is the sum of the delta form factors of the cells j owns:
//   top face (z = 1):   dF = dA / (pi (x^2 + y^2 + 1)^2)
//   side faces (y = 1): dF = z dA / (pi (x^2 + z^2 + 1)^2)
// One hemicube at the centre gives a differential form factor, which is 20 % off for two unit
// squares at distance 1; hirad places hemicubes at several stratified points over the patch
// and averages them, which converges to the area form factor.
#pragma once
#include <cstdint>
#include <utility>
#include <vector>

#include "pipeline/geometry/patches.h"

namespace hirad {

struct HemicubeOptions {
    int resolution = 128;  // cells along the top face's edge (side faces are res x res/2)
    int points = 4;        // hemicubes per patch, on a stratified sqrt(points)^2 grid
};

class Hemicube {
public:
    Hemicube(const std::vector<Patch>& patches, const HemicubeOptions& options);

    // F_ij for every patch j seen from patch i, as (j, F_ij) sorted by j, zeros omitted.
    void row(uint32_t i, std::vector<std::pair<uint32_t, double>>& out) const;

    // One hemicube at x with normal n: adds weight * F(dA_x -> A_j) into accum[j] (size n).
    // Patch `exclude` (the receiver itself) is not rasterised.
    void accumulate(const Vec3& x, const Vec3& n, uint32_t exclude, double weight,
                    std::vector<double>& accum) const;

private:
    const std::vector<Patch>& patches_;
    HemicubeOptions options_;
    std::vector<double> top_delta_;   // res*res delta form factors of the top face
    std::vector<double> side_delta_;  // res*(res/2) of one side face (all four are alike)
};

}  // namespace hirad
