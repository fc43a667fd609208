// Final gather: radiance at surface points re-evaluated from a solved hierarchy.
//
// A link R <- S gives every point of R the same irradiance G / A_R * B_S, so the solution is
// piecewise constant over receivers that may be large where little light arrives. Gathering
// re-evaluates each link that reaches a point x (the links of x's leaf and of all its
// ancestors) at x itself: H(x) = sum over those links of F(x -> S) V(x, S) B_S, with the exact
// point-to-polygon form factor for element sources and stratified faces for cluster sources,
// and the radiosity of the source's leaves at the sampled points.
// Only the sources' radiosity is taken from the solution, and the error in it is reflected
// once more, so the gathered value is far closer to the true radiance than the element's
// (Lischinski, Tampieri and Greenberg 1993 gather the same way for display).
#pragma once
#include <cstdint>
#include <vector>

#include "pipeline/hierarchy/hierarchy.h"
#include "pipeline/hierarchy/refine.h"
#include "pipeline/geometry/visibility.h"

namespace hirad {

struct GatherOptions {
    int rays = 4;              // visibility rays per partly visible element source
    int cluster_samples = 8;   // faces drawn per cluster source (each with its own ray)
    uint64_t seed = 1;
};

class Gatherer {
public:
    // `links` sorted by receiver (sort_links); `radiosity` per node; `visibility` over
    // hierarchy.faces. All are referenced, not copied.
    Gatherer(const Hierarchy& hierarchy, const std::vector<Link>& links, const std::vector<RGB>& radiosity,
             const Visibility& visibility, const GatherOptions& options);

    // Irradiance (W/m^2) at points x[k] of leaf elements leaf[k], on their surface side, in
    // parallel. `key[k]` seeds the point's samples (the result depends on it, not on threads).
    void irradiance(const uint32_t* leaf, const Vec3* x, const uint64_t* key, size_t count, RGB* out) const;

    // Exitant radiance (W/(m^2 sr)): (E + rho H(x)) / pi of the leaf's material.
    void radiance(const uint32_t* leaf, const Vec3* x, const uint64_t* key, size_t count, RGB* out) const;

private:
    RGB at(uint32_t leaf, const Vec3& x, uint64_t key) const;
    RGB element_transfer(const Link& link, const Vec3& x, const Vec3& n, Rng& rng) const;
    RGB cluster_transfer(const Link& link, const Vec3& x, const Vec3& n, Rng& rng) const;  // B-weighted

    const Hierarchy& h_;
    const std::vector<Link>& links_;
    const std::vector<RGB>& radiosity_;
    const Visibility& vis_;
    GatherOptions opt_;
    std::vector<uint64_t> first_link_;  // per node: its links are [first_link_[i], first_link_[i + 1])
};

// The same gather from a flat solution: every patch j is a source, F(x -> j) exact, its
// visibility by `rays` stratified rays (patches whose form factor from x is zero skipped).
// O(patches) per point: the flat method's own cost, for comparing the two methods at points.
void gather_flat(const std::vector<Patch>& patches, const std::vector<RGB>& radiosity, const Visibility& visibility,
                 const Vec3* x, const Vec3* n, size_t count, int rays, uint64_t seed, RGB* irradiance);

}  // namespace hirad
