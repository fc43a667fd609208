// Light groups (Engine::set_light_groups): each group solved alone on the shared links sums to
// the solve of the whole scene (radiosity is linear in its source term), flat and hierarchical.
#include <gtest/gtest.h>

#include <vector>

#include "pipeline/engine/engine.h"

namespace hirad {
namespace {

// The closed unit cube, six quads facing inwards, one mesh each; faces 0 and 1 emit.
struct CubeInput {
    std::vector<double> points;
    std::vector<int32_t> counts, indices, mesh, source;
    std::vector<double> reflectance, emission;
    SceneInput in;
    CubeInput() {
        const double q[6][4][3] = {
            {{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0}}, {{0, 0, 1}, {0, 1, 1}, {1, 1, 1}, {1, 0, 1}},
            {{0, 0, 0}, {0, 1, 0}, {0, 1, 1}, {0, 0, 1}}, {{1, 0, 0}, {1, 0, 1}, {1, 1, 1}, {1, 1, 0}},
            {{0, 0, 0}, {0, 0, 1}, {1, 0, 1}, {1, 0, 0}}, {{0, 1, 0}, {1, 1, 0}, {1, 1, 1}, {0, 1, 1}}};
        for (int f = 0; f < 6; ++f) {
            for (int k = 0; k < 4; ++k) {
                for (int c = 0; c < 3; ++c) points.push_back(q[f][k][c]);
                indices.push_back(f * 4 + k);
            }
            counts.push_back(4);
            mesh.push_back(f);
            source.push_back(0);
            const double e[3] = {f == 0 ? 3.0 : 0.0, f == 1 ? 2.0 : 0.0, f == 0 ? 1.0 : f == 1 ? 4.0 : 0.0};
            for (int c = 0; c < 3; ++c) {
                reflectance.push_back(0.3 + 0.1 * c);
                emission.push_back(f < 2 ? e[c] + 0.5 : 0.0);
            }
        }
        in.points = points.data();
        in.num_points = points.size() / 3;
        in.face_vertex_counts = counts.data();
        in.face_vertex_indices = indices.data();
        in.num_faces = counts.size();
        in.face_mesh = mesh.data();
        in.face_source = source.data();
        in.face_reflectance = reflectance.data();
        in.face_emission = emission.data();
    }
};

TEST(LightGroups, FlatGroupsSumToTheTotal) {
    CubeInput cube;
    Engine e(cube.in, cube.indices.size());
    e.mesh({0.05, 0.3});
    e.compute_links({"raycast", 4, 128, 4, 1});
    SolveOptions so{"gauss_seidel", 1e-12};
    const FlatSolveResult total = e.solve(so);
    e.set_light_groups({LightGroup{{0}, {}}, LightGroup{{1}, {}}});
    const std::vector<GroupSolution> groups = e.solve_groups(so);
    ASSERT_EQ(groups.size(), 2u);
    const std::vector<RGB> h = e.transport(total.radiosity).irradiance;
    double big = 0, worst = 0, worst_h = 0;
    for (size_t i = 0; i < total.radiosity.size(); ++i) {
        const RGB sum = groups[0].radiosity[i] + groups[1].radiosity[i];
        const RGB hs = groups[0].irradiance[i] + groups[1].irradiance[i];
        for (int c = 0; c < 3; ++c) {
            big = std::max(big, total.radiosity[i][c]);
            worst = std::max(worst, std::abs(sum[c] - total.radiosity[i][c]));
            worst_h = std::max(worst_h, std::abs(hs[c] - h[i][c]));
        }
    }
    EXPECT_GT(big, 1.0);
    EXPECT_LT(worst, 1e-9 * big);
    EXPECT_LT(worst_h, 1e-9 * big);
    // each group lights the room alone: group 0's emitter does not emit in group 1
    const PatchArrays p = e.patch_arrays();
    for (size_t i = 0; i < p.count; ++i)
        if (p.mesh[i] == 0) EXPECT_GT(groups[0].radiosity[i][0], groups[1].radiosity[i][0]);
    // the total solve is unchanged by the groups (the patches' source terms are restored)
    const FlatSolveResult again = e.solve(so);
    EXPECT_EQ(again.radiosity.size(), total.radiosity.size());
    for (size_t i = 0; i < total.radiosity.size(); ++i)
        for (int c = 0; c < 3; ++c) EXPECT_EQ(again.radiosity[i][c], total.radiosity[i][c]);
}

TEST(LightGroups, HierarchicalGroupsSumToTheTotal) {
    CubeInput cube;
    Engine plain(cube.in, cube.indices.size());
    Engine grouped(cube.in, cube.indices.size());
    grouped.set_light_groups({LightGroup{{0}, {}}, LightGroup{{1, 2}, {}}});
    const HierarchyOptions ho{1e-3, 0.01, 4, 1, 4};
    const SolveOptions so{"jacobi", 1e-10};
    const HierarchicalResult a = plain.solve_hierarchical(ho, so);
    const HierarchicalResult b = grouped.solve_hierarchical(ho, so);
    EXPECT_TRUE(a.groups.empty());
    ASSERT_EQ(b.groups.size(), 2u);
    ASSERT_EQ(a.radiosity.size(), b.radiosity.size());
    double big = 0, worst = 0;
    for (size_t i = 0; i < a.radiosity.size(); ++i) {
        EXPECT_EQ(a.radiosity[i][0], b.radiosity[i][0]);  // groups change nothing of the total solve
        const RGB sum = b.groups[0].radiosity[i] + b.groups[1].radiosity[i];
        for (int c = 0; c < 3; ++c) {
            big = std::max(big, a.radiosity[i][c]);
            worst = std::max(worst, std::abs(sum[c] - a.radiosity[i][c]));
        }
    }
    EXPECT_GT(big, 1.0);
    EXPECT_LT(worst, 1e-7 * big);
}

}  // namespace
}  // namespace hirad
