// The one luminance weighting and the one emission norm (pipeline/core/colour.h), against
// their definitions: BT.709's weights, and sqrt(sum w |E|^2) worked by hand.
#include "pipeline/core/colour.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <vector>

#include "pipeline/core/vecmath.h"

namespace hirad {
namespace {

TEST(Luminance, Bt709Weights) {
    EXPECT_DOUBLE_EQ(luminance(RGB{1, 0, 0}), 0.2126);
    EXPECT_DOUBLE_EQ(luminance(RGB{0, 1, 0}), 0.7152);
    EXPECT_DOUBLE_EQ(luminance(RGB{0, 0, 1}), 0.0722);
    EXPECT_NEAR(luminance(RGB{1, 1, 1}), 1.0, 1e-15);  // white keeps its level
    EXPECT_NEAR(luminance(RGB{-1, 2, -3}), -0.2126 + 2 * 0.7152 - 3 * 0.0722, 1e-15);
    EXPECT_NEAR(luminance_of_magnitude(RGB{-1, 2, -3}), 0.2126 + 2 * 0.7152 + 3 * 0.0722, 1e-15);
}

TEST(EmissionNorm, WeightedSumOfSquaresOrOne) {
    const std::vector<RGB> e = {{1, 2, 2}, {0, 0, 0}, {3, 0, 4}};  // |E|^2 = 9, 0, 25
    const std::vector<double> w = {2, 7, 0.5};
    const double norm = emission_norm(e.size(), [&](size_t k) { return w[k]; }, [&](size_t k) { return e[k]; });
    EXPECT_NEAR(norm, std::sqrt(2 * 9 + 0.5 * 25), 1e-14);
    // A dark scene divides by 1 (its residual is then the absolute one), not by zero.
    const std::vector<RGB> dark(4);
    EXPECT_EQ(emission_norm(dark.size(), [](size_t) { return 1.0; }, [&](size_t k) { return dark[k]; }), 1.0);
    EXPECT_EQ(emission_norm(0, [](size_t) { return 1.0; }, [](size_t) { return RGB{}; }), 1.0);
    EXPECT_EQ(norm_or_one(0.0), 1.0);
    EXPECT_EQ(norm_or_one(std::numeric_limits<double>::quiet_NaN()), 1.0);
    EXPECT_EQ(norm_or_one(16.0), 4.0);
}

}  // namespace
}  // namespace hirad
