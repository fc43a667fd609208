#include "pipeline/geometry/hemicube.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <thread>
#include <vector>

namespace hirad {
namespace {

// Howell's catalogue: C-11 for two parallel directly opposite squares, C-14 for two
// perpendicular squares sharing an edge.
constexpr double kParallelUnitSquares = 0.199825;    // C-11, a = b = 1, c = 1
constexpr double kParallelHalfDistance = 0.415253;   // C-11, a = b = 1, c = 0.5
constexpr double kPerpendicularUnitSquares = 0.200044;  // C-14, l = h = w = 1
constexpr uint32_t kNoPatch = std::numeric_limits<uint32_t>::max();

// Corners counter-clockwise around the intended normal; normal, area and centroid are
// derived as the mesher does.
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
    double total = 0;
    for (int k = 1; k + 1 < patch.nv; ++k) {
        double a = 0.5 * length(cross(patch.p[k] - patch.p[0], patch.p[k + 1] - patch.p[0]));
        c += (patch.p[0] + patch.p[k] + patch.p[k + 1]) * (a / 3);
        total += a;
    }
    patch.centroid = c / total;
    return patch;
}

// Axis-aligned rectangle [x0, x1] x [y0, y1] at height z, facing up or down.
Patch horizontal(double x0, double x1, double y0, double y1, double z, bool up) {
    if (up) return make_patch({{x0, y0, z}, {x1, y0, z}, {x1, y1, z}, {x0, y1, z}});
    return make_patch({{x0, y0, z}, {x0, y1, z}, {x1, y1, z}, {x1, y0, z}});
}

// The six faces of the unit cube, all facing inward: bottom, top, x=0, x=1, y=0, y=1.
std::vector<Patch> inward_cube() {
    return {
        horizontal(0, 1, 0, 1, 0, true),
        horizontal(0, 1, 0, 1, 1, false),
        make_patch({{0, 0, 0}, {0, 1, 0}, {0, 1, 1}, {0, 0, 1}}),
        make_patch({{1, 0, 0}, {1, 0, 1}, {1, 1, 1}, {1, 1, 0}}),
        make_patch({{0, 0, 0}, {0, 0, 1}, {1, 0, 1}, {1, 0, 0}}),
        make_patch({{0, 1, 0}, {1, 1, 0}, {1, 1, 1}, {0, 1, 1}}),
    };
}

double lookup(const std::vector<std::pair<uint32_t, double>>& row, uint32_t j) {
    for (const auto& [k, f] : row)
        if (k == j) return f;
    return 0;
}

double row_sum(const std::vector<std::pair<uint32_t, double>>& row) {
    double s = 0;
    for (const auto& e : row) s += e.second;
    return s;
}

// The midpoint-rule sum of all delta form factors, computed independently of the engine.
double discrete_delta_sum(int res) {
    const double cell = 2.0 / res;
    double s = 0;
    for (int r = 0; r < res; ++r)
        for (int c = 0; c < res; ++c) {
            double x = -1 + (c + 0.5) * cell, y = -1 + (r + 0.5) * cell, q = x * x + y * y + 1;
            s += cell * cell / (kPi * q * q);
        }
    for (int r = 0; r < res / 2; ++r)
        for (int c = 0; c < res; ++c) {
            double x = -1 + (c + 0.5) * cell, z = (r + 0.5) * cell, q = x * x + z * z + 1;
            s += 4 * z * cell * cell / (kPi * q * q);
        }
    return s;
}

TEST(Hemicube, DeltaFormFactorsSumToOne) {
    EXPECT_NEAR(discrete_delta_sum(64), 1.0, 1e-3);
    // Inside a closed box every cell is owned by exactly one patch, so the hemicube returns
    // the full sum: a gap or a doubly counted cell in the rasteriser would show here. A tilted
    // normal makes the cube edges cross the faces diagonally.
    std::vector<Patch> cube = inward_cube();
    Hemicube hc(cube, {64, 1});
    for (Vec3 n : {Vec3{0, 0, 1}, normalize(Vec3{0.3, -0.5, 0.8}), normalize(Vec3{-1, 2, -0.2})}) {
        std::vector<double> accum(cube.size(), 0.0);
        hc.accumulate({0.4, 0.55, 0.5}, n, kNoPatch, 1.0, accum);
        double sum = 0;
        for (double f : accum) sum += f;
        EXPECT_NEAR(sum, discrete_delta_sum(64), 1e-9);
    }
}

TEST(Hemicube, ClosedCubeRowsSumToOne) {
    std::vector<Patch> cube = inward_cube();
    Hemicube hc(cube, {64, 16});
    std::vector<std::pair<uint32_t, double>> row;
    for (uint32_t i = 0; i < cube.size(); ++i) {
        hc.row(i, row);
        EXPECT_NEAR(row_sum(row), 1.0, 0.01) << "face " << i;
        EXPECT_EQ(lookup(row, i), 0.0) << "a patch must not see itself";
    }
    // Bottom face: the opposite face and the four walls take the closed-form shares.
    hc.row(0, row);
    EXPECT_NEAR(lookup(row, 1), kParallelUnitSquares, 0.02 * kParallelUnitSquares);
    for (uint32_t j = 2; j < 6; ++j) EXPECT_NEAR(lookup(row, j), kPerpendicularUnitSquares, 0.02 * kPerpendicularUnitSquares);
}

TEST(Hemicube, ParallelSquaresMatchHowellC11) {
    std::vector<Patch> patches = {horizontal(0, 1, 0, 1, 0, true), horizontal(0, 1, 0, 1, 1, false)};
    std::vector<std::pair<uint32_t, double>> row;
    Hemicube(patches, {256, 16}).row(0, row);
    ASSERT_EQ(row.size(), 1u);
    EXPECT_EQ(row[0].first, 1u);
    EXPECT_NEAR(row[0].second, kParallelUnitSquares, 0.01 * kParallelUnitSquares);

    // One hemicube at the centre measures the differential form factor there (0.2394),
    // where the far square subtends the most: about 20 % above the area form factor.
    Hemicube(patches, {256, 1}).row(0, row);
    ASSERT_EQ(row.size(), 1u);
    EXPECT_GT(row[0].second, 0.23);
}

TEST(Hemicube, PerpendicularSquaresMatchHowellC14) {
    // Floor [0,1]^2 facing up and the wall x = 0 facing +x, sharing the edge along y.
    std::vector<Patch> patches = {horizontal(0, 1, 0, 1, 0, true),
                                  make_patch({{0, 0, 0}, {0, 1, 0}, {0, 1, 1}, {0, 0, 1}})};
    ASSERT_NEAR(patches[1].normal.x, 1.0, 1e-12);
    std::vector<std::pair<uint32_t, double>> row;
    Hemicube hc(patches, {256, 16});
    hc.row(0, row);
    EXPECT_NEAR(lookup(row, 1), kPerpendicularUnitSquares, 0.01 * kPerpendicularUnitSquares);
    hc.row(1, row);  // symmetric configuration: same value from the wall
    EXPECT_NEAR(lookup(row, 0), kPerpendicularUnitSquares, 0.01 * kPerpendicularUnitSquares);
}

TEST(Hemicube, BlockerHidesFarSquare) {
    std::vector<Patch> patches = {horizontal(0, 1, 0, 1, 0, true), horizontal(0, 1, 0, 1, 1, false),
                                  horizontal(0, 1, 0, 1, 0.5, false)};
    // The blocker is twice as close, so the differential form factor varies more over the
    // receiver than for C-11 at distance 1: 16 points leave +1.8 %, 64 points +0.4 %.
    std::vector<std::pair<uint32_t, double>> row;
    Hemicube(patches, {256, 64}).row(0, row);
    EXPECT_LT(lookup(row, 1), 1e-4);
    EXPECT_NEAR(lookup(row, 2), kParallelHalfDistance, 0.02 * kParallelHalfDistance);
}

TEST(Hemicube, BackFacingPatchIsInvisible) {
    // The far square faces away from the receiver: it emits nothing towards it.
    std::vector<Patch> patches = {horizontal(0, 1, 0, 1, 0, true), horizontal(0, 1, 0, 1, 1, true)};
    std::vector<std::pair<uint32_t, double>> row;
    Hemicube(patches, {64, 4}).row(0, row);
    EXPECT_TRUE(row.empty());
}

TEST(Hemicube, PatchBelowTangentPlaneIsInvisible) {
    // Faces the receiver's plane from below: in front of it, but behind the receiver.
    std::vector<Patch> patches = {horizontal(0, 1, 0, 1, 0, true), horizontal(0, 1, 0, 1, -1, true)};
    std::vector<std::pair<uint32_t, double>> row;
    Hemicube(patches, {64, 4}).row(0, row);
    EXPECT_TRUE(row.empty());
}

TEST(Hemicube, TrianglesCoverTheirQuad) {
    // The far square split along its diagonal: the two triangles share out the quad's cells.
    std::vector<Patch> quad = {horizontal(0, 1, 0, 1, 0, true), horizontal(0, 1, 0, 1, 1, false)};
    std::vector<Patch> tris = {quad[0], make_patch({{0, 0, 1}, {0, 1, 1}, {1, 1, 1}}),
                               make_patch({{0, 0, 1}, {1, 1, 1}, {1, 0, 1}})};
    ASSERT_NEAR(tris[1].normal.z, -1.0, 1e-12);
    ASSERT_NEAR(tris[2].normal.z, -1.0, 1e-12);
    std::vector<std::pair<uint32_t, double>> a, b;
    Hemicube(quad, {128, 4}).row(0, a);
    Hemicube(tris, {128, 4}).row(0, b);
    ASSERT_EQ(b.size(), 2u);
    // Mirror-image halves; cell centres exactly on the shared diagonal tie in depth and go
    // to whichever triangle was drawn first, hence the tolerance.
    EXPECT_NEAR(b[0].second, b[1].second, 0.02 * b[0].second);
    EXPECT_NEAR(b[0].second + b[1].second, lookup(a, 1), 1e-9);
}

TEST(Hemicube, Reciprocity) {
    // A 1 x 1 square and a 2 x 1 rectangle at distance 1, offset by half a metre.
    std::vector<Patch> patches = {horizontal(0, 1, 0, 1, 0, true), horizontal(0.5, 2.5, 0, 1, 1, false)};
    Hemicube hc(patches, {256, 16});
    std::vector<std::pair<uint32_t, double>> row;
    hc.row(0, row);
    const double g01 = patches[0].area * lookup(row, 1);
    hc.row(1, row);
    const double g10 = patches[1].area * lookup(row, 0);
    ASSERT_GT(g01, 0.05);
    EXPECT_NEAR(g01, g10, 0.02 * g01);
}

TEST(Hemicube, ConcurrentRowsMatchSerial) {
    // Rows are computed from TBB workers on one shared Hemicube; per-thread buffers must not
    // leak between calls or threads.
    std::vector<Patch> cube = inward_cube();
    cube.push_back(horizontal(0.25, 0.75, 0.25, 0.75, 0.5, false));
    Hemicube hc(cube, {64, 4});
    std::vector<std::vector<std::pair<uint32_t, double>>> serial(cube.size()), parallel(cube.size());
    for (uint32_t i = 0; i < cube.size(); ++i) hc.row(i, serial[i]);
    std::vector<std::thread> threads;
    for (uint32_t i = 0; i < cube.size(); ++i) threads.emplace_back([&, i] { hc.row(i, parallel[i]); });
    for (auto& t : threads) t.join();
    EXPECT_EQ(serial, parallel);
}

TEST(Hemicube, RejectsOddResolution) {
    std::vector<Patch> patches = {horizontal(0, 1, 0, 1, 0, true)};
    EXPECT_THROW(Hemicube(patches, {63, 4}), std::invalid_argument);
}

}  // namespace
}  // namespace hirad
