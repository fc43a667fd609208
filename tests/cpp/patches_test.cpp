// mesh_patches: patches tile their face within the size limits and weld along shared edges.
#include "pipeline/geometry/patches.h"
#include "pipeline/geometry/visibility.h"

#include <gtest/gtest.h>

#include <cmath>
#include <vector>

namespace hirad {
namespace {

Face make_face(const std::vector<Vec3>& corners, uint32_t mesh = 0, const std::vector<Vec2>& uvs = {}) {
    Face f;
    f.nv = static_cast<int>(corners.size());
    for (int k = 0; k < f.nv; ++k) {
        f.p[k] = corners[k];
        if (k < static_cast<int>(uvs.size())) f.uv[k] = uvs[k];
    }
    f.mesh = mesh;
    f.reflectance = {0.5, 0.5, 0.5};
    return f;
}

Scene scene_of(const std::vector<Face>& faces) {
    Scene s;
    s.faces = faces;
    return s;
}

double max_edge_of(const Patch& p) {
    double m = 0;
    for (int k = 0; k < p.nv; ++k) m = std::max(m, length(p.p[(k + 1) % p.nv] - p.p[k]));
    return m;
}

// Faces of different shapes and orientations, each with the limits it is meshed at.
struct Case {
    const char* name;
    Face face;
    MeshingOptions options;
};

std::vector<Case> cases() {
    std::vector<Case> c;
    c.push_back({"unit square", make_face({{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0}}), {0.01, 0.1}});
    c.push_back({"long thin rectangle", make_face({{0, 0, 0}, {0, 0, 3}, {0, 0.2, 3}, {0, 0.2, 0}}), {0.01, 0.1}});
    // Area-limited: the edge limit alone would give 2 x 1 patches of area 1.
    c.push_back({"area-limited rectangle", make_face({{0, 0, 0}, {2, 0, 0}, {2, 1, 0}, {0, 1, 0}}), {0.05, 1.0}});
    // A trapezoid in a tilted plane (z = x + y): sub-quads are not parallelograms.
    c.push_back({"tilted trapezoid",
                 make_face({{0, 0, 0}, {1.3, 0, 1.3}, {1.0, 0.7, 1.7}, {0.2, 0.7, 0.9}}), {0.004, 0.07}});
    c.push_back({"triangle", make_face({{0, 0, 0}, {1, 0, 0}, {0.3, 0.8, 0}}), {0.01, 0.1}});
    c.push_back({"obtuse tilted triangle", make_face({{0, 0, 1}, {2, 1, 0}, {-0.5, 0.4, 0.2}}), {0.002, 0.3}});
    c.push_back({"area-limited triangle", make_face({{0, 0, 0}, {1, 0, 0}, {0, 1, 0}}), {0.001, 10.0}});
    return c;
}

TEST(MeshPatches, PatchesTileTheFaceWithinTheLimits) {
    for (const Case& c : cases()) {
        SCOPED_TRACE(c.name);
        PatchSet set = mesh_patches(scene_of({c.face}), c.options);
        ASSERT_GT(set.patches.size(), 1u);
        const double face_area = c.face.area();
        const Vec3 n = c.face.normal();
        double total = 0;
        for (const Patch& p : set.patches) {
            EXPECT_EQ(p.nv, c.face.nv);
            EXPECT_EQ(p.face, 0u);
            // The stored area is the patch's own polygon area.
            Vec3 newell;
            for (int k = 0; k < p.nv; ++k) newell += cross(p.p[k], p.p[(k + 1) % p.nv]);
            EXPECT_NEAR(p.area, 0.5 * length(newell), 1e-15 * face_area);
            total += p.area;
            EXPECT_LE(p.area, c.options.max_area * (1 + 1e-12));
            EXPECT_LE(max_edge_of(p), c.options.max_edge_length * (1 + 1e-12));
            EXPECT_NEAR(dot(p.normal, n), 1.0, 1e-12);
            EXPECT_NEAR(length(p.normal), 1.0, 1e-12);
            // The centroid lies in the face's plane.
            EXPECT_NEAR(dot(p.centroid - c.face.p[0], n), 0.0, 1e-12);
        }
        EXPECT_NEAR(total, face_area, 1e-12 * face_area);
    }
}

// A trapezoid's grid cells are not all the same size: the ones along the long parallel side
// are the largest, and they too must respect max_area.
TEST(MeshPatches, AreaLimitHoldsForEveryPatchOfATrapezoid) {
    // Parallel sides 2 (bottom) and 1 (top), height 1: area 1.5. The edge limit is slack, so
    // the area limit alone decides the grid.
    Face f = make_face({{0, 0, 0}, {2, 0, 0}, {1.5, 1, 0}, {0.5, 1, 0}});
    const MeshingOptions opt{0.05, 10.0};
    PatchSet set = mesh_patches(scene_of({f}), opt);
    double largest = 0, total = 0;
    for (const Patch& p : set.patches) {
        largest = std::max(largest, p.area);
        total += p.area;
    }
    EXPECT_NEAR(total, 1.5, 1.5e-12);
    EXPECT_LE(largest, opt.max_area * (1 + 1e-12)) << set.patches.size() << " patches";
}

TEST(MeshPatches, AttributesComeFromTheFace) {
    Face f = make_face({{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0}}, 3);
    f.reflectance = {0.1, 0.2, 0.3};
    f.emission = {7, 8, 9};
    Face g = make_face({{0, 0, 1}, {1, 0, 1}, {0, 1, 1}}, 5);
    PatchSet set = mesh_patches(scene_of({f, g}), {0.3, 0.5});
    size_t from_f = 0, from_g = 0;
    for (const Patch& p : set.patches) {
        if (p.face == 0) {
            ++from_f;
            EXPECT_EQ(p.mesh, 3u);
            EXPECT_EQ(p.reflectance.y, 0.2);
            EXPECT_EQ(p.emission.z, 9);
        } else {
            ++from_g;
            EXPECT_EQ(p.face, 1u);
            EXPECT_EQ(p.mesh, 5u);
        }
    }
    EXPECT_EQ(from_f, 4u);  // ceil(1 / 0.5) = 2 per side, area 0.25 <= 0.3
    EXPECT_EQ(from_g, 9u);  // k = ceil(sqrt(2) / 0.5) = 3, k^2 triangles of area 0.5 / 9
}

TEST(MeshPatches, StripOfTwoUnitQuadsWeldsItsSharedEdge) {
    // Each unit quad at edge 0.25 is a 4 x 4 grid (5 x 5 vertices); the strip is a 8 x 4
    // grid of patches with 9 x 5 = 45 distinct vertices.
    Face a = make_face({{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0}});
    Face b = make_face({{1, 0, 0}, {2, 0, 0}, {2, 1, 0}, {1, 1, 0}});
    PatchSet set = mesh_patches(scene_of({a, b}), {0.1, 0.25});
    EXPECT_EQ(set.patches.size(), 32u);
    EXPECT_EQ(set.vertices.size(), 45u);
    // Every patch corner refers to the vertex at its position.
    for (const Patch& p : set.patches)
        for (int k = 0; k < 4; ++k) {
            const Vec3& v = set.vertices[p.vertex[k]];
            EXPECT_EQ(v.x, p.p[k].x);
            EXPECT_EQ(v.y, p.p[k].y);
            EXPECT_EQ(v.z, p.p[k].z);
        }
}

TEST(MeshPatches, DifferentMeshesDoNotWeld) {
    Face a = make_face({{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0}}, 0);
    Face b = make_face({{1, 0, 0}, {2, 0, 0}, {2, 1, 0}, {1, 1, 0}}, 1);
    PatchSet set = mesh_patches(scene_of({a, b}), {0.1, 0.25});
    EXPECT_EQ(set.vertices.size(), 50u);  // 25 + 25: a vertex belongs to one mesh
    ASSERT_EQ(set.vertex_mesh.size(), set.vertices.size());
    size_t in_mesh1 = 0;
    for (uint32_t m : set.vertex_mesh) in_mesh1 += m == 1;
    EXPECT_EQ(in_mesh1, 25u);
    for (const Patch& p : set.patches)
        for (int k = 0; k < 4; ++k) EXPECT_EQ(set.vertex_mesh[p.vertex[k]], p.mesh);
}

// Neighbouring faces of a consistently oriented mesh run along their shared edge in
// opposite directions, and real coordinates are not dyadic. Points on the shared edge must
// still come out bit-identical from both faces, or the mesh cracks open.
TEST(MeshPatches, WeldingHoldsForOppositeEdgeDirectionsAndNonDyadicSizes) {
    // Two quads split 3 x 3 (edge 0.1 / 0.3 steps of 1/3), the second starting at the far
    // corner so it runs along the shared edge x = 0.4 downwards while the first runs upwards.
    const double x0 = 0.1, x1 = 0.4, x2 = 0.7, y0 = 0.2, y1 = 0.5;
    Face a = make_face({{x0, y0, 0.3}, {x1, y0, 0.3}, {x1, y1, 0.3}, {x0, y1, 0.3}});
    Face b = make_face({{x2, y1, 0.3}, {x1, y1, 0.3}, {x1, y0, 0.3}, {x2, y0, 0.3}});
    ASSERT_GT(dot(a.normal(), b.normal()), 0.999);  // both face +z
    PatchSet set = mesh_patches(scene_of({a, b}), {1.0, 0.1 + 1e-9});
    ASSERT_EQ(set.patches.size(), 18u);
    // 3 x 3 patches per face, 4 x 4 vertices each, 4 shared: 28.
    EXPECT_EQ(set.vertices.size(), 28u);

    // Two triangles sharing the diagonal of a 0.3 square, both facing +z (so they run along
    // the diagonal in opposite directions), split k = ceil(0.3 sqrt(2) / 0.15) = 3.
    const double s = 0.3;
    Face t1 = make_face({{0, 0, 0}, {s, 0, 0}, {0, s, 0}});
    Face t2 = make_face({{s, s, 0}, {0, s, 0}, {s, 0, 0}});
    ASSERT_GT(t2.normal().z, 0.999);
    PatchSet tris = mesh_patches(scene_of({t1, t2}), {1.0, 0.15});
    ASSERT_EQ(tris.patches.size(), 18u);
    // A 3 x 3 grid of squares cut on the diagonals: 4 x 4 = 16 vertices.
    EXPECT_EQ(tris.vertices.size(), 16u);
}

TEST(MeshPatches, PatchCornersSitOnTheFaceCornersExactly) {
    // The outer corners of the grid are the face's own corners, bit for bit, whatever the
    // order of the corners' coordinates.
    std::vector<Vec3> q = {{0.7, 0.1, 0.3}, {0.1, 0.7, 0.3}, {-0.3, 0.3, 0.3}, {0.3, -0.3, 0.3}};
    Face f = make_face(q);
    PatchSet set = mesh_patches(scene_of({f}), {1.0, 0.2});
    for (const Vec3& corner : q) {
        bool found = false;
        for (const Vec3& v : set.vertices) found |= v.x == corner.x && v.y == corner.y && v.z == corner.z;
        EXPECT_TRUE(found) << corner.x << " " << corner.y << " " << corner.z;
    }
}

// Point-in-convex-polygon test in the patch's plane.
bool inside(const Patch& p, const Vec3& x, double eps) {
    if (std::fabs(dot(x - p.p[0], p.normal)) > eps) return false;
    for (int k = 0; k < p.nv; ++k)
        if (dot(cross(p.p[(k + 1) % p.nv] - p.p[k], x - p.p[k]), p.normal) < -eps) return false;
    return true;
}

TEST(MeshPatches, PointOnPatchStaysInside) {
    Rng rng(12345);
    for (const Case& c : cases()) {
        SCOPED_TRACE(c.name);
        PatchSet set = mesh_patches(scene_of({c.face}), c.options);
        for (const Patch& p : set.patches) {
            for (int k = 0; k < 16; ++k) {
                double s = rng.uniform(), t = rng.uniform();
                EXPECT_TRUE(inside(p, p.point(s, t), 1e-12));
            }
            // The corners of the unit square map onto the patch's corners (triangles fold
            // (1, 1) back onto corner 0).
            const Vec3 at00 = p.point(0, 0), at10 = p.point(1, 0), at01 = p.point(0, 1);
            EXPECT_NEAR(length(at00 - p.p[0]), 0, 1e-15);
            EXPECT_NEAR(length(at10 - p.p[1]), 0, 1e-15);
            if (p.nv == 4) {
                EXPECT_NEAR(length(p.point(1, 1) - p.p[2]), 0, 1e-15);
                EXPECT_NEAR(length(at01 - p.p[3]), 0, 1e-15);
            } else {
                EXPECT_NEAR(length(at01 - p.p[2]), 0, 1e-15);
            }
        }
    }
}

TEST(MeshPatches, PointOnTriangleIsUniformOverTheArea) {
    // The mean of point(s, t) over the unit square is the triangle's centroid when the
    // folding maps area uniformly. point() is affine on each half of every grid cell cut by
    // its anti-diagonal (the fold s + t = 1 runs along those diagonals), so averaging it at
    // the two half-cells' centroids, (1/3, 1/3) and (2/3, 2/3) of the cell, is exact.
    Face f = make_face({{0, 0, 0}, {1, 0, 0}, {0.2, 0.9, 0}});
    PatchSet set = mesh_patches(scene_of({f}), {1.0, 10.0});
    ASSERT_EQ(set.patches.size(), 1u);
    const Patch& p = set.patches[0];
    Vec3 mean;
    const int g = 16;
    for (int j = 0; j < g; ++j)
        for (int i = 0; i < g; ++i) {
            mean += p.point((i + 1.0 / 3) / g, (j + 1.0 / 3) / g);
            mean += p.point((i + 2.0 / 3) / g, (j + 2.0 / 3) / g);
        }
    mean = mean / double(2 * g * g);
    Vec3 centroid = (f.p[0] + f.p[1] + f.p[2]) / 3.0;
    EXPECT_NEAR(length(mean - centroid), 0, 1e-12);
    EXPECT_NEAR(length(p.centroid - centroid), 0, 1e-15);
}

TEST(MeshPatches, UVsAreInterpolatedToPatchCorners) {
    // uv is an affine function of position on the face, so each patch corner's uv must be
    // that function at the corner's position.
    auto uv_of = [](const Vec3& p) { return Vec2{0.125 + 0.25 * p.x + 0.05 * p.y, 0.9 - 0.3 * p.y}; };
    std::vector<Vec3> quad = {{0, 0, 0}, {2, 0, 0}, {2.5, 1.5, 0}, {0.5, 1.5, 0}};  // parallelogram
    std::vector<Vec3> tri = {{0, 0, 1}, {1.2, 0.1, 1}, {0.4, 1.1, 1}};
    std::vector<Vec2> quv, tuv;
    for (const Vec3& p : quad) quv.push_back(uv_of(p));
    for (const Vec3& p : tri) tuv.push_back(uv_of(p));
    PatchSet set = mesh_patches(scene_of({make_face(quad, 0, quv), make_face(tri, 1, tuv)}), {0.05, 0.3});
    ASSERT_GT(set.patches.size(), 8u);
    for (const Patch& p : set.patches)
        for (int k = 0; k < 4; ++k) {
            Vec2 want = uv_of(p.p[k]);
            EXPECT_NEAR(p.uv[k].u, want.u, 1e-12);
            EXPECT_NEAR(p.uv[k].v, want.v, 1e-12);
        }
}

TEST(InterpolateCorners, BilinearOnQuadsBarycentricOnTriangles) {
    std::array<RGB, 4> c = {RGB{1, 0, 0}, RGB{0, 2, 0}, RGB{0, 0, 4}, RGB{8, 8, 8}};
    RGB q = interpolate_corners(4, c, 0.25, 0.5);
    // (1-u)(1-v) = 0.375, u(1-v) = 0.125, uv = 0.125, (1-u)v = 0.375.
    EXPECT_DOUBLE_EQ(q.x, 0.375 * 1 + 0.375 * 8);
    EXPECT_DOUBLE_EQ(q.y, 0.125 * 2 + 0.375 * 8);
    EXPECT_DOUBLE_EQ(q.z, 0.125 * 4 + 0.375 * 8);
    RGB t = interpolate_corners(3, c, 0.25, 0.5);  // weights 0.25, 0.25, 0.5; corner 3 unused
    EXPECT_DOUBLE_EQ(t.x, 0.25);
    EXPECT_DOUBLE_EQ(t.y, 0.5);
    EXPECT_DOUBLE_EQ(t.z, 2.0);
}

// Patch::coordinates inverts Patch::point, on trapezoids (not parallelograms) and triangles.
TEST(PatchCoordinates, InvertPointOnEveryShape) {
    for (const Case& c : cases()) {
        const PatchSet set = mesh_patches(scene_of({c.face}), c.options);
        for (const Patch& p : set.patches)
            for (double s = 0.05; s < 1; s += 0.15)
                for (double t = 0.05; t < 1; t += 0.15) {
                    if (p.nv == 3 && s + t > 1) continue;
                    const Vec3 x = p.point(s, t);
                    const Vec2 st = p.coordinates(x);
                    EXPECT_NEAR(st.u, s, 1e-9) << c.name;
                    EXPECT_NEAR(st.v, t, 1e-9) << c.name;
                }
    }
}

// The closest point's coordinates are the patch's own: point(u, v) is the point queried.
// (The two triangles' barycentric coordinates differ from them by several percent of the
// patch on a trapezoid.)
TEST(PatchCoordinates, ClosestPointGivesThePatchsOwnCoordinates) {
    Patch trap;
    trap.nv = 4;
    trap.p = {Vec3{0, 0, 0}, Vec3{1, 0, 0}, Vec3{0.7, 0.4, 0}, Vec3{0.1, 0.4, 0}};
    trap.normal = {0, 0, 1};
    const std::vector<Patch> patches{trap};  // the scene keeps a reference to its patches
    const Visibility vis(patches);
    for (double s = 0.1; s < 1; s += 0.2)
        for (double t = 0.1; t < 1; t += 0.2) {
            const Vec3 x = trap.point(s, t);
            const RayHit hit = vis.closest_point(x + Vec3{0, 0, 0.01}, {0, 0, 1}, 1.0);
            ASSERT_EQ(hit.patch, 0);
            EXPECT_LT(length(trap.point(hit.u, hit.v) - x), 1e-6) << s << " " << t;
        }
}

}  // namespace
}  // namespace hirad

namespace hirad {
namespace {

// The one patch-finishing routine: area and normal by Newell, centroid either way, against
// the closed forms of a trapezoid (parallel sides a at y = 0 and b at y = h: area
// (a + b) h / 2, centroid height h (a + 2b) / (3 (a + b))).
TEST(FinishPatch, TrapezoidAreaNormalAndBothCentroids) {
    Patch p;
    p.nv = 4;
    p.p = {Vec3{0, 0, 1}, Vec3{2, 0, 1}, Vec3{1.5, 1, 1}, Vec3{0.5, 1, 1}};  // a = 2, b = 1, h = 1
    finish_patch(p, PatchCentroid::AreaWeighted);
    EXPECT_NEAR(p.area, 1.5, 1e-15);
    EXPECT_NEAR(p.normal.z, 1.0, 1e-15);
    EXPECT_NEAR(p.centroid.x, 1.0, 1e-15);
    EXPECT_NEAR(p.centroid.y, 4.0 / 9.0, 1e-15);
    EXPECT_NEAR(p.centroid.z, 1.0, 1e-15);
    finish_patch(p, PatchCentroid::CornerMean);
    EXPECT_NEAR(p.area, 1.5, 1e-15);
    EXPECT_NEAR(p.centroid.y, 0.5, 1e-15);  // the corners' mean, not the area's
}

TEST(FinishPatch, TriangleRepeatsItsLastCornerAndFacesItsWinding) {
    Patch t;
    t.nv = 3;
    t.p = {Vec3{0, 0, 0}, Vec3{0, 3, 0}, Vec3{3, 0, 0}, Vec3{9, 9, 9}};  // clockwise seen from +z
    t.uv = {Vec2{0, 0}, Vec2{0, 1}, Vec2{1, 0}, Vec2{5, 5}};
    finish_patch(t, PatchCentroid::AreaWeighted);
    EXPECT_NEAR(t.area, 4.5, 1e-15);
    EXPECT_NEAR(t.normal.z, -1.0, 1e-15);
    EXPECT_NEAR(t.centroid.x, 1.0, 1e-15);
    EXPECT_NEAR(t.centroid.y, 1.0, 1e-15);
    EXPECT_EQ(t.p[3].x, 3.0);
    EXPECT_EQ(t.uv[3].u, 1.0);
    // A triangle's centroid is its corners' mean: both rules agree.
    Patch m = t;
    finish_patch(m, PatchCentroid::CornerMean);
    EXPECT_NEAR(m.centroid.x, t.centroid.x, 1e-15);
    EXPECT_NEAR(m.centroid.y, t.centroid.y, 1e-15);
}

}  // namespace
}  // namespace hirad

namespace hirad {
namespace {

// What meshing will build is estimated before it builds, and refused with the numbers when
// it exceeds max_patches: a 1e30 coordinate used to overflow ceil(len / max_edge) into an
// int and loop for ever; a tiny max_area allocated until bad_alloc.
TEST(MeshPatches, AbsurdSizesAreRefusedBeforeAnythingIsBuilt) {
    const Scene huge = scene_of({make_face({{0, 0, 0}, {1e30, 0, 0}, {1e30, 1, 0}, {0, 1, 0}})});
    try {
        mesh_patches(huge, {0.01, 0.1});
        ADD_FAILURE() << "no error";
    } catch (const std::length_error& e) {
        const std::string msg = e.what();
        EXPECT_NE(msg.find("meshing would make at least 1e+32 patches, more than the limit of 50000000"),
                  std::string::npos) << msg;
        EXPECT_NE(msg.find("metersPerUnit"), std::string::npos) << msg;
    }
    const Scene huge_triangle = scene_of({make_face({{0, 0, 0}, {1e30, 0, 0}, {0, 1e30, 0}})});
    EXPECT_THROW(mesh_patches(huge_triangle, {0.01, 0.1}), std::length_error);
    // max_patch_area 1e-9 on one square metre: 1e9 patches.
    const Scene unit = scene_of({make_face({{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0}})});
    EXPECT_THROW(mesh_patches(unit, {1e-9, 0.1}), std::length_error);
    // The limit is exact: the unit square at 0.0101 m^2 / 0.1 m is a 10 x 10 grid.
    MeshingOptions at_limit{0.0101, 0.1, 100};
    EXPECT_EQ(mesh_patches(unit, at_limit).patches.size(), 100u);
    at_limit.max_patches = 99;
    EXPECT_THROW(mesh_patches(unit, at_limit), std::length_error);
    // Many faces add up: 3 squares of 100 patches under a limit of 250.
    const Scene three = scene_of({unit.faces[0], unit.faces[0], unit.faces[0]});
    EXPECT_THROW(mesh_patches(three, {0.0101, 0.1, 250}), std::length_error);
    EXPECT_EQ(mesh_patches(three, {0.0101, 0.1, 300}).patches.size(), 300u);
}

TEST(MeshPatches, LimitsThatAreNotPositiveNumbersAreRefused) {
    const Scene unit = scene_of({make_face({{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0}})});
    for (const MeshingOptions& bad : {MeshingOptions{0, 0.1}, MeshingOptions{0.01, -1}, MeshingOptions{std::nan(""), 0.1},
                                      MeshingOptions{0.01, INFINITY}})
        EXPECT_THROW(mesh_patches(unit, bad), std::invalid_argument);
}

// The estimate is a lower bound of what is built, and exact for the regular grids.
TEST(MeshPatches, EstimateIsALowerBoundAndExactForGrids) {
    for (const Case& c : cases()) {
        SCOPED_TRACE(c.name);
        const double estimate = estimate_face_patches(c.face, c.options);
        const size_t built = mesh_patches(scene_of({c.face}), c.options).patches.size();
        EXPECT_LE(estimate, double(built));
    }
    const Face square = make_face({{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0}});
    EXPECT_EQ(estimate_face_patches(square, {0.0101, 0.1}), 100.0);  // 10 x 10 cells of 0.01 m^2
    EXPECT_EQ(estimate_face_patches(square, {0.001, 0.1}), 1000.0);  // the area decides
    const Face triangle = make_face({{0, 0, 0}, {1, 0, 0}, {0, 1, 0}});
    EXPECT_EQ(estimate_face_patches(triangle, {1.0, 0.3}), 25.0);  // longest edge sqrt 2: k = 5
}

}  // namespace
}  // namespace hirad
