// L2 spherical-harmonic probes (pipeline/outputs/volume.h, RayScene::volume_probes) against
// closed forms and independent quadratures:
//  - the basis is orthonormal: a fine midpoint quadrature of Y_i Y_j over the sphere gives the
//    identity;
//  - inside a closed box of uniform radiance L, sh2_0 = sqrt(4 pi) L and the rest vanish;
//  - with only the ceiling of a cube lit (L = 1), sh2_k = integral over the ceiling of Y_k dw,
//    computed here by a midpoint rule over the ceiling's area (dw = h dA / r^3);
//  - luminaires (deltas of radiance): sh2_k = sum over the luminaire's points of
//    w_p I / r_p^2 Y_k(direction to p), which the s0/s1 moments alone could not give.
#include <gtest/gtest.h>

#include <cmath>
#include <vector>

#include "pipeline/engine/ray_scene.h"
#include "pipeline/outputs/volume.h"
#include "tests/cpp/test_scenes.h"

namespace hirad {
namespace {

TEST(VolumeSH2, BasisIsOrthonormal) {
    // Midpoint rule in (z, phi): equal-area cells, so every cell weighs 4 pi / (nz nphi).
    const int nz = 400, nphi = 800;
    double g[9][9] = {};
    for (int i = 0; i < nz; ++i)
        for (int j = 0; j < nphi; ++j) {
            const double z = 1 - 2 * (i + 0.5) / nz, phi = 2 * kPi * (j + 0.5) / nphi;
            const double r = std::sqrt(1 - z * z);
            double y[9];
            sh2_basis({r * std::cos(phi), r * std::sin(phi), z}, y);
            for (int a = 0; a < 9; ++a)
                for (int b = 0; b < 9; ++b) g[a][b] += y[a] * y[b];
        }
    for (int a = 0; a < 9; ++a)
        for (int b = 0; b < 9; ++b) EXPECT_NEAR(g[a][b] * 4 * kPi / (nz * nphi), a == b ? 1.0 : 0.0, 1e-4) << a << b;  // midpoint error ~ (2 / nz)^2
}

TEST(VolumeSH2, UniformRadianceProjectsOntoTheConstantOnly) {
    const std::vector<Patch> patches = test::unit_cube_patches(3, test::grey(0.5));
    Visibility vis(patches);
    const RGB L{0.5, 1.0, 2.0};
    CornerValues radiance(patches.size(), {L, L, L, L});
    const std::vector<ProbeMoments> m = probe_moments(patches, vis, radiance, {{0.5, 0.5, 0.5}, {0.2, 0.7, 0.1}}, 1024, 5);
    for (const ProbeMoments& p : m)
        for (int c = 0; c < 3; ++c) {
            // integral of L Y_0 = L / (2 sqrt pi) * 4 pi = sqrt(4 pi) L; every ray sees L.
            EXPECT_NEAR(p.sh2[0][c], std::sqrt(4 * kPi) * L[c], 1e-12 * L[c]);
            // Higher bands integrate to zero; stratified rays leave ~ one stratum's width.
            for (int k = 1; k < 9; ++k) EXPECT_LT(std::fabs(p.sh2[k][c]), 0.02 * std::sqrt(4 * kPi) * L[c]) << k;
        }
}

TEST(VolumeSH2, OnlyTheCeilingLitMatchesAQuadratureOverTheCeiling) {
    const std::vector<Patch> patches = test::unit_cube_patches(2, test::grey(0.5));
    Visibility vis(patches);
    CornerValues radiance(patches.size());
    for (size_t i = 0; i < patches.size(); ++i)
        if (patches[i].normal.z < -0.5) radiance.corners(i) = {RGB{1, 1, 1}, RGB{1, 1, 1}, RGB{1, 1, 1}, RGB{1, 1, 1}};
    const Vec3 x{0.5, 0.4, 0.35};  // off-centre: x, y and the L2 terms all differ from zero
    const std::vector<ProbeMoments> m = probe_moments(patches, vis, radiance, {x}, 256 * 256, 11);
    // The ceiling z = 1 as a 1000 x 1000 midpoint grid: dw = h dA / r^3 with h = 1 - x.z.
    const int n = 1000;
    double ref[9] = {};
    for (int i = 0; i < n; ++i)
        for (int j = 0; j < n; ++j) {
            const Vec3 p{(i + 0.5) / n, (j + 0.5) / n, 1.0};
            const Vec3 d = p - x;
            const double r = length(d);
            const double dw = (1 - x.z) / (r * r * r) / (double(n) * n);
            double y[9];
            sh2_basis(d / r, y);
            for (int k = 0; k < 9; ++k) ref[k] += y[k] * dw;
        }
    for (int k = 0; k < 9; ++k) EXPECT_NEAR(m[0].sh2[k].x, ref[k], 0.005 * ref[0]) << k << " ref " << ref[k];
    // Bands 0 and 1 are the existing moments rescaled.
    EXPECT_NEAR(m[0].sh2[0].x, m[0].s0.x * 0.5 / std::sqrt(kPi), 1e-12);
    EXPECT_NEAR(m[0].sh2[2].x, m[0].s1[2].x * std::sqrt(3 / (4 * kPi)), 1e-12);
}

TEST(VolumeSH2, LuminairePointsAreDeltasOfRadiance) {
    // The cube (dark) with a two-point luminaire of constant intensity I inside it.
    const std::vector<Patch> patches = test::unit_cube_patches(1);
    std::vector<double> corners;
    std::vector<int32_t> nv;
    for (const Patch& p : patches) {
        nv.push_back(p.nv);
        for (int k = 0; k < 4; ++k) corners.insert(corners.end(), {p.p[k].x, p.p[k].y, p.p[k].z});
    }
    RayScene scene(corners.data(), nv.data(), patches.size(), nullptr, nullptr);
    Luminaire l;
    l.name = "two points";
    l.points = {{0.2, 0.3, 0.9}, {0.8, 0.6, 0.7}};
    l.weights = {0.25, 0.75};
    l.axis[0] = {1, 0, 0};
    l.axis[1] = {0, 1, 0};
    l.axis[2] = {0, 0, 1};
    l.candela = {3.0, 3.0};  // nc = 1, ng = 2: isotropic
    l.colour = {1, 0.5, 0.25};
    scene.set_luminaires({l});
    const Vec3 x{0.5, 0.5, 0.3};
    const VolumeProbes v = scene.volume_probes({x}, 64, 1);
    double ref[9] = {}, s0 = 0;
    for (int p = 0; p < 2; ++p) {
        const Vec3 d = l.points[p] - x;
        const double e = l.weights[p] * 3.0 / dot(d, d);
        double y[9];
        sh2_basis(d / length(d), y);
        for (int k = 0; k < 9; ++k) ref[k] += e * y[k];
        s0 += e;
    }
    EXPECT_NEAR(v.s0[0].x, s0, 1e-12 * s0);
    for (int k = 0; k < 9; ++k) {
        EXPECT_NEAR(v.sh2[0][k].x, ref[k], 1e-12 * s0) << k;
        EXPECT_NEAR(v.sh2[0][k].z, 0.25 * ref[k], 1e-12 * s0) << k;
    }
}

}  // namespace
}  // namespace hirad
