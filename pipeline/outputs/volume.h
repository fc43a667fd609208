// Irradiance volume probes and lightmap sample lifting: ray queries against a solved surface
// field (patch corners with their exitant radiance).
#pragma once
#include <array>
#include <cstdint>
#include <vector>

#include "pipeline/geometry/patches.h"
#include "pipeline/geometry/visibility.h"

namespace hirad {

// What a probe in empty space sees, integrated over the whole sphere of directions ω:
//   s0   = ∫ L(ω) dω                  (W/m², "scalar irradiance", the cosine-free integral)
//   s1_a = ∫ L(ω) ω_a dω  for a=x,y,z (W/m², the first moments: L1 spherical harmonics)
// From them, the L1 estimate of the irradiance on a surface facing n is
//   E(n) ≈ s0 / 4 + (n · s1) / 2.
// L(ω) is the exitant radiance of the first surface hit (bilinear over its corners); back
// faces and escaping rays contribute nothing.
struct ProbeMoments {
    RGB s0;
    std::array<RGB, 3> s1;
    double back_fraction = 0;   // rays that hit a back face: a probe inside a solid sees mostly those
    double hit_fraction = 0;    // rays that hit any surface
    double nearest = -1;        // distance of the closest hit (-1: nothing hit)
};

// `rays` stratified directions per probe (rounded up to a square k x k of equal-area strata
// on the sphere, jittered deterministically from `seed` and the probe index).
std::vector<ProbeMoments> probe_moments(const std::vector<Patch>& patches, const Visibility& visibility,
                                        const std::vector<std::array<RGB, 4>>& corner_radiance,
                                        const std::vector<Vec3>& points, int rays, uint64_t seed);

// Lightmap sample points moved to the visible side: each point is lifted by `epsilon` along
// its normal; then short rays (length `reach`) go out along the normal and along 8 tangent
// directions. A ray that first hits a back face shows the point is inside or behind
// geometry (under a wall standing on the floor, inside a joint of two slabs): the point is
// moved just past the nearest such hit (plus epsilon along that ray) and lifted again.
// moved[k] = 1 where that happened. With `anchors` (one point per sample, e.g. the mean of
// the samples of the same texel that are not inside anything), the exit is the back face
// hit in the direction closest to the anchor rather than the nearest one: a texel that
// straddles a wall keeps its samples on the side it mostly shows.
void lift_samples(const std::vector<Patch>& patches, const Visibility& visibility, std::vector<Vec3>& points,
                  const std::vector<Vec3>& normals, double epsilon, double reach, std::vector<uint8_t>& moved,
                  const std::vector<Vec3>* anchors = nullptr);

}  // namespace hirad
