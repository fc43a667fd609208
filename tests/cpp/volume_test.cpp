// Irradiance volume probes (pipeline/outputs/volume.h) against closed forms: inside a closed
// box of uniform radiance L a probe sees L in every direction, so s0 = 4 pi L and the
// irradiance on any plane is pi L; with only the ceiling of a cube lit, s0 is L times the
// ceiling's solid angle (4 pi / 6 from the centre) and s1_z is L pi F(dA -> ceiling).
#include "pipeline/outputs/volume.h"

#include <gtest/gtest.h>

#include <cmath>
#include <vector>

#include "tests/cpp/test_scenes.h"
namespace hirad {
namespace {

TEST(VolumeProbes, UniformRadianceInAClosedBoxIntegratesToFourPiL) {
    const std::vector<Patch> patches = test::unit_cube_patches(3, test::grey(0.5));
    Visibility vis(patches);
    const RGB L{0.5, 1.0, 2.0};
    CornerValues radiance(patches.size(), {L, L, L, L});
    const std::vector<Vec3> points = {{0.5, 0.5, 0.5}, {0.1, 0.2, 0.9}, {0.93, 0.5, 0.07}};
    const int rays = 1024;  // 32 x 32 strata
    const std::vector<ProbeMoments> m = probe_moments(patches, vis, radiance, points, rays, 3);
    ASSERT_EQ(m.size(), points.size());
    for (size_t q = 0; q < m.size(); ++q) {
        SCOPED_TRACE(q);
        EXPECT_EQ(m[q].hit_fraction, 1.0);
        EXPECT_EQ(m[q].back_fraction, 0.0);
        for (int c = 0; c < 3; ++c) {
            // Every ray meets L and carries 4 pi / n: the sum is exact to rounding.
            EXPECT_NEAR(m[q].s0[c], 4 * kPi * L[c], 1e-12 * L[c]);
            // The first moments of a uniform field vanish; stratified directions leave an
            // error of the order of a stratum's width (2 / 32 in z) times 4 pi L.
            for (int a = 0; a < 3; ++a) EXPECT_LT(std::fabs(m[q].s1[a][c]), 4 * kPi * L[c] * (2.0 / 32)) << a;
            // L1 irradiance on a plane facing up: pi L.
            const double e_up = m[q].s0[c] / 4 + m[q].s1[2][c] / 2;
            EXPECT_NEAR(e_up, kPi * L[c], 0.05 * kPi * L[c]);
        }
        EXPECT_GT(m[q].nearest, 0.0);
    }
}

TEST(VolumeProbes, OnlyTheCeilingLitSeenFromTheCentre) {
    const std::vector<Patch> patches = test::unit_cube_patches(2, test::grey(0.5));
    Visibility vis(patches);
    CornerValues radiance(patches.size());
    const RGB L{1, 1, 1};
    for (size_t i = 0; i < patches.size(); ++i)
        if (patches[i].normal.z < -0.5) radiance.corners(i) = {L, L, L, L};  // the ceiling faces down
    const std::vector<ProbeMoments> m = probe_moments(patches, vis, radiance, {{0.5, 0.5, 0.5}}, 128 * 128, 9);
    // Solid angle of one face of a cube from its centre: 4 pi / 6.
    EXPECT_NEAR(m[0].s0.x, 4 * kPi / 6, 0.01 * 4 * kPi / 6);
    // s1_z = L * integral of cos over the ceiling = L pi F, F from the centre point (facing
    // up) to the ceiling: four 0.5 x 0.5 rectangles at distance 0.5, each with the point
    // under a corner (A = B = 1): F = 4 / (2 pi) * 2 * (1 / sqrt 2) atan(1 / sqrt 2).
    const double F = 4.0 / (2 * kPi) * 2 * (1 / std::sqrt(2.0)) * std::atan(1 / std::sqrt(2.0));
    EXPECT_NEAR(m[0].s1[2].x, kPi * F, 0.01 * kPi * F);
    EXPECT_NEAR(m[0].s1[0].x, 0.0, 0.01);
    EXPECT_NEAR(m[0].s1[1].x, 0.0, 0.01);
}

TEST(VolumeProbes, AProbeInsideASolidSeesBackFaces) {
    // Outside the inward-facing cube, every ray that hits it meets the back of a face.
    const std::vector<Patch> patches = test::unit_cube_patches(1, test::grey(0.5));
    Visibility vis(patches);
    CornerValues radiance(patches.size(), {RGB{1, 1, 1}, RGB{1, 1, 1}, RGB{1, 1, 1}, RGB{1, 1, 1}});
    const std::vector<ProbeMoments> m = probe_moments(patches, vis, radiance, {{0.5, 0.5, 3.0}}, 4096, 1);
    EXPECT_GT(m[0].hit_fraction, 0.0);
    EXPECT_EQ(m[0].back_fraction, m[0].hit_fraction);
    EXPECT_EQ(m[0].s0.x, 0.0);
}

}  // namespace
}  // namespace hirad
