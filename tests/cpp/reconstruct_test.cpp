// Reconstruction of per-point values from per-patch values: the display mesh (welded corners
// split at creases, boundary marked) and the interior-mean / boundary-extrapolation rule.
#include "pipeline/outputs/reconstruct.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <map>
#include <vector>

namespace hirad {
namespace {

Face quad_face(const std::vector<Vec3>& c) {
    Face f;
    f.nv = 4;
    for (int k = 0; k < 4; ++k) f.p[k] = c[k];
    return f;
}

// A flat 3 x 3 grid of square patches of side h starting at (x0, y0) in the plane z = 0.25,
// either as one face split 3 x 3 or as nine faces of one mesh welded together.
constexpr double x0 = 0.5, y0 = 0.5, h = 0.4;

PatchSet grid(bool nine_faces) {
    Scene scene;
    if (nine_faces) {
        for (int j = 0; j < 3; ++j)
            for (int i = 0; i < 3; ++i) {
                const double xa = x0 + i * h, xb = x0 + (i + 1) * h, ya = y0 + j * h, yb = y0 + (j + 1) * h;
                scene.faces.push_back(quad_face({{xa, ya, 0.25}, {xb, ya, 0.25}, {xb, yb, 0.25}, {xa, yb, 0.25}}));
            }
        return mesh_patches(scene, {1.0, 1.0});
    }
    const double x3 = x0 + 3 * h, y3 = y0 + 3 * h;
    scene.faces.push_back(quad_face({{x0, y0, 0.25}, {x3, y0, 0.25}, {x3, y3, 0.25}, {x0, y3, 0.25}}));
    return mesh_patches(scene, {1.0, h * (1 + 1e-9)});
}

bool on_rim(const Vec3& p) {
    auto near = [](double a, double b) { return std::fabs(a - b) < 1e-9; };
    return near(p.x, x0) || near(p.x, x0 + 3 * h) || near(p.y, y0) || near(p.y, y0 + 3 * h);
}

TEST(DisplayMesh, FlatGridHasSixteenPointsTwelveOnTheBoundary) {
    for (bool nine : {false, true}) {
        SCOPED_TRACE(nine ? "nine faces" : "one face");
        PatchSet set = grid(nine);
        ASSERT_EQ(set.patches.size(), 9u);
        DisplayMesh mesh = build_display_mesh(set, 30.0);
        ASSERT_EQ(mesh.points.size(), 16u);
        ASSERT_EQ(mesh.boundary.size(), 16u);
        ASSERT_EQ(mesh.point_mesh.size(), 16u);
        int boundary = 0;
        for (size_t v = 0; v < mesh.points.size(); ++v) {
            boundary += mesh.boundary[v];
            EXPECT_EQ(mesh.boundary[v] != 0, on_rim(mesh.points[v])) << "point " << v;
        }
        EXPECT_EQ(boundary, 12);
        // Every patch corner refers to the point at its position.
        for (size_t i = 0; i < set.patches.size(); ++i)
            for (int k = 0; k < 4; ++k) EXPECT_LT(length(mesh.points[mesh.corners[i][k]] - set.patches[i].p[k]), 1e-15);
    }
}

// A linear field sampled at patch centroids. Interior points take the mean of their four
// patches, whose centroids sit symmetrically around them: the field's value there. A
// boundary point b is extrapolated through its nearest interior neighbour i (along a patch
// edge, or the diagonal at the grid's corners) as 2 mean_b - mean_i. Its patches' centroids
// average to the midpoint of b and i -- (x_b, y_b + h/2) for a point on the bottom edge with
// i straight above, (x_b + h/2, y_b + h/2) for a corner with i diagonally inside -- and
// mean_i = f(i), so for a linear f the rule gives 2 f((b + i)/2) - f(i) = f(b) exactly.
TEST(VertexValues, LinearFieldIsReproducedAtEveryPoint) {
    auto f = [](const Vec3& p) { return RGB{p.x, p.y, 1 + 2 * p.x + 3 * p.y}; };
    for (bool nine : {false, true}) {
        SCOPED_TRACE(nine ? "nine faces" : "one face");
        PatchSet set = grid(nine);
        DisplayMesh mesh = build_display_mesh(set, 30.0);
        std::vector<RGB> values;
        for (const Patch& p : set.patches) values.push_back(f(p.centroid));
        std::vector<RGB> out = vertex_values(set, mesh, values);
        ASSERT_EQ(out.size(), mesh.points.size());
        for (size_t v = 0; v < out.size(); ++v) {
            const RGB want = f(mesh.points[v]);
            for (int c = 0; c < 3; ++c) EXPECT_NEAR(out[v][c], want[c], 1e-12) << "point " << v << " channel " << c;
        }
    }
}

TEST(VertexValues, BoundaryExtrapolationIsClampedAtZero) {
    // f = x - 0.6 is positive at every centroid (x >= 0.7) but extrapolates to -0.1 on the
    // left edge x = 0.5, where the clamp gives 0; elsewhere the values stay exact.
    PatchSet set = grid(false);
    DisplayMesh mesh = build_display_mesh(set, 30.0);
    std::vector<RGB> values;
    for (const Patch& p : set.patches) values.push_back(RGB{p.centroid.x - 0.6, 1, 1});
    std::vector<RGB> out = vertex_values(set, mesh, values);
    int left = 0;
    for (size_t v = 0; v < out.size(); ++v) {
        const double x = mesh.points[v].x;
        if (std::fabs(x - x0) < 1e-9) {
            ++left;
            EXPECT_EQ(out[v].x, 0.0);
        } else {
            EXPECT_NEAR(out[v].x, x - 0.6, 1e-12);
        }
        EXPECT_NEAR(out[v].y, 1.0, 1e-15);
    }
    EXPECT_EQ(left, 4);
}

// The unit cube, six faces of one mesh facing outward, each 2 x 2 patches. Welded, it has
// 8 corners + 12 edge midpoints + 6 face centres = 26 vertices.
PatchSet cube() {
    const std::vector<std::vector<Vec3>> quads = {
        {{0, 0, 0}, {0, 1, 0}, {1, 1, 0}, {1, 0, 0}}, {{0, 0, 1}, {1, 0, 1}, {1, 1, 1}, {0, 1, 1}},
        {{0, 0, 0}, {0, 0, 1}, {0, 1, 1}, {0, 1, 0}}, {{1, 0, 0}, {1, 1, 0}, {1, 1, 1}, {1, 0, 1}},
        {{0, 0, 0}, {1, 0, 0}, {1, 0, 1}, {0, 0, 1}}, {{0, 1, 0}, {0, 1, 1}, {1, 1, 1}, {1, 1, 0}},
    };
    Scene scene;
    for (const auto& q : quads) scene.faces.push_back(quad_face(q));
    return mesh_patches(scene, {1.0, 0.5});
}

TEST(DisplayMesh, CubeIsSplitAtItsEdges) {
    PatchSet set = cube();
    ASSERT_EQ(set.patches.size(), 24u);
    ASSERT_EQ(set.vertices.size(), 26u);
    for (const Patch& p : set.patches) ASSERT_GT(dot(p.normal, p.centroid - Vec3{0.5, 0.5, 0.5}), 0.49);  // outward

    // At 30 degrees every 90-degree edge is a crease: each face becomes its own 3 x 3 sheet
    // of points, 6 x 9 = 54, of which the 8 rim points of each sheet are boundary.
    DisplayMesh split = build_display_mesh(set, 30.0);
    EXPECT_EQ(split.points.size(), 54u);
    int boundary = 0;
    for (uint8_t b : split.boundary) boundary += b;
    EXPECT_EQ(boundary, 48);
    // Count the points at each position: corners 3, edge midpoints 2, face centres 1.
    std::map<std::array<double, 3>, int> at;
    for (const Vec3& p : split.points) ++at[{p.x, p.y, p.z}];
    EXPECT_EQ(at.size(), 26u);
    for (const auto& [pos, count] : at) {
        int on_planes = 0;  // how many of the cube's face planes the position lies in
        for (double c : pos) on_planes += (c == 0 || c == 1);
        EXPECT_EQ(count, on_planes) << pos[0] << " " << pos[1] << " " << pos[2];
    }
    // Each patch's corners are points of its own face only.
    std::vector<int> face_of(split.points.size(), -1);
    for (size_t i = 0; i < set.patches.size(); ++i)
        for (int k = 0; k < 4; ++k) {
            int& f = face_of[split.corners[i][k]];
            if (f < 0) f = static_cast<int>(set.patches[i].face);
            EXPECT_EQ(f, static_cast<int>(set.patches[i].face));
        }

    // Above 90 degrees nothing is split: the closed cube has 26 points and no boundary.
    DisplayMesh whole = build_display_mesh(set, 100.0);
    EXPECT_EQ(whole.points.size(), 26u);
    for (uint8_t b : whole.boundary) EXPECT_EQ(b, 0);
}

TEST(VertexValues, CreasesKeepFacesFromBlurringIntoEachOther) {
    // A different constant on every face. Split at the creases, every point of a face gets
    // that face's value: interior (the face centre) as the mean of four equal patches, rim
    // points as 2 c - c.
    PatchSet set = cube();
    DisplayMesh mesh = build_display_mesh(set, 30.0);
    auto face_value = [](uint32_t face) { return RGB{1.0 + face, 10.0 - face, 0.5 * face}; };
    std::vector<RGB> values;
    for (const Patch& p : set.patches) values.push_back(face_value(p.face));
    std::vector<RGB> out = vertex_values(set, mesh, values);
    for (size_t i = 0; i < set.patches.size(); ++i)
        for (int k = 0; k < 4; ++k) {
            const RGB got = out[mesh.corners[i][k]], want = face_value(set.patches[i].face);
            for (int c = 0; c < 3; ++c) EXPECT_NEAR(got[c], want[c], 1e-12);
        }
    // Not split, a cube corner averages its three faces.
    DisplayMesh whole = build_display_mesh(set, 100.0);
    std::vector<RGB> blurred = vertex_values(set, whole, values);
    for (size_t v = 0; v < whole.points.size(); ++v) {
        const Vec3& p = whole.points[v];
        if (p.x != 0 || p.y != 0 || p.z != 0) continue;
        // Faces through the origin: 0 (z = 0), 2 (x = 0), 4 (y = 0).
        EXPECT_NEAR(blurred[v].x, (1.0 + 3.0 + 5.0) / 3, 1e-12);
    }
}

// The leaves of a solved hierarchy are held as a FaceTable welded by mesh (Engine::
// use_leaves_as_patches): its display mesh and vertex values must be those of the PatchSet
// weld_patches makes of the same patches, to the bit. The case has what the welding decides:
// T-vertices (one quad of four split again), two meshes meeting along an edge (their points
// stay apart), a triangle, and a corner at -0.0 where its neighbour has +0.0 (one vertex).
TEST(DisplayMesh, LeavesHeldCompactlyGiveTheSameMeshAndValuesToTheBit) {
    auto quad = [](Vec3 a, Vec3 b, Vec3 c, Vec3 d, uint32_t mesh) {
        Patch p;
        p.nv = 4;
        p.p = {a, b, c, d};
        p.mesh = mesh;
        p.face = mesh;
        finish_patch(p, PatchCentroid::CornerMean);
        return p;
    };
    std::vector<Patch> patches;
    for (int j = 0; j < 2; ++j)
        for (int i = 0; i < 2; ++i) {
            const double x = 0.5 * i, y = 0.5 * j;
            Patch p = quad({x, y, 0}, {x + 0.5, y, 0}, {x + 0.5, y + 0.5, 0}, {x, y + 0.5, 0}, 0);
            if (i == 0 && j == 0) {
                Patch kids[4];
                split_in_four(p, kids);
                for (Patch& k : kids) {
                    finish_patch(k, PatchCentroid::CornerMean);
                    patches.push_back(k);
                }
            } else {
                patches.push_back(p);
            }
        }
    // Another mesh along the edge x = 1, and a wall of the first mesh with a corner at -0.0.
    patches.push_back(quad({1, 0, 0}, {1.5, 0, 0}, {1.5, 1, 0}, {1, 1, 0}, 1));
    patches.push_back(quad({-0.0, 0, 0}, {0, 0, 1}, {0, 0.5, 1}, {0, 0.5, 0}, 0));
    Patch tri;
    tri.nv = 3;
    tri.p = {Vec3{0, 1, 0}, Vec3{0.5, 1, 0}, Vec3{0.25, 1.5, 0}, Vec3{}};
    finish_patch(tri, PatchCentroid::CornerMean);
    patches.push_back(tri);

    FaceTable table(PatchCentroid::CornerMean, Welding::ByMesh);
    for (const Patch& p : patches) table.push_back(p);
    table.seal();
    const PatchSet set = weld_patches(patches);
    ASSERT_EQ(table.points(), set.vertices.size());
    for (double crease : {30.0, 100.0}) {
        SCOPED_TRACE(crease);
        const DisplayMesh a = build_display_mesh(set, crease), b = build_display_mesh(table, crease);
        ASSERT_EQ(a.points.size(), b.points.size());
        for (size_t v = 0; v < a.points.size(); ++v) {
            EXPECT_EQ(std::memcmp(&a.points[v], &b.points[v], sizeof(Vec3)), 0) << "point " << v;
            EXPECT_EQ(a.point_mesh[v], b.point_mesh[v]);
            EXPECT_EQ(a.boundary[v], b.boundary[v]);
            EXPECT_EQ(a.anchors[v], b.anchors[v]);
        }
        EXPECT_EQ(a.corners, b.corners);
        EXPECT_EQ(a.faces, b.faces);
        EXPECT_EQ(a.face_nv, b.face_nv);
        EXPECT_EQ(a.face_patch, b.face_patch);
        EXPECT_EQ(a.face_code, b.face_code);
        // T-vertices were found (fans) and the two meshes kept apart at x = 1.
        EXPECT_GT(a.faces.size(), patches.size());
        int at_one = 0;
        for (const Vec3& p : a.points) at_one += p.x == 1 && p.y == 0 && p.z == 0;
        EXPECT_EQ(at_one, 2);
        std::vector<RGB> values;
        for (size_t i = 0; i < patches.size(); ++i) values.push_back({0.1 * i, std::sin(double(i)), 1.0 / (i + 1)});
        const std::vector<RGB> va = vertex_values(set, a, values), vb = vertex_values(table, b, values);
        ASSERT_EQ(va.size(), vb.size());
        EXPECT_EQ(std::memcmp(va.data(), vb.data(), va.size() * sizeof(RGB)), 0);
    }
    // A table welded by bits is refused: its points may join meshes.
    FaceTable by_bits;
    for (const Patch& p : patches) by_bits.push_back(p);
    EXPECT_THROW(build_display_mesh(by_bits, 30.0), std::invalid_argument);
}

}  // namespace
}  // namespace hirad
