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
// V(x, y) is what a ray from x to y carries: 1, 0 when something opaque is in the way, and
// through clear glass the product of its panes' factors T(theta) (visibility.h).
//
// Directional moments (GatherOptions::directional, off by default; with importance 0 the
// irradiance does not depend on it, bit for bit: the moments evaluate every link). With it the gather also returns, per point, the zeroth and first
// moments of the radiance L(w) arriving over the point's hemisphere (w unit, towards the source):
//   l0 = integral L(w) dw            (W/m^2 per RGB channel)
//   l1 = integral L(w) w dw          (W/m^2 per channel and world axis)
// so that E = n . l1 (n the surface normal: cos theta = n . w). A contribution dE
// arriving from one direction d (a point luminaire) carries radiance times solid angle
// dE / cos theta: l0 += dE / cos, l1 += dE / cos * d (cos > 0 always there: the luminaire code
// drops arrivals at or below the horizon; the ratio is I V / r^2, finite at grazing).
// A surface source S is not one direction: its samples y are drawn by area, not by the
// kernel, and per-sample dE / cos theta_y weights would be wrong for a source that is large
// seen from x (1 / cos blows up at the horizon while the kernel there is small). Instead each
// source polygon, clipped to x's hemisphere like its form factor, contributes its exact solid
// angle moments, scaled by the same radiosity-and-visibility factor b that its irradiance
// carries (E_S = b F(x -> S), b = B_S for an unoccluded leaf, the mean of V(x, y) B(y) over
// the stratified points y otherwise; per drawn face for a cluster source):
//   Omega_S = integral over S of dw         (the fan of spherical triangles, Van Oosterom and
//                                            Strackee 1983)
//   W_S     = integral over S of w dw = 1/2 sum_edges gamma_k u_k
// (Arvo 1995, the first-moment irradiance tensor; u_k the unit normal of the plane through x
// and edge k, gamma_k the edge's angle seen from x, signs taken so that n . W_S >= 0), and
// n . W_S = pi F(x -> S) is Lambert's contour sum. With L_S = b / pi:
//   l0 += b Omega_S / pi,  l1 += b W_S / pi,  E += b F(x -> S) = b n . W_S / pi.
// For a small source this is dE / cos theta and dE / cos theta * d, the rule above; for a
// large one it is exact where the per-sample rule is biased.
// Points y of S below x's horizon are outside the clipped polygon that F and the moments
// count, and a ray to one passes under x's own surface: they are redrawn (uniformly over S,
// up to 8 times) until above, so b is the mean over the part F counts. (Averaging over all of
// S, as before stop 27, counted them as blocked and biased E low where S straddles the
// horizon: -5 to -11 % at the foot of the Cornell box's blocks, whose floor runs on under
// them.) What b does not see is the direction of a partial occlusion inside one source (a
// half-hidden element's l1 points to its unoccluded centre): refinement splits the links whose visibility varies and that carry enough
// light to matter, so such sources are small.
// L1 spherical harmonics of L (real, orthonormal: Y00 = 1 / (2 sqrt(pi)) = 0.282095,
// Y1m = sqrt(3 / (4 pi)) (y, z, x) = 0.488603 (y, z, x) for m = -1, 0, 1):
//   c00 = Y00 l0,  c1-1 = 0.488603 l1_y,  c10 = 0.488603 l1_z,  c11 = 0.488603 l1_x,
// and the irradiance they give a normal n (Ramamoorthi and Hanrahan 2001, A0 = pi,
// A1 = 2 pi / 3) is E1(n) = l0 / 4 + n . l1 / 2, within l0 / 4 of the true E(n) for light
// from the hemisphere above n (|max(c, 0) - 1/4 - c/2| <= 1/4 for c = n . w in [-1, 1]).
#pragma once
#include <tbb/concurrent_hash_map.h>

#include <array>
#include <cstdint>
#include <memory>
#include <vector>

#include "pipeline/hierarchy/hierarchy.h"
#include "pipeline/hierarchy/refine.h"
#include "pipeline/geometry/visibility.h"

namespace hirad {

struct GatherOptions {
    int rays = 4;              // visibility rays per partly visible element source (an emitting
                               // one always takes 16 and is traced whatever its estimate saw)
    int cluster_samples = 8;   // faces drawn per cluster source (each with its own ray)
    uint64_t seed = 1;
    bool directional = false;  // also the radiance moments l0, l1 (see above); E unchanged
    // Importance (0: every link of a point's chain is evaluated at the point). Else, per leaf,
    // the links of its chain are ranked by the irradiance each brings to the receiver on
    // average (B_S G / A_R); the weakest, together at most `importance` of the leaf's total,
    // are taken at that average instead of at the point, except those from emitters and those
    // whose source is close to the leaf (within the larger of the two's diagonals), where the
    // light varies most over the leaf. The average of a link over its receiver is what the
    // point values average to, so this adds no bias, only a bounded local error (at most the
    // weak links' share times their variation over the leaf). The directional moments always
    // evaluate every link.
    double importance = 0;
    // Close sources gathered once more (0: off). A leaf source S whose box is nearer to the
    // point x than `second_bounce` times its diagonal is not taken at its one radiosity B_S:
    // S is cut in four (as subdivision cuts elements), and again each cell still that close to
    // x compared with its own size (down to 1/32 of S's side), and each cell's radiosity is
    // gathered at its centre y, B(y) = E_S + rho_S H(y) = B_S + rho_S (H(y) - H_S),
    // H(y) from S's own chain of links at y (those taken at their leaves' radiosity: one bounce
    // more, not two) and H_S the leaf's mean irradiance from the same links at their mean
    // coupling (the links whose light does not vary across S, far sources, taken at S's
    // centre once for all its cells), so that
    //   E(x) from S = sum over cells c of F(x -> c) V_c B(y_c),
    // F exact per cell. The cells are gathered once per leaf (cached; every point near the same
    // contact shares them). Along a contact (a block's wall at the
    // floor) the kernel from a point millimetres away sits on the strip of S next to it, where
    // the radiosity falls towards the corner (the block's own shadow, the two surfaces hiding
    // each other's light) while a 1 cm element holds its mean: taking B_S read +99 % 3.4 mm
    // up the Cornell box's tall block. E_S (never used itself: B_S - rho_S H_S, so a light
    // group's gather needs no emission of its own) holds the luminaires' direct light as its
    // mean over the leaf; the light from emitting surfaces is gathered at y (cluster sources of
    // y's chain at their mean, element sources with one visibility ray). Costs one chain
    // gather per cell, once (cells are cached: every point near the same contact shares them),
    // and a few form factors per close source at each point.
    double second_bounce = 0;
};

// Whether two option sets gather the same values (every field above; extend it with them).
inline bool same_gather(const GatherOptions& a, const GatherOptions& b) {
    return a.rays == b.rays && a.cluster_samples == b.cluster_samples && a.seed == b.seed &&
           a.directional == b.directional && a.importance == b.importance && a.second_bounce == b.second_bounce;
}

// The moments of the radiance arriving at a surface point over its hemisphere (see above).
struct RadianceMoments {
    RGB l0;                  // integral L dw, W/m^2 per channel
    std::array<RGB, 3> l1;   // l1[a] = integral L w_a dw for world axis a, W/m^2 per channel
};

// What the gather reads of a link: 12 of its 24 bytes. Its receiver is its row in the table
// (node i's links are links[first[i], first[i + 1])); the unoccluded estimate and the error
// bound are refinement's. An out-of-core bake reads its store straight into this form
// (gather_links, outofcore.h): the 1M-triangle kitchen's 14 M links take 168 MB, not 336.
struct GatherLink {
    uint32_t source = 0;
    float coupling = 0;    // Link::coupling, m^2
    float visibility = 0;  // Link::visibility, [0, 1]
};
static_assert(sizeof(GatherLink) == 12, "GatherLink must be 12 bytes");

struct GatherLinks {
    std::vector<uint64_t> first;    // per node, and one past the last: where its links start
    std::vector<GatherLink> links;  // by receiver, then by source (sort_links' order)
    GatherLinks() = default;
    // From links sorted by receiver (sort_links) over a hierarchy of `nodes` nodes.
    GatherLinks(const std::vector<Link>& sorted, size_t nodes);
    size_t size() const { return links.size(); }
};

class Gatherer {
public:
    // `links` by receiver; `radiosity` per node; `visibility` over hierarchy.faces. All are
    // referenced, not copied.
    Gatherer(const Hierarchy& hierarchy, const GatherLinks& links, const std::vector<RGB>& radiosity,
             const Visibility& visibility, const GatherOptions& options);
    // The same from links sorted by receiver (sort_links), converted to a GatherLinks it owns.
    Gatherer(const Hierarchy& hierarchy, const std::vector<Link>& links, const std::vector<RGB>& radiosity,
             const Visibility& visibility, const GatherOptions& options);

    // Irradiance (W/m^2) at points x[k] of leaf elements leaf[k], on their surface side, in
    // parallel. `key[k]` seeds the point's samples (the result depends on it, not on threads).
    // `moments` non-null: also the radiance moments there (the irradiance is the same bits
    // with or without them).
    void irradiance(const uint32_t* leaf, const Vec3* x, const uint64_t* key, size_t count, RGB* out,
                    RadianceMoments* moments = nullptr) const;

    // Exitant radiance (W/(m^2 sr)): (E + rho H(x)) / pi of the leaf's material.
    void radiance(const uint32_t* leaf, const Vec3* x, const uint64_t* key, size_t count, RGB* out) const;

private:
    // The links of a leaf's chain evaluated at its points, and the rest's mean irradiance.
    struct Split {
        std::vector<uint64_t> links;
        RGB rest;
    };
    Split split(uint32_t leaf) const;
    void build_steps();
    static constexpr size_t kSplitBlock = 8192;         // leaves whose splits irradiance() holds at once
    static constexpr size_t kCellCacheMost = 1u << 20;  // cells kept between blocks (about 80 MB)
    // The mean irradiance at `leaf` per unit B_S of a link to `receiver` (leaf or an ancestor).
    double mean_coupling(const GatherLink& l, uint32_t receiver, uint32_t leaf) const;
    // Whether a link's light varies much across `leaf`: its source emits, or is closer to the
    // leaf than the larger of the two's diagonals.
    bool varies(const GatherLink& l, uint32_t leaf) const;
    uint32_t leaf_at(uint32_t node, double s, double t) const {
        return descend_to_leaf([this](uint32_t k) { return steps_[k]; }, node, s, t);
    }
    RGB at(uint32_t leaf, const Vec3& x, uint64_t key, RadianceMoments* mo, const Split* sp) const;
    // The irradiance at x on `leaf` from its whole chain.
    RGB chain(uint32_t leaf, const Vec3& x, const Vec3& n, Rng& rng, RadianceMoments* mo) const;
    RGB element_transfer(const GatherLink& link, const Vec3& x, const Vec3& n, Rng& rng, RadianceMoments* mo,
                         int depth = 0) const;
    // The second bounce (GatherOptions::second_bounce): a close leaf cut into cells where x is
    // close to them, each cell's radiosity gathered at its centre (cached by leaf and cell).
    static constexpr int kCellDepth = 3;  // cells down to 1/8 of the leaf's side
    static_assert(2 * kCellDepth + 3 <= 16, "a cell's path and depth fill 16 bits of its cache key");
    RGB cell_transfer(const GatherLink& link, uint32_t source, const Patch& cell, uint64_t code, int depth, const Vec3& x,
                      const Vec3& n, Rng& rng, RadianceMoments* mo) const;
    RGB cell_radiosity(uint32_t source, const Patch& cell, uint64_t code) const;
    // H(y) - H_S over the element links of leaf `source`'s chain that vary across it (near) or
    // not, at its point y (seeded by the leaf and `code`).
    RGB cell_difference(uint32_t source, const Vec3& y, bool near, uint64_t code) const;
    static constexpr uint64_t kLeafCode = 0xFFFF;  // the cache key of a leaf's far part, no cell's
    RGB cluster_transfer(const GatherLink& link, const Vec3& x, const Vec3& n, Rng& rng,
                         RadianceMoments* mo) const;  // B-weighted

    const Hierarchy& h_;
    std::unique_ptr<const GatherLinks> own_;  // when made from a vector of Link
    const GatherLinks& table_;
    const std::vector<GatherLink>& links_;
    const std::vector<uint64_t>& first_link_;  // per node: its links are [first_link_[i], first_link_[i + 1])
    const std::vector<RGB>& radiosity_;
    const Visibility& vis_;
    GatherOptions opt_;
    std::vector<DescentStep> steps_;    // per node, for leaf_at
    // Per close leaf its cells' radiosity, made by the first point that needs it.
    // The key is (leaf << 16 | cell code), so its low bits take a few hundred values; TBB's
    // default hash of an integer is the integer, and buckets are chosen by its low bits: every
    // cell of the scene would share those few buckets (56 % of the Modern Hall's lightmap time
    // went into walking their chains). The key is mixed first (splitmix64's finaliser).
    struct CellKeyHash {
        static size_t hash(uint64_t k) {
            k = (k ^ (k >> 30)) * 0xBF58476D1CE4E5B9ull;
            k = (k ^ (k >> 27)) * 0x94D049BB133111EBull;
            return size_t(k ^ (k >> 31));
        }
        static bool equal(uint64_t a, uint64_t b) { return a == b; }
    };
    using CellCache = tbb::concurrent_hash_map<uint64_t, RGB, CellKeyHash>;
    mutable CellCache cells_;
};

// The same gather from a flat solution: every patch j is a source, F(x -> j) exact, its
// visibility by `rays` stratified rays (patches whose form factor from x is zero skipped).
// O(patches) per point: the flat method's own cost, for comparing the two methods at points.
void gather_flat(const std::vector<Patch>& patches, const std::vector<RGB>& radiosity, const Visibility& visibility,
                 const Vec3* x, const Vec3* n, size_t count, int rays, uint64_t seed, RGB* irradiance);

// The exact solid angle moments of polygon `poly` (its emitting side facing x) clipped to the
// hemisphere above x's tangent plane (normal n): omega = integral dw (sr), w1 = integral w dw
// (sr, a vector with n . w1 = pi F(x -> poly)). Zero when x is behind it or nothing is above.
struct SolidAngleMoments {
    double omega = 0;
    Vec3 w1;
};
SolidAngleMoments polygon_solid_angle_moments(const Vec3& x, const Vec3& n, const Vec3* poly, int nv,
                                              const Vec3& poly_normal);

}  // namespace hirad
