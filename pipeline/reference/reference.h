// A Monte Carlo reference for the radiosity solution, independent of form factors and
// meshing (in the spirit of Ward, Rubinstein and Clear 1988): exitant radiance at surface
// points by path tracing diffuse interreflection with Embree, with next-event estimation
// towards the emitting patches and Russian roulette, each estimate with its standard error.
// Luminaires (luminaire.h) are evaluated exactly at every path vertex (their light is a
// point-to-point term with one shadow ray per luminaire point), never through the patches'
// averaged `direct`; a patch's self-emission is its emission less rho x direct.
//
// Glass (visibility.h: a patch with a normal transmittance tau0 > 0) is traced as what it is,
// a thin sheet that lets light straight through with T(theta) = tau0 r(cos theta) and reflects
// its reflectance diffusely on the side it is met from: a path that meets glass passes it with
// probability T / (T + max rho) (the weight T over that probability) or is reflected there
// (the weight rho over the rest); next-event rays to the emitters pass glass with T, as the
// luminaires' rays do. hirad's solution treats glass the same way (Hierarchy::glass: links and
// the final gather pass panes with T); the reference does it by paths, independently of the
// links. Several panes on one path multiply.
#pragma once
#include <cstdint>
#include <vector>

#include "pipeline/geometry/luminaire.h"
#include "pipeline/geometry/patches.h"
#include "pipeline/geometry/visibility.h"

namespace hirad {

struct ReferenceOptions {
    int paths = 1024;       // paths per point
    int min_bounces = 3;    // Russian roulette starts after this many bounces
    uint64_t seed = 1;
};

struct ReferenceEstimate {
    RGB radiance;        // exitant radiance, W/(m^2 sr)
    RGB standard_error;  // of `radiance`
};

// Exitant radiance at the point (s, t) of each given patch (Patch::point coordinates).
std::vector<ReferenceEstimate> reference_radiance(const std::vector<Patch>& patches, const Visibility& visibility,
                                                  const std::vector<uint32_t>& patch, const std::vector<Vec2>& st,
                                                  const ReferenceOptions& options,
                                                  const std::vector<Luminaire>& luminaires = {});

}  // namespace hirad
