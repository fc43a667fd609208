// Form factors between patches.
//
// F_ij is the fraction of the power leaving patch i that arrives at patch j. hirad estimates
// it as (1/A_i) * integral over i of F(dA_x -> A_j) * V(x, j), where F(dA_x -> A_j) is
// Lambert's contour integral (exact for the unoccluded polygon) evaluated at stratified
// points x on i, and V is the fraction of rays from x to points on j that arrive.
#pragma once
#include <cstdint>
#include <utility>
#include <vector>

#include "pipeline/geometry/patches.h"
#include "pipeline/geometry/visibility.h"

namespace hirad {

// Differential-area-to-polygon form factor by Lambert's contour formula:
//   F = 1/(2 pi) * sum_k  angle(e_k, e_{k+1}) * n . normalize(e_k x e_{k+1})
// with e_k = v_k - x. The polygon is first clipped to the half-space in front of (x, n);
// zero when x is behind the polygon's own plane (surfaces emit from their front only).
double point_polygon_form_factor(const Vec3& x, const Vec3& n, const Vec3* poly, int nv,
                                 const Vec3& poly_normal);

// The same by Gauss quadrature of the kernel cos theta_x cos theta_y / (pi r^2) over the
// polygon, for a polygon far from x compared with its size: 2 x 2 Gauss-Legendre points on a
// quad's bilinear map (times its Jacobian), the 3-point rule of degree 2 (Strang and Fix) on a
// triangle. Where the polygon's diagonal is at most kQuadratureFar times its box's distance from
// x, it agrees with the contour sum within about 1e-3 relative (tests/cpp/formfactors_test.cpp:
// mean error of order 1e-6 over random orientations), with no atan2 and no clipping. When a
// corner is not in front of x's tangent plane, or x is not in front of the polygon, the contour
// sum is returned (the quadrature does not clip).
constexpr double kQuadratureFar = 0.25;
double point_polygon_form_factor_by_quadrature(const Vec3& x, const Vec3& n, const Vec3* poly, int nv,
                                               const Vec3& poly_normal, double area);

// A point y of the polygon for estimating its visible form factor from (x, n): the direction
// from x is drawn over the polygon's solid angle with density proportional to cos theta_x
// (directions uniform over each spherical triangle of the clipped polygon by Arvo's method,
// "Stratified sampling of spherical triangles", SIGGRAPH 1995, then kept with probability
// cos theta_x), so that F(x -> polygon) times the mean of V(x, y) is an unbiased estimate of
// the visible form factor. Points drawn uniformly by area only give that where the kernel
// cos cos / r^2 is nearly constant over the polygon: from a point 3 m under a 200 m square,
// the 4 x 4 m part overhead is 36 % of the form factor and 0.04 % of the area. Draws from `rng` (the same draws
// whatever happens elsewhere). Returns false when x is behind the polygon or sees it edge on (no
// direction was kept in `tries`): the caller then draws by area.
bool sample_polygon_by_form_factor(const Vec3& x, const Vec3& n, const Vec3* poly, int nv, const Vec3& poly_normal,
                                   Rng& rng, Vec3& y, int tries = 32);
// Both at once, on one clip of the polygon: F(x -> polygon) (as point_polygon_form_factor), and
// when it is positive a point y drawn as sample_polygon_by_form_factor draws it (`drawn` false
// when none was kept). The same draws from `rng` as calling the two one after the other.
double point_polygon_form_factor_and_point(const Vec3& x, const Vec3& n, const Vec3* poly, int nv,
                                           const Vec3& poly_normal, Rng& rng, Vec3& y, bool& drawn);

// Closed forms (Howell's catalogue, C-11 and C-14), used as test oracles.
// Two parallel a x b rectangles directly opposite at distance c.
double parallel_rectangles_form_factor(double a, double b, double c);
// From the w x l rectangle to the h x l rectangle, perpendicular, sharing the edge of
// length l (Howell C-14 with H = h/l, W = w/l).
double perpendicular_rectangles_form_factor(double l, double h, double w);

struct RayCastOptions {
    int samples = 16;      // stratified points on the receiving patch
    uint64_t seed = 1;
};

class RayCastFormFactors {
public:
    RayCastFormFactors(const std::vector<Patch>& patches, const Visibility& visibility,
                       const RayCastOptions& options);

    // F_ij estimated from samples on i alone (an independent estimate in each direction).
    double form_factor(uint32_t i, uint32_t j) const;

    // The symmetric coupling G_ij = A_i F_ij = A_j F_ji, estimated once per unordered pair
    // by sampling the smaller patch, so reciprocity holds exactly in the stored system.
    double coupling(uint32_t i, uint32_t j) const;

    // Couplings of i with every other patch that can exchange light with it (front-facing
    // pairs only), appended as (j, G_ij). Rays are batched across all j.
    void couplings_of(uint32_t i, std::vector<std::pair<uint32_t, float>>& out) const;

    // Couplings for j > i only: the upper triangle the link matrix is assembled from.
    void upper_couplings_of(uint32_t i, std::vector<std::pair<uint32_t, float>>& out) const;

private:
    // Can light leave the front of `from` and arrive at the front of `to`?
    bool facing(uint32_t from, uint32_t to) const;
    void batch_couplings(uint32_t i, const std::vector<uint32_t>& partners,
                         std::vector<std::pair<uint32_t, float>>& out) const;
    void couplings_block(uint32_t i, const std::vector<uint32_t>& partners,
                         std::vector<std::pair<uint32_t, float>>& out) const;

    const std::vector<Patch>& patches_;
    const Visibility& visibility_;
    RayCastOptions options_;
};

}  // namespace hirad
