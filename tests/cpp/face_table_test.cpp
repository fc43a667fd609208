// The hierarchy's compact faces (pipeline/geometry/face_table.h): every face's patch made from
// the table is the patch it was made from, to the bit, and the table holds a fraction of the
// patches' bytes.
#include "pipeline/geometry/face_table.h"

#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <cstring>
#include <set>
#include <vector>

#include "pipeline/geometry/visibility.h"
#include "pipeline/hierarchy/hierarchy.h"
#include "test_scenes.h"

namespace hirad {
namespace {

bool same(const Vec3& a, const Vec3& b) { return std::memcmp(&a, &b, sizeof(Vec3)) == 0; }
bool same(const Vec2& a, const Vec2& b) { return std::memcmp(&a, &b, sizeof(Vec2)) == 0; }
bool same(double a, double b) { return std::memcmp(&a, &b, sizeof(double)) == 0; }

// Every field a Patch carries for the hierarchy, bit for bit (Patch::vertex is PatchSet's, not
// the hierarchy's: zero in both).
void expect_same_patch(const Patch& want, const Patch& got, size_t f) {
    ASSERT_EQ(want.nv, got.nv) << "face " << f;
    for (int k = 0; k < 4; ++k) {
        EXPECT_TRUE(same(want.p[k], got.p[k])) << "face " << f << " corner " << k;
        EXPECT_TRUE(same(want.uv[k], got.uv[k])) << "face " << f << " uv " << k;
    }
    EXPECT_TRUE(same(want.normal, got.normal)) << "face " << f;
    EXPECT_TRUE(same(want.centroid, got.centroid)) << "face " << f;
    EXPECT_TRUE(same(want.area, got.area)) << "face " << f;
    EXPECT_TRUE(same(want.reflectance, got.reflectance)) << "face " << f;
    EXPECT_TRUE(same(want.emission, got.emission)) << "face " << f;
    EXPECT_TRUE(same(want.direct, got.direct)) << "face " << f;
    EXPECT_EQ(want.mesh, got.mesh);
    EXPECT_EQ(want.face, got.face);
    EXPECT_EQ(want.back, got.back);
}

Patch finished(const std::vector<Vec3>& corners, const std::vector<Vec2>& uv, uint32_t face) {
    Patch p;
    p.nv = int(corners.size());
    for (int k = 0; k < p.nv; ++k) {
        p.p[k] = corners[k];
        p.uv[k] = uv.empty() ? Vec2{} : uv[k];
    }
    p.vertex = {0, 0, 0, 0};
    p.face = face;
    p.mesh = face % 3;
    p.reflectance = {0.1 * (face % 4), 0.5, 0.9};
    p.emission = {face == 2 ? 3.0 : 0.0, 0, 0};
    finish_patch(p, PatchCentroid::CornerMean);
    return p;
}

TEST(FaceTable, APatchMadeFromTheTableIsThePatchItWasMadeFrom) {
    // Quads and triangles, texture coordinates on some faces only (the table keeps none until
    // one has them), a corner at -0.0 beside one at +0.0 (welded by their bits: two points),
    // awkward coordinates whose centroid rounds, a back (corners reversed), and light set
    // after the face went in.
    std::vector<Patch> want;
    want.push_back(finished({{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0}}, {}, 0));
    want.push_back(finished({{-0.0, 0, 0}, {0.1, 0.3, 0.7}, {1.0 / 3, 2.0 / 7, 1e-9}}, {}, 1));
    want.push_back(finished({{0.1, 0.2, 0.3}, {1.7, 0.2, 0.3}, {1.7, 2.9, 0.31}, {0.1, 2.9, 0.3}},
                            {{0, 0}, {0.25, 0}, {0.25, 0.5}, {0, 0.5}}, 2));
    want.push_back(finished({{1, 1, 0}, {1, 0, 0}, {0, 0, 0}}, {{0.5, 0.5}, {0.5, 0}, {0, 0}}, 3));
    Patch back = want[2];
    std::swap(back.p[0], back.p[3]);
    std::swap(back.p[1], back.p[2]);
    back.back = true;
    back.emission = {};
    finish_patch(back, PatchCentroid::CornerMean);
    want.push_back(back);
    FaceTable table;
    for (const Patch& p : want) table.push_back(p);
    table.seal();
    ASSERT_EQ(table.size(), want.size());
    want[3].direct = {0.2, 0.3, 0.4};
    want[3].emission = want[3].emission + mul(want[3].reflectance, want[3].direct);
    table.set_light(3, want[3].direct, want[3].emission);
    for (size_t f = 0; f < want.size(); ++f) {
        expect_same_patch(want[f], table[f], f);
        EXPECT_TRUE(same(table.normal(f), want[f].normal));
        EXPECT_TRUE(same(table.area(f), want[f].area));
        EXPECT_TRUE(same(table.point(f, 0.3, 0.6), want[f].point(0.3, 0.6))) << "face " << f;
    }
    // -0.0 and +0.0 are different points (a patch made again must keep its own sign).
    EXPECT_TRUE(std::signbit(table[1].p[0].x));
    EXPECT_FALSE(std::signbit(table[0].p[0].x));
}

TEST(FaceTable, LightIsHeldOnlyOnceAFaceHasSome) {
    // A table whose faces have no emission or direct light (a ray scene's display faces) holds
    // neither array: 48 bytes a face less. The first face with some makes the array, the faces
    // before it reading zeros; an emission of -0.0 is some (its bits are kept); set_light on a
    // table without light makes it too.
    std::vector<Patch> dark;
    for (int k = 0; k < 64; ++k) {
        dark.push_back(finished({{0, 0, double(k)}, {1, 0, double(k)}, {1, 1, double(k)}}, {}, k));
        dark.back().emission = {};
    }
    FaceTable plain, lit;
    for (const Patch& p : dark) plain.push_back(p);
    Patch glowing = dark[10], signed_zero = dark[20];
    glowing.emission = {1, 2, 3};
    signed_zero.direct = {-0.0, 0, 0};
    for (size_t k = 0; k < dark.size(); ++k) lit.push_back(k == 10 ? glowing : (k == 20 ? signed_zero : dark[k]));
    plain.seal();
    lit.seal();
    EXPECT_EQ(lit.bytes() - plain.bytes(), 2 * dark.size() * sizeof(RGB));
    for (size_t f = 0; f < dark.size(); ++f) {
        const Patch want = f == 10 ? glowing : (f == 20 ? signed_zero : dark[f]);
        expect_same_patch(want, lit[f], f);
        expect_same_patch(dark[f], plain[f], f);
    }
    EXPECT_TRUE(std::signbit(lit.direct(20).x));
    const RGB d{0.5, 0.25, 0.125};
    plain.set_light(7, d, RGB{});
    EXPECT_TRUE(same(plain.direct(7), d));
    EXPECT_TRUE(same(plain.direct(8), RGB{}));
    EXPECT_TRUE(same(plain.emission(7), RGB{}));
}

TEST(FaceTable, AHierarchysFacesAreThePatchesOfItsSceneFacesAndTakeAFractionOfTheirBytes) {
    // A tiled cube of 40 x 40 quads a side, each quad as two triangles: 19,200 faces whose
    // corners are shared by up to six of them. Every element root's patch is its scene face
    // finished as the hierarchy finishes it, and the table holds what its layout says.
    Scene quads = test::tiled_cube(40, test::grey(0.5));
    Scene scene;
    for (const Face& q : quads.faces)
        for (int half = 0; half < 2; ++half) {
            Face t = q;
            t.nv = 3;
            const int c[2][3] = {{0, 1, 2}, {0, 2, 3}};
            for (int k = 0; k < 3; ++k) t.p[k] = q.p[c[half][k]];
            t.p[3] = t.p[2];
            scene.faces.push_back(t);
        }
    const Hierarchy h(scene);
    ASSERT_EQ(h.faces.size(), scene.faces.size());
    for (uint32_t f = 0; f < scene.faces.size(); ++f) {
        const Face& face = scene.faces[f];
        Patch want;
        want.nv = face.nv;
        for (int k = 0; k < 4; ++k) {
            want.p[k] = face.p[std::min(k, face.nv - 1)];
            want.uv[k] = face.uv[std::min(k, face.nv - 1)];
        }
        want.reflectance = face.reflectance;
        want.emission = face.emission;
        want.mesh = face.mesh;
        want.face = f;
        want.vertex = {0, 0, 0, 0};
        finish_patch(want, PatchCentroid::CornerMean);
        expect_same_patch(want, h.shape(h.face_node[f]), f);
        if (::testing::Test::HasFailure()) return;
    }
    // 112 bytes a face (corner indices, mesh, face, reflectance index, corner count and side:
    // 32; normal 24, area 8, emission 24, direct 24) and 24 a point, no texture coordinates
    // (the cube has none), under half a Patch's 328 a face in all.
    const size_t n = h.faces.size();
    EXPECT_LE(h.faces.bytes(), 112 * n + 24 * h.faces.points() + 4096) << h.faces.bytes() << " bytes";
    EXPECT_LT(double(h.faces.bytes()), 0.5 * double(sizeof(Patch) * n)) << h.faces.bytes() << " bytes";
    // One point for each distinct corner of the scene's faces (by its bits).
    std::set<std::array<uint64_t, 3>> distinct;
    for (const Face& face : scene.faces)
        for (int k = 0; k < face.nv; ++k) {
            std::array<uint64_t, 3> bits;
            std::memcpy(bits.data(), &face.p[k], sizeof bits);
            distinct.insert(bits);
        }
    EXPECT_EQ(h.faces.points(), distinct.size());
    EXPECT_LT(distinct.size(), scene.faces.size());  // shared corners: fewer points than faces
}

TEST(FaceTable, EmbreeKeepsOneVertexAPointAndACompactTree) {
    // Visibility over a hierarchy's faces hands Embree the table's points once and quads that
    // index them, and asks for its compact tree (leaves that index the vertices instead of
    // copying four of them a quad): what Embree holds after the build is its index and vertex
    // buffers (16 bytes a face, 12 a point) plus the tree, counted by the device's memory
    // monitor.
    Scene quads = test::tiled_cube(40, test::grey(0.5));
    const Hierarchy h(quads);
    const Visibility vis(h.faces);
    const size_t n = h.faces.size(), points = h.faces.points();
    const uint64_t buffers = 16 * n + 12 * points;
    EXPECT_GE(vis.bytes(), buffers);
    EXPECT_GE(vis.peak_bytes(), vis.bytes());
    // The compact tree: a leaf of four quads holds their 16 vertex indices and their ids (96
    // bytes, 24 a quad), and a 4-wide node, its children's boxes and references (128 bytes),
    // comes once for about three leaves (11 a quad): under 48 bytes a face. The default tree
    // copies each quad's four vertices into its leaf (48 bytes a quad and more: 82 a face here).
    const double tree_per_face = double(vis.bytes() - buffers) / double(n);
    EXPECT_LT(tree_per_face, 48.0) << vis.bytes() << " bytes for " << n << " faces and " << points << " points";
}

}  // namespace
}  // namespace hirad
