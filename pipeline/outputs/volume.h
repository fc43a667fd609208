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
//
// The same rays also project L onto the 9 real spherical harmonics of bands l = 0, 1, 2
// (L2 SH, "sh2"), orthonormal over the sphere (integral of Y_i Y_j dw = delta_ij), in the
// convention of Ramamoorthi & Hanrahan 2001, "An efficient representation for irradiance
// environment maps" (SIGGRAPH 2001, eq. 3; no Condon-Shortley phase: every constant is
// positive), for a unit direction w = (x, y, z) in the world frame (metres, the stage's axes):
//   k  (l, m)   Y_k(w)
//   0  (0, 0)   0.282095                       = 1/2 sqrt(1/pi)
//   1  (1,-1)   0.488603 y                     = 1/2 sqrt(3/pi)
//   2  (1, 0)   0.488603 z
//   3  (1, 1)   0.488603 x
//   4  (2,-2)   1.092548 x y                   = 1/2 sqrt(15/pi)
//   5  (2,-1)   1.092548 y z
//   6  (2, 0)   0.315392 (3 z^2 - 1)           = 1/4 sqrt(5/pi)
//   7  (2, 1)   1.092548 x z
//   8  (2, 2)   0.546274 (x^2 - y^2)           = 1/4 sqrt(15/pi)
// (index k = l (l + 1) + m; the code uses the exact constants, the digits above are rounded).
//   sh2_k = integral of L(w) Y_k(w) dw         (W/m^2 per unit of Y, RGB)
// so sh2_0 = s0 / (2 sqrt(pi)) and sh2_{1,2,3} = sqrt(3 / (4 pi)) s1_{y,z,x}. The irradiance on
// a surface facing n is, to L2 accuracy (R&H eq. 7-8: the clamped cosine's SH convolution
// weights A_0 = pi, A_1 = 2 pi / 3, A_2 = pi / 4),
//   E(n) ~ sum_k A_l(k) sh2_k Y_k(n),
// which R&H show is within about 3 % (9 % worst case) of the exact irradiance of any lighting.
struct ProbeMoments {
    RGB s0;
    std::array<RGB, 3> s1;
    std::array<RGB, 9> sh2{};   // L2 SH projection of L (see above)
    double back_fraction = 0;   // rays that hit a back face: a probe inside a solid sees mostly those
    double hit_fraction = 0;    // rays that hit any surface
    double nearest = -1;        // distance of the closest hit (-1: nothing hit)
};

// The 9 real SH basis functions above at a unit direction d: y[k] = Y_k(d).
void sh2_basis(const Vec3& d, double y[9]);

// `rays` stratified directions per probe (rounded up to a square k x k of equal-area strata
// on the sphere, jittered deterministically from `seed` and the probe index).
std::vector<ProbeMoments> probe_moments(const PatchView& patches, const Visibility& visibility,
                                        const CornerValues& corner_radiance,
                                        const std::vector<Vec3>& points, int rays, uint64_t seed);

// Lightmap sample points moved to the visible side: each point is lifted by `epsilon` along
// its normal; then short rays (length `reach`) go out along the normal and along 8 tangent
// directions. A ray that first hits a back face shows the point is inside or behind
// geometry (under a wall standing on the floor, inside a joint of two slabs): the point is
// moved just past the nearest such hit (plus epsilon along that ray) and lifted again.
// moved[k] = 1 where that happened. With `anchors` (one point per sample, e.g. the mean of
// the samples of the same texel that are not inside anything), the exit is the back face
// hit in the direction closest to the anchor rather than the nearest one: a texel that
// straddles a wall keeps its samples on the side it mostly shows. Normals (and anchors) must
// be one per point (std::invalid_argument).
void lift_samples(const PatchView& patches, const Visibility& visibility, std::vector<Vec3>& points,
                  const std::vector<Vec3>& normals, double epsilon, double reach, std::vector<uint8_t>& moved,
                  const std::vector<Vec3>* anchors = nullptr);

}  // namespace hirad
