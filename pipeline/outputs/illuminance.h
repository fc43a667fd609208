// Illuminance at arbitrary points: the read-out of a lighting study's calculation grid.
//
// A sensor is a small plane at a point x facing a unit normal n, anywhere in the scene (in
// free space above a floor, on a wall, at an eye). Its illuminance is
//   E(x, n) = integral over the hemisphere of n of L(x, w) cos(n, w) dw
// split into two parts that are evaluated differently:
//   direct    the light of every emitter patch (a patch with self-emitted radiance Le > 0),
//             integrated exactly: an emitter contributes pi Le F(dA_x -> emitter) V, where F
//             is Lambert's contour integral (formfactors.h, exact for the unoccluded polygon,
//             clipped to the sensor's hemisphere) and V is one shadow ray from x to the
//             emitter's centre; within 4 of its diameters of x it is cut into g x g pieces,
//             each with its own F and shadow ray. A fully visible emitter is therefore exact
//             to rounding; a partly hidden one is resolved to its pieces (near) or to whole
//             emitter patches (far: the patches are small against their distance there).
//   indirect  everything else the surfaces send: cosine-distributed, stratified rays
//             (k x k strata, k = ceil(sqrt(rays))) over the hemisphere; a ray that hits the
//             front of a patch brings (L_corner interpolated - Le) of that patch, a ray that
//             hits a back face or escapes brings nothing; E_ind = pi x the mean.
// So the self-emission of an emitter is counted once, in the exact part, and its reflected
// light (an emitter with a reflectance) in the sampled one. The sensor is never snapped to a
// surface: its value is that of the point itself. A sensor may lie on a surface (a corridor's
// grid at floor level, height 0): its shadow rays, to the emitters, the luminaires and the
// distant lights (RayScene::direct_transmittance, which daylight coefficients read),
// start Visibility::ray_offset() (1e-5 of the scene's size) off it along n, so that the surface under it does not
// block them (a shadow ray from the point itself met the floor at t = 0, and a floor-level
// grid read no direct light from emitting surfaces at all); its hemisphere rays leave it
// along their own directions past a tnear of 1e-7 x the scene's size.
//
// Units: metres; radiance W/(m^2 sr); illuminance W/m^2 per RGB channel (lux when the scene's
// quantities are photometric). Deterministic: each point draws from its own seed.
#pragma once
#include <array>
#include <cstdint>
#include <vector>

#include "pipeline/geometry/patches.h"
#include "pipeline/geometry/visibility.h"

namespace hirad {

struct IlluminanceOptions {
    int rays = 512;            // hemisphere rays for the indirect part (0: direct only)
    int emitter_samples = 4;   // g: each emitter patch cut into g x g pieces for its visibility
    uint64_t seed = 1;
};

// The indirect part's rays without their values: `rays` rays a sensor (k x k, k = ceil of sqrt
// of the rays asked), each giving the front-facing surfaces it reads: the hit past any clear
// glass, and each pane it crossed from its front (seen_through_glass), as entries (sensor,
// patch, Embree's u, v, weight: the glass passed before that surface, 1 without), sensor by
// sensor, ray by ray. The indirect illuminance of any corner radiance L (zero emission) is
// pi / rays x the sum of weight x L interpolated at a sensor's entries: linear in L, so the
// rays of a grid are traced once for many solutions (daylight coefficients,
// hirad.daylight.coefficients).
struct HemisphereHits {
    int rays = 0;
    std::vector<int32_t> sensor, patch;
    std::vector<double> u, v, weight;
};

struct Illuminance {
    std::vector<RGB> direct;    // from the emitter patches, exact where unoccluded, W/m^2
    std::vector<RGB> indirect;  // from every other surface's exitant radiance, W/m^2
};

// `corner_radiance` (per patch, 4 corners) is the full exitant radiance; `emitted` (per patch)
// its self-emitted part Le, W/(m^2 sr). Throws std::invalid_argument on mismatched lengths,
// a zero normal or non-finite input.
Illuminance illuminance_at(const PatchView& patches, const Visibility& visibility,
                           const CornerValues& corner_radiance, const std::vector<RGB>& emitted,
                           const std::vector<Vec3>& points, const std::vector<Vec3>& normals,
                           const IlluminanceOptions& options);

// The indirect part's rays of illuminance_at (the same rays for the same seed), traced once.
HemisphereHits hemisphere_hits(const PatchView& patches, const Visibility& visibility,
                               const std::vector<Vec3>& points, const std::vector<Vec3>& normals, int rays,
                               uint64_t seed);

// The g x g pieces of a patch as polygons (quads: bilinear sub-quads, planar when the patch
// is; triangles: the g^2 triangles of its barycentric grid, repeated corner 2 as corner 3).
// Their areas sum to the patch's. Exposed for tests.
std::vector<Patch> patch_pieces(const Patch& patch, int g);

}  // namespace hirad
