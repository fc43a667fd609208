// Form factors: the closed forms, Lambert's contour integral from a point, and the ray-cast
// estimator built on them.
#include "pipeline/geometry/formfactors.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <vector>

#include "tests/cpp/test_scenes.h"
namespace hirad {
namespace {

// Howell's catalogue (C-11: parallel directly opposite rectangles a x b at distance c;
// C-14: perpendicular rectangles sharing the edge w, from l x w to h x w). The values were
// also checked against a 60 x 60 Gauss-Legendre integration of the contour formula.
TEST(ClosedForms, ParallelRectanglesMatchHowell) {
    EXPECT_NEAR(parallel_rectangles_form_factor(1, 1, 1), 0.199825, 1e-5);
    EXPECT_NEAR(parallel_rectangles_form_factor(1, 1, 0.5), 0.415253, 1e-5);
    EXPECT_NEAR(parallel_rectangles_form_factor(2, 1, 1), 0.285875, 1e-5);
    EXPECT_NEAR(parallel_rectangles_form_factor(1, 1, 2), 0.06859, 1e-5);
    // The geometry is symmetric in a and b.
    EXPECT_NEAR(parallel_rectangles_form_factor(1, 2, 1), parallel_rectangles_form_factor(2, 1, 1), 1e-14);
}

// Arguments (l, h, w) as in Howell C-14: l is the length of the common edge, w the width of
// the source and h the height of the receiver (H = h/l, W = w/l).
TEST(ClosedForms, PerpendicularRectanglesMatchHowell) {
    EXPECT_NEAR(perpendicular_rectangles_form_factor(1, 1, 1), 0.200044, 1e-5);
    EXPECT_NEAR(perpendicular_rectangles_form_factor(1, 2, 1), 0.232853, 1e-5);  // receiver 2 tall
    EXPECT_NEAR(perpendicular_rectangles_form_factor(2, 1, 1), 0.240636, 1e-5);  // common edge 2 long
    // Reciprocity: (w l) F(l, h, w) = (h l) F(l, w, h). From the 2 x 1 wall back down to the
    // unit floor: 0.232853 / 2.
    EXPECT_NEAR(perpendicular_rectangles_form_factor(1, 1, 2), 0.232853 / 2, 1e-5);
    EXPECT_NEAR(2 * perpendicular_rectangles_form_factor(1, 1, 2), perpendicular_rectangles_form_factor(1, 2, 1),
                1e-12);
    EXPECT_NEAR(0.7 * perpendicular_rectangles_form_factor(1.3, 1.9, 0.7),
                1.9 * perpendicular_rectangles_form_factor(1.3, 0.7, 1.9), 1e-12);
    // A very long common edge tends to the 2D value by Hottel's crossed strings: (2 - sqrt 2) / 2.
    EXPECT_NEAR(perpendicular_rectangles_form_factor(1e4, 1, 1), (2 - std::sqrt(2.0)) / 2, 1e-3);
}

// Differential area at the origin facing +z, rectangle [0,a] x [0,b] at height c facing down:
// F = 1/(2 pi) [A/sqrt(1+A^2) atan(B/sqrt(1+A^2)) + B/sqrt(1+B^2) atan(A/sqrt(1+B^2))],
// A = a/c, B = b/c.
double corner_closed_form(double a, double b, double c) {
    const double A = a / c, B = b / c;
    const double sa = std::sqrt(1 + A * A), sb = std::sqrt(1 + B * B);
    return (A / sa * std::atan(B / sa) + B / sb * std::atan(A / sb)) / (2 * kPi);
}

std::array<Vec3, 4> rectangle_facing_down(double x0, double x1, double y0, double y1, double z) {
    return {Vec3{x0, y0, z}, Vec3{x0, y1, z}, Vec3{x1, y1, z}, Vec3{x1, y0, z}};
}

TEST(PointPolygon, PointBelowRectangleCornerMatchesClosedForm) {
    const Vec3 up{0, 0, 1}, down{0, 0, -1};
    const double dims[][3] = {{1, 1, 1}, {2, 0.5, 1}, {0.3, 4, 0.7}, {10, 10, 0.1}, {0.01, 0.02, 1}};
    for (const auto& d : dims) {
        auto r = rectangle_facing_down(0, d[0], 0, d[1], d[2]);
        EXPECT_NEAR(point_polygon_form_factor({0, 0, 0}, up, r.data(), 4, down), corner_closed_form(d[0], d[1], d[2]),
                    1e-9)
            << d[0] << " x " << d[1] << " at " << d[2];
    }
    // Below the centre: four corner rectangles of a/2 x b/2.
    auto r = rectangle_facing_down(-1, 1, -0.5, 0.5, 0.8);
    EXPECT_NEAR(point_polygon_form_factor({0, 0, 0}, up, r.data(), 4, down), 4 * corner_closed_form(1, 0.5, 0.8),
                1e-9);
    // The answer does not depend on the polygon's winding (only on its emitting side).
    std::array<Vec3, 4> reversed = {r[3], r[2], r[1], r[0]};
    EXPECT_NEAR(point_polygon_form_factor({0, 0, 0}, up, reversed.data(), 4, down),
                4 * corner_closed_form(1, 0.5, 0.8), 1e-9);
}

TEST(PointPolygon, TriangleIsHalfTheSquareBySymmetry) {
    // The square [-1,1]^2 at height 1 splits along its diagonal into two triangles that the
    // point below its centre sees identically.
    const Vec3 up{0, 0, 1}, down{0, 0, -1};
    Vec3 tri[3] = {{-1, -1, 1}, {1, 1, 1}, {1, -1, 1}};
    EXPECT_NEAR(point_polygon_form_factor({0, 0, 0}, up, tri, 3, down), 2 * corner_closed_form(1, 1, 1), 1e-9);
}

// The quadrature form (formfactors.h) against Lambert's contour sum: quads of random shape and
// orientation (planar, convex: a rectangle sheared and its far corner moved in its plane) and
// triangles, each seen from a random point and normal with the polygon wholly in front, its
// diagonal kQuadratureFar of its box's distance from the point (the nearest the gather uses it).
// Gauss's rules integrate polynomials of degree 3 (quads) and 2 (triangles) exactly; the
// kernel's next terms in diagonal / distance leave a relative error of order (kQuadratureFar /
// 2)^4 = 2.4e-4 times its derivatives: at most 2e-3 at any of the points, and on average well
// under 1e-4 (the error's sign varies with the orientation).
TEST(PointPolygon, QuadratureAgreesWithTheContourSumForFarPolygons) {
    Rng rng(2024);
    auto unit = [&] {
        for (;;) {
            const Vec3 v{2 * rng.uniform() - 1, 2 * rng.uniform() - 1, 2 * rng.uniform() - 1};
            const double l = length(v);
            if (l > 0.1 && l < 1) return v / l;
        }
    };
    double sum = 0, worst = 0;
    int used = 0;
    for (int trial = 0; trial < 20000 && used < 4000; ++trial) {
        const int nv = trial % 2 ? 3 : 4;
        const Vec3 u = unit();
        const Vec3 v = normalize(cross(u, unit()));
        const double a = 0.2 + rng.uniform(), b = 0.2 + rng.uniform();
        Vec3 p[4] = {Vec3{}, u * a, u * a + v * b + u * (0.3 * (rng.uniform() - 0.5)), v * b};
        if (nv == 3) p[2] = v * b + u * (a * rng.uniform());
        const Vec3 normal = normalize(cross(p[1] - p[0], p[2] - p[0]));
        Vec3 lo = p[0], hi = p[0];
        for (int k = 1; k < nv; ++k)
            for (int c = 0; c < 3; ++c) {
                lo[c] = std::min(lo[c], p[k][c]);
                hi[c] = std::max(hi[c], p[k][c]);
            }
        const Vec3 centre = (lo + hi) * 0.5;
        Vec3 dir = unit();
        if (dot(dir, normal) < 0) dir = dir * -1.0;
        // the box's distance from x is at least the distance from the centre less the half diagonal
        const double diagonal = length(hi - lo);
        const Vec3 x = centre + dir * (diagonal / kQuadratureFar + diagonal / 2);
        Vec3 n = unit();
        if (dot(n, centre - x) < 0) n = n * -1.0;
        bool front = dot(x - p[0], normal) > 0;
        for (int k = 0; k < nv; ++k) front = front && dot(p[k] - x, n) > 0;
        if (!front) continue;
        double area = length(cross(p[1] - p[0], p[2] - p[0])) / 2;
        if (nv == 4) area += length(cross(p[2] - p[0], p[3] - p[0])) / 2;
        const double exact = point_polygon_form_factor(x, n, p, nv, normal);
        if (!(exact > 1e-12)) continue;
        const double e = point_polygon_form_factor_by_quadrature(x, n, p, nv, normal, area) / exact - 1;
        sum += e;
        worst = std::max(worst, std::abs(e));
        ++used;
    }
    ASSERT_GT(used, 2000);
    EXPECT_LT(worst, 2e-3);
    EXPECT_LT(std::abs(sum / used), 1e-4);
    // Not in front: the contour sum itself (clipped).
    const Vec3 sq[4] = {{0, 0, 1}, {0, 1, 1}, {1, 1, 1}, {1, 0, 1}};
    const Vec3 down{0, 0, -1}, x{0.5, 0.5, 0}, tilted = normalize(Vec3{1, 0, 0.2});
    EXPECT_EQ(point_polygon_form_factor_by_quadrature(x, tilted, sq, 4, down, 1.0),
              point_polygon_form_factor(x, tilted, sq, 4, down));
}

TEST(PointPolygon, ZeroBehindTheEmittingSide) {
    const double c = 0.6;
    auto r = rectangle_facing_down(0, 1, 0, 2, c);
    // Above the rectangle, looking down at its back: nothing.
    const Vec3 above{0, 0, 2 * c};
    EXPECT_EQ(point_polygon_form_factor(above, {0, 0, -1}, r.data(), 4, {0, 0, -1}), 0.0);
    // The same position with the rectangle's front turned up sees the corner closed form
    // (distance c again).
    EXPECT_NEAR(point_polygon_form_factor(above, {0, 0, -1}, r.data(), 4, {0, 0, 1}), corner_closed_form(1, 2, c),
                1e-9);
    // In the polygon's own plane: zero as well.
    EXPECT_EQ(point_polygon_form_factor({5, 5, c}, {0, 0, -1}, r.data(), 4, {0, 0, -1}), 0.0);
}

TEST(PointPolygon, PolygonBehindTheReceiverSeesNothing) {
    // The rectangle faces the point, but lies entirely below the point's tangent plane.
    Vec3 wall[4] = {{0, 1, -2}, {1, 1, -2}, {1, 1, -1}, {0, 1, -1}};  // plane y = 1, facing -y
    EXPECT_EQ(point_polygon_form_factor({0, 0, 0}, {0, 0, 1}, wall, 4, {0, -1, 0}), 0.0);
}

TEST(PointPolygon, ClippedToTheTangentPlane) {
    // A wall in the plane y = d facing -y, x in [0, a], z in [-h, h], straddling the tangent
    // plane z = 0 of a point at the origin facing +z. Only its upper half is visible, for which
    // the contour integral gives
    //   F = 1/(2 pi) [atan(a/d) - d/sqrt(d^2+h^2) atan(a/sqrt(d^2+h^2))].
    const double a = 1, d = 1, h = 1;
    const Vec3 x{0, 0, 0}, n{0, 0, 1}, wn{0, -1, 0};
    Vec3 full[4] = {{0, d, -h}, {a, d, -h}, {a, d, h}, {0, d, h}};
    Vec3 upper[4] = {{0, d, 0}, {a, d, 0}, {a, d, h}, {0, d, h}};
    const double want =
        (std::atan(a / d) - d / std::sqrt(d * d + h * h) * std::atan(a / std::sqrt(d * d + h * h))) / (2 * kPi);
    const double f_full = point_polygon_form_factor(x, n, full, 4, wn);
    const double f_upper = point_polygon_form_factor(x, n, upper, 4, wn);
    EXPECT_NEAR(f_upper, want, 1e-12);
    EXPECT_NEAR(f_full, f_upper, 1e-12);
    // Straddling along a diagonal: a triangle cut by the plane, against its part above.
    Vec3 tri[3] = {{0, d, -1}, {2, d, 1}, {0, d, 1}};  // facing -y: (2,0,2)x(0,0,2) = (0,-4,0)
    Vec3 tri_upper[4] = {{0, d, 0}, {1, d, 0}, {2, d, 1}, {0, d, 1}};
    EXPECT_NEAR(point_polygon_form_factor(x, n, tri, 3, wn), point_polygon_form_factor(x, n, tri_upper, 4, wn), 1e-12);
    EXPECT_GT(point_polygon_form_factor(x, n, tri, 3, wn), 0.01);
}

// --- Points drawn by the kernel -----------------------------------------------------------

// Points y drawn by sample_polygon_by_form_factor fall in a part R of the polygon with
// probability F(x -> R) / F(x -> polygon): the share of the form factor, not of the area.
// Cases: a 200 m square 3 m above the point with R its 4 x 4 m part overhead (0.04 % of the
// area, 36 % of the form factor), a triangle, a wall the tangent plane cuts, and a small
// square far off (where the two shares agree).
TEST(KernelSampling, PointsFallInEachPartByItsShareOfTheFormFactor) {
    const Vec3 x{0, 0, 0}, up{0, 0, 1};
    struct Case {
        std::vector<Vec3> poly, part;
        Vec3 normal;
    };
    const Case cases[] = {
        {{{-100, -100, 3}, {-100, 100, 3}, {100, 100, 3}, {100, -100, 3}},
         {{-2, -2, 3}, {-2, 2, 3}, {2, 2, 3}, {2, -2, 3}}, {0, 0, -1}},
        {{{-1, -1, 1}, {3, 0, 1}, {0, 2, 1}}, {{-1, -1, 1}, {1, -0.5, 1}, {0, 0.5, 1}}, {0, 0, -1}},
        {{{-1, 1, -1}, {2, 1, -1}, {2, 1, 2}, {-1, 1, 2}}, {{0, 1, 0}, {2, 1, 0}, {2, 1, 2}, {0, 1, 2}}, {0, -1, 0}},
        {{{10, 10, 20}, {10, 10.5, 20}, {10.5, 10.5, 20}, {10.5, 10, 20}},
         {{10, 10, 20}, {10, 10.5, 20}, {10.25, 10.5, 20}, {10.25, 10, 20}}, {0, 0, -1}},
    };
    for (const Case& c : cases) {
        // Orient each polygon as its normal says (corners counter-clockwise seen from the front).
        auto facing = [&](std::vector<Vec3> p) {
            Vec3 n;
            for (size_t k = 0; k < p.size(); ++k) n += cross(p[k], p[(k + 1) % p.size()]);
            if (dot(n, c.normal) < 0) std::reverse(p.begin(), p.end());
            return p;
        };
        const std::vector<Vec3> poly = facing(c.poly), part = facing(c.part);
        const double f = point_polygon_form_factor(x, up, poly.data(), int(poly.size()), c.normal);
        const double f_part = point_polygon_form_factor(x, up, part.data(), int(part.size()), c.normal);
        ASSERT_GT(f, 0);
        const double share = f_part / f;
        // Whether y is in the part: inside its (convex) outline, in the polygon's plane.
        auto inside = [&](const Vec3& y) {
            for (size_t k = 0; k < part.size(); ++k) {
                const Vec3 e = part[(k + 1) % part.size()] - part[k];
                if (dot(cross(e, y - part[k]), c.normal) < -1e-9) return false;
            }
            return true;
        };
        Rng rng(7);
        const int n = 200000;
        int hits = 0, drawn = 0;
        for (int i = 0; i < n; ++i) {
            Vec3 y;
            if (!sample_polygon_by_form_factor(x, up, poly.data(), int(poly.size()), c.normal, rng, y)) continue;
            ++drawn;
            EXPECT_NEAR(dot(y - poly[0], c.normal), 0, 1e-6 * length(y - x));
            hits += inside(y);
        }
        EXPECT_EQ(drawn, n);  // every polygon here is seen from x: a direction is always kept
        const double p = double(hits) / drawn, sigma = std::sqrt(share * (1 - share) / drawn);
        EXPECT_NEAR(p, share, 4 * sigma + 1e-4) << "share " << share;
    }
    // The first case is the one area-drawn points get wrong: a 0.04 % area share, 36 % of F.
    EXPECT_GT(point_polygon_form_factor(x, up, std::vector<Vec3>{{-2, -2, 3}, {-2, 2, 3}, {2, 2, 3}, {2, -2, 3}}.data(), 4,
                                        {0, 0, -1}) /
                  point_polygon_form_factor(x, up, std::vector<Vec3>{{-100, -100, 3}, {-100, 100, 3}, {100, 100, 3}, {100, -100, 3}}.data(),
                                            4, {0, 0, -1}),
              0.3);
}

TEST(KernelSampling, NothingIsDrawnBehindThePolygonOrBelowTheTangentPlane) {
    Rng rng(3);
    Vec3 y;
    const Vec3 square[4] = {{-1, -1, 1}, {-1, 1, 1}, {1, 1, 1}, {1, -1, 1}};  // facing down
    EXPECT_FALSE(sample_polygon_by_form_factor({0, 0, 2}, {0, 0, -1}, square, 4, {0, 0, -1}, rng, y));  // behind it
    const Vec3 below[4] = {{-1, -1, -1}, {1, -1, -1}, {1, 1, -1}, {-1, 1, -1}};  // facing up at x, under its tangent plane
    EXPECT_FALSE(sample_polygon_by_form_factor({0, 0, 0}, {0, 0, 1}, below, 4, {0, 0, 1}, rng, y));
}

// --- The ray-cast estimator -------------------------------------------------------------

Patch make_patch(std::vector<Vec3> corners) {
    Patch patch;
    patch.nv = static_cast<int>(corners.size());
    for (int k = 0; k < patch.nv; ++k) patch.p[k] = corners[k];
    if (patch.nv == 3) patch.p[3] = patch.p[2];
    Vec3 n;
    for (int k = 0; k < patch.nv; ++k) n += cross(patch.p[k], patch.p[(k + 1) % patch.nv]);
    patch.area = 0.5 * length(n);
    patch.normal = normalize(n);
    Vec3 c;
    for (int k = 0; k < patch.nv; ++k) c += patch.p[k];
    patch.centroid = c / patch.nv;  // exact for the parallelograms used here
    return patch;
}

Patch floor_square(double z = 0) { return make_patch({{0, 0, z}, {1, 0, z}, {1, 1, z}, {0, 1, z}}); }
Patch ceiling_square(double z) { return make_patch({{0, 0, z}, {0, 1, z}, {1, 1, z}, {1, 0, z}}); }

TEST(RayCast, ParallelUnitSquares) {
    const double c_values[] = {1.0, 0.5};
    for (double c : c_values) {
        std::vector<Patch> patches = {floor_square(), ceiling_square(c)};
        Visibility vis(patches);
        RayCastFormFactors rc(patches, vis, {256, 1});
        const double want = parallel_rectangles_form_factor(1, 1, c);
        const double g01 = rc.coupling(0, 1);
        EXPECT_NEAR(g01, want * 1.0, 0.01 * want) << "c = " << c;  // A = 1
        EXPECT_EQ(g01, rc.coupling(1, 0));
        EXPECT_NEAR(rc.form_factor(0, 1), want, 0.01 * want);
        EXPECT_NEAR(rc.form_factor(1, 0), want, 0.01 * want);
    }
}

TEST(RayCast, PerpendicularSquaresSharingAnEdge) {
    std::vector<Patch> patches = {floor_square(), make_patch({{0, 0, 0}, {0, 1, 0}, {0, 1, 1}, {0, 0, 1}})};
    ASSERT_NEAR(patches[1].normal.x, 1.0, 1e-15);
    Visibility vis(patches);
    RayCastFormFactors rc(patches, vis, {256, 1});
    const double want = 0.200044;
    EXPECT_NEAR(rc.coupling(0, 1), want, 0.01 * want);
    EXPECT_EQ(rc.coupling(0, 1), rc.coupling(1, 0));
    EXPECT_NEAR(rc.form_factor(0, 1), want, 0.01 * want);
    EXPECT_NEAR(rc.form_factor(1, 0), want, 0.01 * want);
}

TEST(RayCast, ReciprocityIsExactForUnequalPatches) {
    // A 1 x 1 floor and a 1 x 2 wall (w = 1, h = 2): G = A_floor F = 0.232853.
    std::vector<Patch> patches = {floor_square(), make_patch({{0, 0, 0}, {0, 1, 0}, {0, 1, 2}, {0, 0, 2}})};
    Visibility vis(patches);
    RayCastFormFactors rc(patches, vis, {256, 7});
    const double g = rc.coupling(0, 1);
    EXPECT_EQ(g, rc.coupling(1, 0));
    EXPECT_NEAR(g, 0.232853, 0.01 * 0.232853);
    // The one-sided estimates agree with G / A in each direction. Sampled on the tall wall the
    // integrand varies steeply near the common edge (F -> 1/2 there): over 20 seeds the error
    // is up to 2 % at 256 samples but 0.13 % at 4096, so that estimate gets 4096.
    EXPECT_NEAR(rc.form_factor(0, 1), 0.232853, 0.01 * 0.232853);
    RayCastFormFactors fine(patches, vis, {4096, 7});
    EXPECT_NEAR(fine.form_factor(1, 0), 0.232853 / 2, 0.01 * 0.232853 / 2);
}

TEST(RayCast, BackToBackAndCoplanarPatchesDoNotCouple) {
    // Two squares facing away from each other, and two side by side in one plane.
    std::vector<Patch> patches = {floor_square(1), ceiling_square(0), floor_square(0)};
    patches[2] = make_patch({{1, 0, 0}, {2, 0, 0}, {2, 1, 0}, {1, 1, 0}});
    // 0: z = 1 facing up; 1: z = 0 facing down; 2: z = 0 facing up, beside patch 1's square.
    Visibility vis(patches);
    RayCastFormFactors rc(patches, vis, {64, 1});
    EXPECT_EQ(rc.coupling(0, 1), 0.0);
    EXPECT_EQ(rc.form_factor(0, 1), 0.0);
    EXPECT_EQ(rc.coupling(1, 2), 0.0);
    EXPECT_EQ(rc.form_factor(2, 1), 0.0);
    std::vector<std::pair<uint32_t, float>> row;
    rc.couplings_of(1, row);
    EXPECT_TRUE(row.empty());
}

TEST(RayCast, BlockerBetweenSquaresHidesThem) {
    // A 2 x 2 square at z = 0.5 covers every segment between the unit squares at z = 0 and
    // z = 1 (each crosses z = 0.5 inside [0,1]^2).
    std::vector<Patch> patches = {floor_square(), ceiling_square(1),
                                  make_patch({{-0.5, -0.5, 0.5}, {1.5, -0.5, 0.5}, {1.5, 1.5, 0.5}, {-0.5, 1.5, 0.5}})};
    Visibility vis(patches);
    RayCastFormFactors rc(patches, vis, {256, 1});
    EXPECT_EQ(rc.coupling(0, 1), 0.0);
    EXPECT_EQ(rc.form_factor(0, 1), 0.0);
    EXPECT_EQ(rc.form_factor(1, 0), 0.0);
    // The ceiling still sees the blocker, which contains the square directly below each of its
    // points: more than the unit square opposite at the same distance 0.5 would give.
    EXPECT_GT(rc.form_factor(1, 2), parallel_rectangles_form_factor(1, 1, 0.5));
}

TEST(RayCast, HalfBlockerHalvesTheExchangeBySymmetry) {
    // Two unit squares at z = 0 and z = 1; a blocker at z = 0.5 covering x < 0.5 over the
    // whole width. Every segment from (x, y, 0) to (x', y', 1) crosses z = 0.5 at
    // x = (x + x') / 2, so it is blocked exactly when x + x' < 1. The map x -> 1 - x on both
    // squares swaps blocked and unblocked pairs and leaves the kernel unchanged, so exactly
    // half of the exchange survives.
    std::vector<Patch> patches = {floor_square(), ceiling_square(1),
                                  make_patch({{-1, -1, 0.5}, {0.5, -1, 0.5}, {0.5, 2, 0.5}, {-1, 2, 0.5}})};
    Visibility vis(patches);
    RayCastFormFactors rc(patches, vis, {4096, 3});
    const double want = 0.5 * parallel_rectangles_form_factor(1, 1, 1);
    // (The estimator multiplies F(x -> square) by the fraction of target points visible from
    // x, here x itself; the same symmetry makes that exactly half as well.) Visibility is one
    // Bernoulli ray per sample, about 1.2 % standard error at 4096 samples: allow 5 %.
    EXPECT_NEAR(rc.coupling(0, 1), want, 0.05 * want);
}

TEST(RayCast, CubeRowSumsAreThePatchArea) {
    std::vector<Patch> patches = test::unit_cube_patches(2);
    ASSERT_EQ(patches.size(), 24u);
    for (const Patch& p : patches) {
        ASSERT_NEAR(p.area, 0.25, 1e-15);
        ASSERT_NEAR(dot(p.normal, Vec3{0.5, 0.5, 0.5} - p.centroid), 0.5, 1e-12);  // inward
    }
    Visibility vis(patches);
    RayCastFormFactors rc(patches, vis, {64, 1});
    for (uint32_t i = 0; i < patches.size(); ++i) {
        std::vector<std::pair<uint32_t, float>> row;
        rc.couplings_of(i, row);
        // Everything not on i's own face couples with it: 24 - 4 = 20 partners.
        EXPECT_EQ(row.size(), 20u);
        double sum = 0;
        for (const auto& [j, g] : row) {
            EXPECT_NE(j, i);
            EXPECT_NE(patches[j].face, patches[i].face);
            EXPECT_GT(g, 0);
            sum += g;
            // The row agrees with the pairwise coupling exactly (same pair-keyed samples).
            EXPECT_EQ(g, static_cast<float>(rc.coupling(i, j)));
        }
        EXPECT_NEAR(sum, patches[i].area, 0.01 * patches[i].area) << "row " << i;
    }
}

TEST(RayCast, UpperCouplingsAreTheUpperPartOfTheRow) {
    std::vector<Patch> patches = test::unit_cube_patches(2);
    Visibility vis(patches);
    RayCastFormFactors rc(patches, vis, {16, 5});
    for (uint32_t i = 0; i < patches.size(); ++i) {
        std::vector<std::pair<uint32_t, float>> row, upper;
        rc.couplings_of(i, row);
        rc.upper_couplings_of(i, upper);
        std::vector<std::pair<uint32_t, float>> want;
        for (const auto& e : row)
            if (e.first > i) want.push_back(e);
        EXPECT_EQ(upper, want) << "row " << i;
    }
}

TEST(RayCast, SameSeedSameNumbersOtherSeedOtherNumbers) {
    std::vector<Patch> patches = {floor_square(), ceiling_square(1)};
    Visibility vis(patches);
    RayCastFormFactors a(patches, vis, {16, 1}), b(patches, vis, {16, 1}), c(patches, vis, {16, 2});
    EXPECT_EQ(a.coupling(0, 1), b.coupling(0, 1));
    EXPECT_NE(a.coupling(0, 1), c.coupling(0, 1));
}

}  // namespace
}  // namespace hirad
