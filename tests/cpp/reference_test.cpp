// The Monte Carlo reference (pipeline/reference/reference.h) in the furnace: a closed box
// whose every surface emits E and reflects rho has exitant radiance L = E / (pi (1 - rho))
// everywhere, and the estimate must be within a few of its own standard errors of it.
#include "pipeline/reference/reference.h"

#include <gtest/gtest.h>

#include <cmath>
#include <vector>

#include "tests/cpp/test_scenes.h"
namespace hirad {
namespace {

TEST(Reference, FurnaceRadianceIsEOverPiOneMinusRhoWithinItsStandardError) {
    const RGB rho{0.5, 0.7, 0.0};
    const RGB E{1.0, 0.5, 2.0};
    const std::vector<Patch> patches = test::unit_cube_patches(2, rho, E);
    Visibility vis(patches);
    std::vector<uint32_t> at;
    std::vector<Vec2> st;
    for (uint32_t i = 0; i < patches.size(); i += 3) {
        at.push_back(i);
        st.push_back({0.3 + 0.01 * i, 0.6});
    }
    ReferenceOptions opt;
    opt.paths = 8192;
    opt.seed = 5;
    const std::vector<ReferenceEstimate> est = reference_radiance(patches, vis, at, st, opt);
    ASSERT_EQ(est.size(), at.size());
    for (int c = 0; c < 3; ++c) {  // the points pooled: their mean has a smaller error bar
        const double want = E[c] / (kPi * (1 - rho[c]));
        double mean = 0, var = 0;
        for (const ReferenceEstimate& e : est) {
            mean += e.radiance[c] / est.size();
            var += e.standard_error[c] * e.standard_error[c] / (double(est.size()) * est.size());
        }
        EXPECT_LE(std::fabs(mean - want), 4 * std::sqrt(var) + 1e-12 * want) << "channel " << c;
    }
    for (size_t q = 0; q < est.size(); ++q) {
        for (int c = 0; c < 3; ++c) {
            SCOPED_TRACE(testing::Message() << "point " << q << " channel " << c);
            const double want = E[c] / (kPi * (1 - rho[c]));
            const double se = est[q].standard_error[c];
            // The error bar is honest and useful: within 4 standard errors, and small enough
            // that an estimate missing the interreflection (E / pi, off by a factor 1 - rho)
            // could not pass.
            EXPECT_LE(std::fabs(est[q].radiance[c] - want), 4 * se + 1e-12 * want);
            EXPECT_LT(se, 0.05 * want);
            if (rho[c] == 0) {
                EXPECT_NEAR(est[q].radiance[c], want, 1e-12 * want);  // no reflection: exactly E / pi
                EXPECT_LT(se, 1e-9 * want);
            }
        }
    }
}

TEST(Reference, DarkBoxIsBlackAndBadArgumentsAreRefused) {
    const std::vector<Patch> patches = test::unit_cube_patches(1, test::grey(0.5));
    Visibility vis(patches);
    const std::vector<ReferenceEstimate> est = reference_radiance(patches, vis, {0, 3}, {{0.5, 0.5}, {0.2, 0.2}}, {});
    for (const ReferenceEstimate& e : est) EXPECT_EQ(e.radiance.y, 0.0);
    EXPECT_THROW(reference_radiance(patches, vis, {0}, {}, {}), std::invalid_argument);
}

}  // namespace
}  // namespace hirad
