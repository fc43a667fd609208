// Link estimates: the exact form (Lambert's contour sum at points of one end, visibility rays
// drawn by Arvo's sampling) and the cheap one for far pairs (the point-to-point kernel between
// stratified points of both ends, RefineOptions::far) against the closed form of two parallel
// squares directly opposite (Howell C-11).
#include <gtest/gtest.h>

#include <cmath>
#include <vector>

#include "pipeline/geometry/formfactors.h"
#include "pipeline/geometry/visibility.h"
#include "pipeline/hierarchy/refine.h"
#include "tests/cpp/test_scenes.h"

namespace hirad {
namespace {

// Two side x side squares at z = 0 (facing up) and z = gap (facing down), centred on the z axis.
Scene opposite_squares(double side, double gap) {
    Scene scene;
    const double h = side / 2;
    Face up, down;
    up.nv = down.nv = 4;
    up.p = {Vec3{-h, -h, 0}, Vec3{h, -h, 0}, Vec3{h, h, 0}, Vec3{-h, h, 0}};
    down.p = {Vec3{-h, -h, gap}, Vec3{-h, h, gap}, Vec3{h, h, gap}, Vec3{h, -h, gap}};
    up.reflectance = down.reflectance = test::grey(0.5);
    down.emission = test::grey(1.0);
    scene.faces = {up, down};
    return scene;
}

struct Estimates {
    double mean = 0;  // of the couplings G
    double spread = 0;  // their standard deviation
};

// `streams` independent estimates of G between the two squares' element roots.
Estimates estimate_many(const Scene& scene, double far, int samples, int streams) {
    Hierarchy h(scene);
    Visibility vis(h.faces);
    RefineOptions opt;
    opt.samples = samples;
    opt.far = far;
    Refiner refiner(h, vis, opt);
    double sum = 0, sum2 = 0;
    for (int k = 0; k < streams; ++k) {
        const double g = refiner.estimate(h.face_node[0], h.face_node[1], uint64_t(k)).coupling;
        sum += g;
        sum2 += g * g;
    }
    Estimates e;
    e.mean = sum / streams;
    e.spread = std::sqrt(std::max(0.0, sum2 / streams - e.mean * e.mean));
    return e;
}

// Squares 0.15 m on a side, the nearest that the default `far` takes as far (their diagonal,
// 0.21 m, equal to far x the gap), and 1 m apart.
TEST(RefinerEstimate, AFarPairsCheapFormIsUnbiased) {
    const double side = 0.15, diagonal = side * std::sqrt(2.0);
    for (double gap : {diagonal / RefineOptions{}.far * (1 + 1e-9), 1.0}) {
        const double exact = side * side * parallel_rectangles_form_factor(side, side, gap);
        const Scene scene = opposite_squares(side, gap);
        const int streams = 4000;
        const Estimates cheap = estimate_many(scene, RefineOptions{}.far, 16, streams);
        const Estimates lambert = estimate_many(scene, 0.0, 16, streams);
        // The mean of 4000 estimates is within 4 standard errors of the closed form.
        EXPECT_NEAR(cheap.mean, exact, 4 * cheap.spread / std::sqrt(double(streams)) + 1e-6 * exact) << gap;
        EXPECT_NEAR(lambert.mean, exact, 4 * lambert.spread / std::sqrt(double(streams)) + 1e-6 * exact) << gap;
        // One estimate's spread. Between the squares the kernel cos cos / (pi r^2) = z^2 /
        // (pi r^4) lies within a factor k = (1 + (diagonal / z)^2)^2 (r^2 from z^2 to z^2 +
        // diagonal^2), 4 at the nearest far pair: a sample's weight lies between w_min and
        // k w_min, and their mean G is at least w_min. By Popoviciu's bound one sample spreads
        // by at most (k - 1) G / 2, the mean of n = 16 by (k - 1) G / (2 sqrt n) (stratification
        // only narrows it).
        const double k = std::pow(1 + diagonal * diagonal / (gap * gap), 2);
        EXPECT_LT(cheap.spread, (k - 1) * exact / (2 * std::sqrt(16.0))) << gap;
        EXPECT_GT(cheap.spread, 0.0) << gap;  // (sampled, not the exact form)
    }
}

// The same squares 0.15 m apart: not far (diagonal 0.21 m > 1.0 x 0.15 m), so the exact form is
// used, the same bits whatever `far`; 1 m apart the cheap form takes other samples.
TEST(RefinerEstimate, OnlyFarPairsTakeTheCheapForm) {
    for (double gap : {0.15, 1.0}) {
        const Scene scene = opposite_squares(0.15, gap);
        Hierarchy h(scene);
        Visibility vis(h.faces);
        RefineOptions cheap, exact;
        cheap.far = 1.0;
        exact.far = 0.0;
        const Link a = Refiner(h, vis, cheap).estimate(h.face_node[0], h.face_node[1]);
        const Link b = Refiner(h, vis, exact).estimate(h.face_node[0], h.face_node[1]);
        if (gap < 0.5) {
            EXPECT_EQ(a.coupling, b.coupling);
            EXPECT_EQ(a.unoccluded, b.unoccluded);
        } else {
            EXPECT_NE(a.coupling, b.coupling);
        }
        EXPECT_EQ(a.visibility, 1.0f);  // nothing between them
    }
}

// A far pair half hidden: a 1 m wide opaque wall between the squares covers the half x > 0 of
// the line of sight. Both forms estimate the visible G; their means over many streams agree.
TEST(RefinerEstimate, AFarPairsVisibilityAgreesWithTheExactForm) {
    Scene scene = opposite_squares(0.15, 1.0);
    Face wall;
    wall.nv = 4;
    wall.p = {Vec3{0, -0.5, 0.5}, Vec3{0.5, -0.5, 0.5}, Vec3{0.5, 0.5, 0.5}, Vec3{0, 0.5, 0.5}};
    wall.reflectance = test::grey(0.5);
    scene.faces.push_back(wall);
    const int streams = 2000;
    const Estimates cheap = estimate_many(scene, 1.0, 16, streams);
    const Estimates lambert = estimate_many(scene, 0.0, 16, streams);
    const double se = std::hypot(cheap.spread, lambert.spread) / std::sqrt(double(streams));
    EXPECT_NEAR(cheap.mean, lambert.mean, 4 * se);
    const double open = 0.15 * 0.15 * parallel_rectangles_form_factor(0.15, 0.15, 1.0);
    EXPECT_NEAR(cheap.mean / open, 0.5, 0.05);  // about half: rays from x < 0 to y > 0 pass too
}

}  // namespace
}  // namespace hirad
