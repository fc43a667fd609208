// Illuminance at sensors (pipeline/outputs/illuminance.h) against closed forms: inside a
// closed box of uniform radiance L every sensor reads pi L; the direct light of a lit ceiling
// on a sensor facing it is pi L F(dA -> rectangle) (Howell's catalogue, the differential
// element below the corner of a parallel rectangle, summed over four quarters); an opaque
// blocker over the sensor takes all of it away.
#include "pipeline/outputs/illuminance.h"

#include <gtest/gtest.h>

#include <cmath>
#include <vector>

#include "tests/cpp/test_scenes.h"
namespace hirad {
namespace {

// F from dA to a parallel a x b rectangle at distance c, dA below one of its corners.
double corner_rectangle(double a, double b, double c) {
    const double x = a / c, y = b / c;
    return (x / std::sqrt(1 + x * x) * std::atan(y / std::sqrt(1 + x * x)) +
            y / std::sqrt(1 + y * y) * std::atan(x / std::sqrt(1 + y * y))) / (2 * kPi);
}

// The unit cube of 3 x 3 patches a side whose ceiling (z = 1) emits radiance le; the rest black.
struct LitCeiling {
    double le = 100;
    std::vector<Patch> patches = test::unit_cube_patches(3);
    std::vector<RGB> emitted;
    CornerValues radiance;
    LitCeiling() : emitted(patches.size(), RGB{}), radiance(patches.size()) {
        for (size_t i = 0; i < patches.size(); ++i)
            if (patches[i].normal.z < -0.5) {
                emitted[i] = test::grey(le);
                radiance.corners(i) = {emitted[i], emitted[i], emitted[i], emitted[i]};
            }
    }
};

TEST(Illuminance, PiecesTileThePatch) {
    const std::vector<Patch> quads = test::unit_cube_patches(1);
    for (int g : {1, 2, 5}) {
        double area = 0;
        for (const Patch& p : patch_pieces(quads[0], g)) area += p.area;
        EXPECT_NEAR(area, quads[0].area, 1e-12) << g;
        Patch tri = quads[0];
        tri.nv = 3;
        tri.p[3] = tri.p[2];
        finish_patch(tri, PatchCentroid::AreaWeighted);
        const std::vector<Patch> t = patch_pieces(tri, g);
        EXPECT_EQ(t.size(), size_t(g) * g);
        area = 0;
        for (const Patch& p : t) {
            area += p.area;
            EXPECT_GT(dot(p.normal, tri.normal), 0.999);  // same orientation as the parent
        }
        EXPECT_NEAR(area, tri.area, 1e-12) << g;
    }
}

TEST(Illuminance, UniformBoxReadsPiLEverywhere) {
    const std::vector<Patch> patches = test::unit_cube_patches(3, test::grey(0.5));
    Visibility vis(patches);
    const RGB L{0.5, 1.0, 2.0};
    CornerValues radiance(patches.size(), {L, L, L, L});
    const std::vector<RGB> emitted(patches.size(), RGB{});
    const std::vector<Vec3> points = {{0.5, 0.5, 0.5}, {0.1, 0.2, 0.9}, {0.93, 0.5, 0.07}};
    const std::vector<Vec3> normals = {{0, 0, 1}, {1, 1, 0}, {-0.3, 0.2, -1}};
    const Illuminance e = illuminance_at(patches, vis, radiance, emitted, points, normals, {256, 4, 7});
    for (size_t q = 0; q < points.size(); ++q)
        for (int c = 0; c < 3; ++c) {
            EXPECT_NEAR(e.indirect[q][c], kPi * L[c], 1e-9 * L[c]) << q;  // every ray brings L
            EXPECT_EQ(e.direct[q][c], 0.0);
        }
}

TEST(Illuminance, LitCeilingIsExactAndShadowed) {
    // The ceiling (z = 1, 3 x 3 patches) emits L; everything else is black.
    LitCeiling box;
    std::vector<Patch>& patches = box.patches;
    std::vector<RGB>& emitted = box.emitted;
    CornerValues& radiance = box.radiance;
    const double le = box.le;
    {
        Visibility vis(patches);
        const Vec3 x{0.5, 0.5, 0.3};
        const Illuminance e = illuminance_at(patches, vis, radiance, emitted, {x}, {{0, 0, 1}}, {64, 3, 1});
        const double expected = kPi * le * 4 * corner_rectangle(0.5, 0.5, 0.7);
        EXPECT_NEAR(e.direct[0].x, expected, 1e-9 * expected);
        EXPECT_EQ(e.indirect[0].x, 0.0);  // the ceiling's own emission is not counted twice
        // Facing down, the sensor sees none of the ceiling.
        const Illuminance d = illuminance_at(patches, vis, radiance, emitted, {x}, {{0, 0, -1}}, {64, 3, 1});
        EXPECT_EQ(d.direct[0].x, 0.0);
    }
    // A large opaque sheet just above the sensor, facing down: no piece of the ceiling is seen.
    Patch sheet = patches[0];
    sheet.p = {Vec3{-1, -1, 0.5}, Vec3{-1, 2, 0.5}, Vec3{2, 2, 0.5}, Vec3{2, -1, 0.5}};
    sheet.nv = 4;
    finish_patch(sheet, PatchCentroid::AreaWeighted);
    patches.push_back(sheet);
    emitted.push_back(RGB{});
    radiance.push_back({});
    Visibility vis(patches);
    const Illuminance e = illuminance_at(patches, vis, radiance, emitted, {{0.5, 0.5, 0.3}}, {{0, 0, 1}}, {64, 3, 1});
    EXPECT_EQ(e.direct[0].x, 0.0);
}

TEST(Illuminance, SensorOnTheFloorReadsTheCeiling) {
    // A calculation grid at floor level (a corridor's, height 0) puts its sensors on the floor
    // itself. Each reads the lit ceiling's pi L F whole: the floor under it blocks no shadow ray
    // (they start Visibility::ray_offset() off it; from the point itself they met the floor at t = 0 and the
    // direct light read 0). Sensors at the floor's middle and off it, by the corner formula.
    LitCeiling box;
    const std::vector<Patch>& patches = box.patches;
    const double le = box.le;
    Visibility vis(patches);
    const std::vector<Vec3> points = {{0.5, 0.5, 0.0}, {0.2, 0.7, 0.0}, {1.0 / 3, 1.0 / 3, 0.0}};
    const Illuminance e = illuminance_at(patches, vis, box.radiance, box.emitted, points,
                                         std::vector<Vec3>(points.size(), Vec3{0, 0, 1}), {16, 3, 1});
    for (size_t q = 0; q < points.size(); ++q) {
        const double x = points[q].x, y = points[q].y;
        const double f = corner_rectangle(x, y, 1) + corner_rectangle(1 - x, y, 1) + corner_rectangle(x, 1 - y, 1) +
                         corner_rectangle(1 - x, 1 - y, 1);
        EXPECT_NEAR(e.direct[q].x, kPi * le * f, 1e-9 * kPi * le * f) << q;
    }
}

}  // namespace
}  // namespace hirad
