// Scene::build: which polygons stay quads, which are triangulated, what is dropped and counted.
#include "pipeline/geometry/scene.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <string>
#include <vector>

namespace hirad {
namespace {

// A polygon soup in the flat layout the USD reader produces. Corners given by position are
// deduplicated by exact equality, so faces that share a corner share its index (the way a
// welded mesh shares them).
struct Soup {
    std::vector<double> points;
    std::vector<int32_t> counts, indices, mesh, source;
    std::vector<double> reflectance, emission, uv;
    bool with_uv = false;

    int32_t point(const Vec3& p) {
        for (size_t i = 0; i < points.size() / 3; ++i)
            if (points[3 * i] == p.x && points[3 * i + 1] == p.y && points[3 * i + 2] == p.z) return int32_t(i);
        points.insert(points.end(), {p.x, p.y, p.z});
        return int32_t(points.size() / 3 - 1);
    }
    // A corner that is never shared (e.g. one holding a NaN, which equals nothing).
    int32_t fresh_point(const Vec3& p) {
        points.insert(points.end(), {p.x, p.y, p.z});
        return int32_t(points.size() / 3 - 1);
    }
    void face_indices(const std::vector<int32_t>& idx, const std::vector<Vec2>& uvs = {}) {
        counts.push_back(int32_t(idx.size()));
        indices.insert(indices.end(), idx.begin(), idx.end());
        mesh.push_back(0);
        source.push_back(int32_t(counts.size() - 1));
        reflectance.insert(reflectance.end(), {0.5, 0.5, 0.5});
        emission.insert(emission.end(), {0.0, 0.0, 0.0});
        for (size_t k = 0; k < idx.size(); ++k) {
            Vec2 t = k < uvs.size() ? uvs[k] : Vec2{};
            uv.insert(uv.end(), {t.u, t.v});
        }
    }
    void face(const std::vector<Vec3>& corners, const std::vector<Vec2>& uvs = {}) {
        std::vector<int32_t> idx;
        for (const Vec3& p : corners) idx.push_back(point(p));
        face_indices(idx, uvs);
    }
    Scene build() const {
        SceneInput in;
        in.points = points.data();
        in.num_points = points.size() / 3;
        in.face_vertex_counts = counts.data();
        in.face_vertex_indices = indices.data();
        in.num_faces = counts.size();
        in.face_mesh = mesh.data();
        in.face_source = source.data();
        in.face_reflectance = reflectance.data();
        in.face_emission = emission.data();
        in.corner_uv = with_uv ? uv.data() : nullptr;
        return Scene::build(in);
    }
};

// Twice the signed area of a 2D polygon (shoelace), positive when counter-clockwise.
double shoelace2(const std::vector<std::array<double, 2>>& q) {
    double s = 0;
    for (size_t k = 0; k < q.size(); ++k) {
        const auto& a = q[k];
        const auto& b = q[(k + 1) % q.size()];
        s += a[0] * b[1] - a[1] * b[0];
    }
    return s;
}

// An orthonormal frame (e1, e2, e1 x e2) placed at `origin`: maps plane coordinates into 3D.
struct Frame {
    Vec3 origin, e1, e2;
    Vec3 operator()(double x, double y) const { return origin + e1 * x + e2 * y; }
    Vec3 normal() const { return cross(e1, e2); }
};

// Frames whose normals have every sign and dominant axis, so the projection used by the
// triangulator is exercised with and without its orientation flip.
std::vector<Frame> frames() {
    std::vector<Frame> out;
    out.push_back({{0, 0, 0}, {1, 0, 0}, {0, 1, 0}});                       // +z
    out.push_back({{1, 2, 3}, {0, 1, 0}, {1, 0, 0}});                       // -z
    out.push_back({{-1, 0.5, 2}, {0, 1, 0}, {0, 0, 1}});                    // +x
    out.push_back({{0.3, -2, 1}, {0, 0, 1}, {0, 1, 0}});                    // -x
    // A tilted plane: e1 = (3, 4, 0)/5, e2 = (0, 0.6, 0.8) orthogonalised by hand:
    // e2 - (e2.e1) e1 with e2.e1 = 0.48 gives (-0.288, 0.216, 0.8), length sqrt(0.7696).
    const double l = std::sqrt(0.288 * 0.288 + 0.216 * 0.216 + 0.64);
    out.push_back({{0.25, 0.5, -0.75}, {0.6, 0.8, 0}, {-0.288 / l, 0.216 / l, 0.8 / l}});
    out.push_back({{0.25, 0.5, -0.75}, {-0.288 / l, 0.216 / l, 0.8 / l}, {0.6, 0.8, 0}});  // its mirror
    return out;
}

// Crossing-number test in the polygon's own 2D coordinates.
bool inside_polygon(const std::vector<std::array<double, 2>>& q, double x, double y) {
    bool in = false;
    for (size_t k = 0, l = q.size() - 1; k < q.size(); l = k++) {
        const auto &a = q[k], &b = q[l];
        if ((a[1] > y) != (b[1] > y) && x < (b[0] - a[0]) * (y - a[1]) / (b[1] - a[1]) + a[0]) in = !in;
    }
    return in;
}

void expect_triangulated_like(const Scene& scene, const Frame& fr, const std::vector<std::array<double, 2>>& poly2d,
                              const char* what) {
    SCOPED_TRACE(what);
    const double area = 0.5 * shoelace2(poly2d);
    ASSERT_GT(area, 0);
    EXPECT_EQ(scene.stats.triangulated_faces, 1u);
    // A triangulation of a simple n-gon without new vertices has n - 2 triangles; fewer
    // survive when one of them is a zero-area sliver across collinear corners (dropped).
    ASSERT_GE(scene.faces.size(), 1u);
    ASSERT_LE(scene.faces.size(), poly2d.size() - 2);
    double total = 0;
    const Vec3 n = fr.normal();
    for (const Face& f : scene.faces) {
        EXPECT_EQ(f.nv, 3);
        total += f.area();
        // Each triangle faces the way the polygon does (a flipped one would still add area).
        EXPECT_GT(dot(f.normal(), n), 1 - 1e-12);
        // ... and lies inside the polygon (its centroid does; with the total area exact, no
        // triangle can then spill over a reflex corner).
        Vec3 c = (f.p[0] + f.p[1] + f.p[2]) / 3.0 - fr.origin;
        EXPECT_TRUE(inside_polygon(poly2d, dot(c, fr.e1), dot(c, fr.e2)));
    }
    EXPECT_NEAR(total, area, 1e-12 * area);
}

TEST(SceneBuild, PlanarConvexQuadStaysQuad) {
    for (const Frame& fr : frames()) {
        Soup soup;
        // A general convex quad (no two sides parallel).
        soup.face({fr(0, 0), fr(2, 0.2), fr(2.5, 1.7), fr(-0.3, 1.2)});
        Scene scene = soup.build();
        ASSERT_EQ(scene.faces.size(), 1u);
        const Face& f = scene.faces[0];
        EXPECT_EQ(f.nv, 4);
        EXPECT_EQ(scene.stats.triangulated_faces, 0u);
        EXPECT_EQ(scene.stats.degenerate_faces, 0u);
        EXPECT_EQ(scene.stats.input_faces, 1u);
        EXPECT_GT(dot(f.normal(), fr.normal()), 1 - 1e-12);
        const double area = 0.5 * shoelace2({{{0, 0}}, {{2, 0.2}}, {{2.5, 1.7}}, {{-0.3, 1.2}}});
        EXPECT_NEAR(f.area(), area, 1e-12 * area);
    }
}

TEST(SceneBuild, NonPlanarQuadIsTriangulated) {
    Soup soup;
    // The unit square with two opposite corners lifted by 0.1: far outside any planarity
    // tolerance.
    soup.face({{0, 0, 0}, {1, 0, 0.1}, {1, 1, 0}, {0, 1, 0.1}});
    Scene scene = soup.build();
    EXPECT_EQ(scene.stats.triangulated_faces, 1u);
    ASSERT_EQ(scene.faces.size(), 2u);
    for (const Face& f : scene.faces) {
        EXPECT_EQ(f.nv, 3);
        EXPECT_GT(f.normal().z, 0);  // still facing +z
    }
}

TEST(SceneBuild, ConcaveQuadIsTriangulatedWithItsArea) {
    for (const Frame& fr : frames()) {
        // An arrowhead: reflex corner at (0.5, 1). Shoelace: 0 + 4 - 1 + 0 = 3, area 1.5.
        std::vector<std::array<double, 2>> q = {{{0, 0}}, {{2, 1}}, {{0, 2}}, {{0.5, 1}}};
        Soup soup;
        std::vector<Vec3> corners;
        for (const auto& c : q) corners.push_back(fr(c[0], c[1]));
        soup.face(corners);
        Scene scene = soup.build();
        expect_triangulated_like(scene, fr, q, "arrowhead");
    }
}

TEST(SceneBuild, LShapedHexagonTriangulatedWithExactArea) {
    // L: 2x2 square minus the unit square at (1..2, 1..2): area 3.
    std::vector<std::array<double, 2>> q = {{{0, 0}}, {{2, 0}}, {{2, 1}}, {{1, 1}}, {{1, 2}}, {{0, 2}}};
    ASSERT_DOUBLE_EQ(0.5 * shoelace2(q), 3.0);
    for (const Frame& fr : frames()) {
        // Start the polygon at every corner: the reflex corner must never be clipped as an ear.
        for (size_t start = 0; start < q.size(); ++start) {
            SCOPED_TRACE(testing::Message() << "frame normal " << fr.normal().x << " " << fr.normal().y << " "
                                            << fr.normal().z << ", first corner " << start);
            Soup soup;
            std::vector<Vec3> corners;
            for (size_t k = 0; k < q.size(); ++k) corners.push_back(fr(q[(start + k) % q.size()][0], q[(start + k) % q.size()][1]));
            soup.face(corners);
            expect_triangulated_like(soup.build(), fr, q, "L hexagon");
        }
    }
}

TEST(SceneBuild, ConcaveUOctagonTriangulatedWithExactArea) {
    // U: 3x2 rectangle minus the notch (1..2, 1..2): area 6 - 1 = 5.
    std::vector<std::array<double, 2>> q = {{{0, 0}}, {{3, 0}}, {{3, 2}}, {{2, 2}},
                                            {{2, 1}}, {{1, 1}}, {{1, 2}}, {{0, 2}}};
    ASSERT_DOUBLE_EQ(0.5 * shoelace2(q), 5.0);
    for (const Frame& fr : frames()) {
        for (size_t start = 0; start < q.size(); ++start) {
            SCOPED_TRACE(testing::Message() << "frame normal " << fr.normal().x << " " << fr.normal().y << " "
                                            << fr.normal().z << ", first corner " << start);
            Soup soup;
            std::vector<Vec3> corners;
            for (size_t k = 0; k < q.size(); ++k) corners.push_back(fr(q[(start + k) % q.size()][0], q[(start + k) % q.size()][1]));
            soup.face(corners);
            expect_triangulated_like(soup.build(), fr, q, "U octagon");
        }
    }
}

TEST(SceneBuild, NonFiniteCornerDropsTheFace) {
    const double nan = std::numeric_limits<double>::quiet_NaN();
    const double inf = std::numeric_limits<double>::infinity();
    Soup soup;
    soup.face({{0, 0, 0}, {1, 0, 0}, {0, 1, 0}});  // a good triangle, kept
    soup.face_indices({soup.point({0, 0, 0}), soup.point({1, 0, 0}), soup.fresh_point({nan, 1, 0})});
    soup.face_indices({soup.point({0, 0, 0}), soup.fresh_point({1, inf, 0}), soup.point({1, 1, 0}), soup.point({0, 1, 0})});
    soup.face_indices({soup.fresh_point({0, 0, -inf}), soup.point({1, 0, 0}), soup.point({0, 1, 0})});
    Scene scene = soup.build();
    EXPECT_EQ(scene.stats.input_faces, 4u);
    EXPECT_EQ(scene.stats.nonfinite_faces, 3u);
    EXPECT_EQ(scene.stats.degenerate_faces, 0u);
    ASSERT_EQ(scene.faces.size(), 1u);
    EXPECT_EQ(scene.faces[0].source_face, 0u);
    for (const Face& f : scene.faces)
        for (int k = 0; k < f.nv; ++k) EXPECT_TRUE(isfinite(f.p[k]));
}

// A material the solve cannot take is refused, with the count and the first face: a NaN or
// infinite emission or reflectance, a negative one, or a reflectance above 1 (it would make
// light).
TEST(SceneBuild, InvalidMaterialsAreRefusedWithTheCountAndTheFirstFace) {
    const double nan = std::numeric_limits<double>::quiet_NaN();
    struct Case {
        int channel;
        bool emission;
        double value;
    };
    for (const Case& c : {Case{1, true, nan}, Case{0, true, -1.0}, Case{2, true, INFINITY}, Case{0, false, nan},
                          Case{1, false, -0.5}, Case{2, false, 1.5}}) {
        SCOPED_TRACE(testing::Message() << (c.emission ? "emission " : "reflectance ") << c.value);
        Soup soup;
        for (int k = 0; k < 4; ++k) soup.face({{double(k), 0, 0}, {k + 1.0, 0, 0}, {double(k), 1, 0}});
        (c.emission ? soup.emission : soup.reflectance)[3 * 2 + c.channel] = c.value;
        (c.emission ? soup.emission : soup.reflectance)[3 * 3 + c.channel] = c.value;
        try {
            soup.build();
            ADD_FAILURE() << "accepted";
        } catch (const std::invalid_argument& e) {
            const std::string msg = e.what();
            EXPECT_NE(msg.find("scene: 2 of 4 faces have a reflectance outside [0, 1], an emission"), std::string::npos)
                << msg;
            EXPECT_NE(msg.find("the first is face 2 (mesh 0, authored face 2)"), std::string::npos) << msg;
        }
    }
    // The edges of the valid range are valid: black, reflectance 1, no emission.
    Soup soup;
    soup.face({{0, 0, 0}, {1, 0, 0}, {0, 1, 0}});
    soup.reflectance = {0.0, 1.0, 0.0};
    EXPECT_EQ(soup.build().faces.size(), 1u);
}

// Polygons whose edges cross have no one surface: a bow tie (two lobes of opposite turn),
// a pentagram (its centre wound twice). They are skipped and counted, never covered twice or
// backwards; simple neighbours in the same mesh are kept whole.
TEST(SceneBuild, SelfIntersectingPolygonsAreSkippedAndCounted) {
    for (const Frame& fr : frames()) {
        SCOPED_TRACE(testing::Message() << "frame normal " << fr.normal().x << " " << fr.normal().y << " "
                                        << fr.normal().z);
        Soup soup;
        soup.face({fr(0, 0), fr(2, 2), fr(2, 0), fr(0, 1)});  // bow tie: lobes of area 1 and 1/3
        std::vector<Vec3> star;
        for (int k = 0; k < 5; ++k) {
            const double a = 2 * kPi * ((2 * k) % 5) / 5;
            star.push_back(fr(5 + std::cos(a), 5 + std::sin(a)));
        }
        soup.face(star);
        soup.face({fr(10, 0), fr(11, 0), fr(11, 1), fr(10.5, 0.5), fr(10, 1)});  // concave, simple
        soup.face({fr(20, 0), fr(21, 0), fr(21, 1), fr(20, 1)});               // a plain square
        const Scene scene = soup.build();
        EXPECT_EQ(scene.stats.self_intersecting_faces, 2u);
        EXPECT_EQ(scene.stats.degenerate_faces, 0u);
        double kept = 0;
        for (const Face& f : scene.faces) {
            EXPECT_GE(f.source_face, 2u);  // nothing of the bow tie or the star
            EXPECT_GT(dot(f.normal(), fr.normal()), 0.999);  // nothing faces backwards
            EXPECT_TRUE(std::isfinite(f.area()));
            kept += f.area();
        }
        EXPECT_NEAR(kept, 0.75 + 1.0, 1e-12);  // the concave pentagon (1 - 1/4) and the square
    }
}

TEST(PolygonSelfIntersects, CrossingEdgesOnly) {
    auto z0 = [](std::vector<std::array<double, 2>> q) {
        std::vector<Vec3> p;
        for (const auto& c : q) p.push_back({c[0], c[1], 0});
        return p;
    };
    // (A bow tie of equal lobes has no normal at all: Scene::build drops it as degenerate.)
    EXPECT_TRUE(polygon_self_intersects(z0({{0, 0}, {2, 2}, {2, 0}, {0, 1}})));
    EXPECT_TRUE(polygon_self_intersects(z0({{0, 0}, {3, 0}, {3, 3}, {1, -1}, {0, 3}})));
    EXPECT_FALSE(polygon_self_intersects(z0({{0, 0}, {1, 0}, {1, 1}, {0, 1}})));
    EXPECT_FALSE(polygon_self_intersects(z0({{0, 0}, {1, 0}, {1, 1}})));
    EXPECT_FALSE(polygon_self_intersects(z0({{0, 0}, {3, 0}, {3, 2}, {2, 2}, {2, 1}, {1, 1}, {1, 2}, {0, 2}})));  // U
    // Touching is not crossing: a keyhole (a square with a square hole joined by a bridge
    // walked both ways) stays a polygon to triangulate.
    EXPECT_FALSE(polygon_self_intersects(
        z0({{0, 0}, {4, 0}, {4, 4}, {0, 4}, {0, 0}, {1, 1}, {1, 3}, {3, 3}, {3, 1}, {1, 1}})));
}

TEST(SceneBuild, ZeroAreaAndRepeatedCornerFacesAreDegenerate) {
    Soup soup;
    soup.face({{0, 0, 0}, {1, 0, 0}, {2, 0, 0}});              // collinear: zero area
    soup.face({{0, 0, 0}, {1, 0, 0}, {2, 0, 0}, {3, 0, 0}});   // collinear quad
    soup.face_indices({soup.point({0, 0, 0}), soup.point({1, 0, 0}), soup.point({1, 0, 0})});  // b, b
    soup.face_indices({soup.point({0, 0, 0}), soup.point({1, 0, 0}), soup.point({0, 0, 0})});  // a, b, a
    soup.face_indices({soup.point({5, 5, 5}), soup.point({5, 5, 5}), soup.point({5, 5, 5})});  // one point
    Scene scene = soup.build();
    EXPECT_EQ(scene.stats.input_faces, 5u);
    EXPECT_EQ(scene.stats.degenerate_faces, 5u);
    EXPECT_EQ(scene.stats.nonfinite_faces, 0u);
    EXPECT_TRUE(scene.faces.empty());
}

TEST(SceneBuild, QuadWithRepeatedCornerIsKeptAsItsTriangle) {
    // The repeated corner is a zero-length edge, not a reason to drop the face: three
    // distinct corners remain, a right triangle of area 1/2.
    Soup soup;
    soup.face_indices({soup.point({0, 0, 0}), soup.point({1, 0, 0}), soup.point({1, 0, 0}), soup.point({0, 1, 0})});
    Scene scene = soup.build();
    EXPECT_EQ(scene.stats.degenerate_faces, 0u);
    ASSERT_EQ(scene.faces.size(), 1u);
    EXPECT_EQ(scene.faces[0].nv, 3);
    EXPECT_NEAR(scene.faces[0].area(), 0.5, 1e-15);
}

TEST(SceneBuild, EdgeSharedByThreeFacesIsOneNonmanifoldEdge) {
    Soup soup;
    // Three fins on the edge (0,0,0)-(1,0,0), plus a fourth face sharing a different edge
    // with only one of them (a manifold edge, not counted).
    soup.face({{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0}});
    soup.face({{1, 0, 0}, {0, 0, 0}, {0, 0, 1}});
    soup.face({{0, 0, 0}, {1, 0, 0}, {0.5, -1, -1}});
    soup.face({{1, 0, 0}, {2, 0, 0}, {1, 1, 0}});
    Scene scene = soup.build();
    EXPECT_EQ(scene.stats.nonmanifold_edges, 1u);
    EXPECT_EQ(scene.faces.size(), 4u);  // counted, not dropped
}

TEST(SceneBuild, ClosedCubeHasNoNonmanifoldEdges) {
    Soup soup;
    soup.face({{0, 0, 0}, {0, 1, 0}, {1, 1, 0}, {1, 0, 0}});
    soup.face({{0, 0, 1}, {1, 0, 1}, {1, 1, 1}, {0, 1, 1}});
    soup.face({{0, 0, 0}, {1, 0, 0}, {1, 0, 1}, {0, 0, 1}});
    soup.face({{0, 1, 0}, {0, 1, 1}, {1, 1, 1}, {1, 1, 0}});
    soup.face({{0, 0, 0}, {0, 0, 1}, {0, 1, 1}, {0, 1, 0}});
    soup.face({{1, 0, 0}, {1, 1, 0}, {1, 1, 1}, {1, 0, 1}});
    Scene scene = soup.build();
    EXPECT_EQ(scene.stats.nonmanifold_edges, 0u);
    EXPECT_EQ(scene.faces.size(), 6u);
    Vec3 lo, hi;
    scene.bounds(lo, hi);
    EXPECT_EQ(lo.x, 0); EXPECT_EQ(lo.y, 0); EXPECT_EQ(lo.z, 0);
    EXPECT_EQ(hi.x, 1); EXPECT_EQ(hi.y, 1); EXPECT_EQ(hi.z, 1);
}

TEST(SceneBuild, UVsAreCarriedToCorners) {
    Soup soup;
    soup.with_uv = true;
    soup.face({{0, 0, 0}, {2, 0, 0}, {2, 1, 0}, {0, 1, 0}}, {{0.1, 0.2}, {0.9, 0.2}, {0.9, 0.7}, {0.1, 0.7}});
    // An L hexagon: its triangles must take the uv of the polygon corner at each position.
    std::vector<Vec3> l = {{0, 0, 5}, {2, 0, 5}, {2, 1, 5}, {1, 1, 5}, {1, 2, 5}, {0, 2, 5}};
    std::vector<Vec2> luv;
    for (const Vec3& p : l) luv.push_back({0.25 * p.x + 0.125, 0.5 - 0.125 * p.y});
    soup.face(l, luv);
    Scene scene = soup.build();
    EXPECT_TRUE(scene.has_uv);
    ASSERT_EQ(scene.faces.size(), 1u + 4u);
    const Face& quad = scene.faces[0];
    ASSERT_EQ(quad.nv, 4);
    const Vec2 want[4] = {{0.1, 0.2}, {0.9, 0.2}, {0.9, 0.7}, {0.1, 0.7}};
    for (int k = 0; k < 4; ++k) {
        EXPECT_EQ(quad.uv[k].u, want[k].u);
        EXPECT_EQ(quad.uv[k].v, want[k].v);
    }
    for (size_t f = 1; f < scene.faces.size(); ++f)
        for (int k = 0; k < 3; ++k) {
            const Vec3& p = scene.faces[f].p[k];
            EXPECT_EQ(scene.faces[f].uv[k].u, 0.25 * p.x + 0.125);
            EXPECT_EQ(scene.faces[f].uv[k].v, 0.5 - 0.125 * p.y);
        }
}

TEST(SceneBuild, NoUVInputGivesZeroUVs) {
    Soup soup;
    soup.face({{0, 0, 0}, {1, 0, 0}, {0, 1, 0}});
    Scene scene = soup.build();
    EXPECT_FALSE(scene.has_uv);
    ASSERT_EQ(scene.faces.size(), 1u);
    for (int k = 0; k < 3; ++k) {
        EXPECT_EQ(scene.faces[0].uv[k].u, 0);
        EXPECT_EQ(scene.faces[0].uv[k].v, 0);
    }
}

TEST(SceneBuild, FaceAttributesAreCarried) {
    Soup soup;
    soup.face({{0, 0, 0}, {1, 0, 0}, {0, 1, 0}});
    soup.mesh[0] = 7;
    soup.source[0] = 42;
    soup.reflectance = {0.1, 0.2, 0.3};
    soup.emission = {4, 5, 6};
    Scene scene = soup.build();
    ASSERT_EQ(scene.faces.size(), 1u);
    const Face& f = scene.faces[0];
    EXPECT_EQ(f.mesh, 7u);
    EXPECT_EQ(f.source_face, 42u);
    EXPECT_EQ(f.reflectance.x, 0.1); EXPECT_EQ(f.reflectance.y, 0.2); EXPECT_EQ(f.reflectance.z, 0.3);
    EXPECT_EQ(f.emission.x, 4); EXPECT_EQ(f.emission.y, 5); EXPECT_EQ(f.emission.z, 6);
}

TEST(TriangulatePolygon, ConvexPentagonGivesThreeTriangles) {
    // Regular pentagon of circumradius 1 in a tilted plane; area (5/2) sin(72 deg).
    Frame fr = frames()[4];
    std::vector<Vec3> poly;
    for (int k = 0; k < 5; ++k) poly.push_back(fr(std::cos(2 * kPi * k / 5), std::sin(2 * kPi * k / 5)));
    auto tris = triangulate_polygon(poly);
    ASSERT_EQ(tris.size(), 3u);
    double total = 0;
    std::vector<int> used(5, 0);
    for (const auto& t : tris) {
        Vec3 c = cross(poly[t[1]] - poly[t[0]], poly[t[2]] - poly[t[0]]);
        EXPECT_GT(dot(c, fr.normal()), 0);
        total += 0.5 * length(c);
        for (int i : t) {
            ASSERT_GE(i, 0);
            ASSERT_LT(i, 5);
            used[i] = 1;
        }
    }
    const double area = 2.5 * std::sin(2 * kPi / 5);
    EXPECT_NEAR(total, area, 1e-12 * area);
    for (int u : used) EXPECT_EQ(u, 1);
}

TEST(TriangulatePolygon, FewerThanThreeCornersGiveNothing) {
    EXPECT_TRUE(triangulate_polygon({}).empty());
    EXPECT_TRUE(triangulate_polygon({{0, 0, 0}, {1, 0, 0}}).empty());
}

}  // namespace
}  // namespace hirad
