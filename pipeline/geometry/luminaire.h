// Luminaires: light sources that are not Lambertian surfaces (point lights, spots, IES
// profiles, sphere and cylinder lights, shaped area lights). A luminaire is a table of
// luminous intensity I(C, gamma) in its own frame, emitted from a few points over its luminous
// opening; it is not part of the surfaces and reflects nothing.
//
// Frame and angles (the IES LM-63 type C convention, as hirad.photometry.ies):
//   gamma = 0 is the light's local -Z (nadir), gamma = 180 its +Z;
//   C = 0 is local +X, C = 90 local +Y (C turns counter-clockwise seen from +Z);
//   local direction (gamma, C) = (sin gamma cos C, sin gamma sin C, -cos gamma).
// The table holds I at C_i = 360 i / nc (i < nc, periodic) and gamma_j = 180 j / (ng - 1) and
// is bilinear in (C, gamma) between its nodes; nc = 1 is a rotationally symmetric profile.
//
// The flux of the table is integrated exactly: in a cell [C_i, C_i+1] x [g_j, g_j+1] the C
// integral of the bilinear I is dC times the mean of the two C edges, m(gamma), linear in
// gamma; with h = g_j+1 - g_j,
//   integral of m(gamma) sin(gamma) over the cell = m_j (S - B) + m_j+1 B,
//   S = cos g_j - cos g_j+1,  B = (sin g_j+1 - sin g_j - h cos g_j+1) / h.
// So the flux the engine emits is the flux it accounts for, and the energy balance closes.
//
// Direct light at a receiver x with normal n (the first bounce, the only non-diffuse one):
//   H(x, n) = sum_k w_k I(R^T (x - p_k) / r_k) max(0, n . (p_k - x) / r_k) / r_k^2 V(x, p_k)
// over the luminaire's points p_k with weights w_k (sum 1), r_k = |x - p_k|, V one Embree
// shadow ray. It is exact for a point source and converges with the points for an extended
// one (the near field of a long cylinder or a large panel). After that bounce, everything is
// diffuse: a surface that receives H re-emits rho H like self-emission.
//
// Distant lights (distant = true): the sun, and the patches of a sky dome. They are too far for
// their points to matter: `points` are unit world directions d_k towards the light (from the
// scene to the sky), `weights` split the light over them, and `illuminance` E_perp is what a
// surface facing the light squarely receives, per unit colour (lux or W/m^2):
//   H(x, n) = E_perp sum_k w_k max(0, n . d_k) T(x, d_k)
// with T the transmittance of a ray from x towards d_k out of the scene (0 when blocked, the
// glazing's factors through windows, visibility.h). A sun of angular diameter a is a few
// directions over its disk; a sky patch of luminance L and solid angle Omega is E_perp = L Omega
// over directions inside the patch (hirad.daylight.sources). They have no flux of their own
// (the light on the scene depends on the scene): flux() is 0 and the engine counts what they
// deliver to the surfaces. Frame and candela table are unused.
//
// Units: metres; intensity in cd (photometric scenes) or W/sr (radiometric), per RGB
// channel = candela x colour; flux in lm or W; irradiance in lux or W/m^2.
#pragma once
#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "pipeline/core/vecmath.h"

namespace hirad {

class Visibility;

struct Luminaire {
    std::string name;
    std::vector<Vec3> points;     // world positions, m
    std::vector<double> weights;  // per point, >= 0, sum 1
    Vec3 axis[3];                 // local X, Y, Z in world space (orthonormal, right-handed)
    int nc = 1, ng = 2;           // table size
    std::vector<double> candela;  // nc x ng, row-major: candela[i * ng + j] = I(C_i, gamma_j)
    RGB colour{1, 1, 1};          // channel multiplier
    bool distant = false;         // a distant light: points are directions (see above)
    double illuminance = 0;       // distant: E_perp per unit colour, lux or W/m^2
    std::vector<RGB> tints;       // distant, optional: per direction a colour times `colour` (a
                                  // textured dome's cells in one light); empty: all white
    bool interleave = false;      // distant: one part of a sky cut into many lights (the sky
                                  // patches of daylight coefficients): on elements, interleaved
                                  // with the other such lights of the list as one sky
                                  // (kSkyDirections), whatever its own size

    // Checks the data (sizes, finiteness, weights, frame); throws std::invalid_argument
    // naming the luminaire and the problem.
    void validate() const;
    // I (per unit colour) toward a world direction (any length > 0).
    double intensity(const Vec3& world_direction) const;
    // The exact flux of the table per unit colour (lm or W); times colour for RGB. 0 for a
    // distant light.
    double table_flux() const;
    RGB flux() const { return colour * table_flux(); }
    // A 64-bit hash of everything that determines the light (for the run store).
    uint64_t fingerprint() const;
};

// Direct irradiance from every luminaire at receivers x[k] facing n[k] (unit). Receivers are
// lifted by `lift` along their normal before the shadow rays (a surface point does not shadow
// itself). Parallel over receivers; deterministic. `visibility` may be null (no occlusion).
void luminaire_irradiance(const std::vector<Luminaire>& luminaires, const Visibility* visibility, const Vec3* x,
                          const Vec3* n, size_t count, RGB* out, double lift);

// The same at one receiver, on the calling thread (a path tracer's vertex).
RGB luminaire_irradiance_at(const std::vector<Luminaire>& luminaires, const Visibility* visibility, const Vec3& x,
                            const Vec3& n, double lift);

// The luminaires' light arriving at points in free space (irradiance probes), as full-sphere
// moments: s0 = sum_k w_k I / r_k^2 V (the cosine-free integral of a point source's delta of
// radiance) and s1_a = the same sum times the unit direction towards the light, component a.
// Adds to s0 and s1 (they hold the surfaces' part already).
void luminaire_moments(const std::vector<Luminaire>& luminaires, const Visibility* visibility, const Vec3* x,
                       size_t count, RGB* s0, std::array<RGB, 3>* s1);

// The luminaires' light over a surface element: the mean of H at the g x g stratum centres
// of the element (Patch::point; skies interleaved over them, kSkyDirections), and the spread (max - min of the luminance Y of H over
// those points, W/m^2 or lux), which says whether the element resolves the light. For many
// elements at once (parallel over elements): `mean` and `spread` are resized to the count.
struct Patch;
void element_luminaire_irradiance(const std::vector<Luminaire>& luminaires, const Visibility& visibility,
                                  const Patch* const* elements, size_t count, int g, std::vector<RGB>& mean,
                                  std::vector<double>& spread);

// element_luminaire_irradiance for many light groups at once: `group[l]` is luminaire l's group
// (< groups); out[q * count + e] the mean direct light of group q over element e. Each
// element's points trace the rays of all groups' lights together, so lights marked
// `interleave` (a sky cut into one group per patch) cost an element one ray per direction in
// all, not g^2 per direction per group; the groups' sum is the light of the whole sky as
// element_luminaire_irradiance would interleave it. `sky_start`: the interleaved directions
// that come before these lights (a sky's groups lit in batches number their directions on).
void element_group_irradiance(const std::vector<Luminaire>& luminaires, const std::vector<uint32_t>& group,
                              size_t groups, const Visibility& visibility, const Patch* const* elements, size_t count,
                              int g, std::vector<RGB>& out, size_t sky_start = 0);

// Far directions seen from points (daylight coefficients, sun hours): out[p * D + d] =
// max(0, n_p . d_d) T(x_p lifted by `lift` along n_p, d_d), T the transmittance of the ray out
// of the scene (0 blocked, glass factors). Directions must be unit. Parallel over points.
void distant_transmittance(const Visibility& visibility, const Vec3* x, const Vec3* n, size_t count,
                           const std::vector<Vec3>& directions, double lift, float* out);

// A light of more than this many directions (a sky: patches cut into cells) lights an element's
// g x g points interleaved: point k takes every (g^2)-th direction from the k-th, weighted g^2
// times. Lights marked `interleave` are one such sky together: their directions are numbered
// one after the other through the list, and point k takes every (g^2)-th of that numbering. The element's mean then sees each direction once from stratified points (a sky costs
// an element as many rays as it has directions, not g^2 times that); the points' spread, which
// decides splits, carries the interleaving's noise as well as the light's variation. Suns and
// luminaires are seen whole from every point (their shadow edges need it).
constexpr size_t kSkyDirections = 64;

// Directions normalised; a zero or non-finite one is an std::invalid_argument.
std::vector<Vec3> unit_directions(const std::vector<Vec3>& directions);

// A distant light (validated): `directions` towards the light (normalised here), weights summing
// to 1, E_perp per unit colour.
Luminaire distant_light(std::string name, std::vector<Vec3> directions, std::vector<double> weights,
                        double illuminance, RGB colour, std::vector<RGB> tints = {});

uint64_t luminaires_fingerprint(const std::vector<Luminaire>& luminaires);

}  // namespace hirad
