// bake_uv: rasterising per-corner values into UV space, and dilation into empty texels.
#include "lightmaps.h"

#include <gtest/gtest.h>

#include <cmath>
#include <vector>

namespace hirad {
namespace {

constexpr int W = 16, H = 16;

// Texel centre (x, y) in uv: row 0 is the top (v = 1).
Vec2 centre(int x, int y) { return {(x + 0.5) / W, 1 - (y + 0.5) / H}; }
RGB texel(const TexelImage& img, int x, int y) {
    const float* p = &img.rgb[3 * (size_t(y) * img.width + x)];
    return {p[0], p[1], p[2]};
}

// The left half of the image, u in [0, 0.5], with corner values c0..c3 at uv (0,0),
// (0.5,0), (0.5,1), (0,1).
UVPolygon left_half() {
    UVPolygon q;
    q.nv = 4;
    q.uv = {Vec2{0, 0}, Vec2{0.5, 0}, Vec2{0.5, 1}, Vec2{0, 1}};
    q.value = {RGB{1, 2, 3}, RGB{5, 1, 0.5}, RGB{2, 7, 1}, RGB{4, 4, 4}};
    return q;
}

TEST(BakeUV, QuadGivesBilinearValuesAtTexelCentres) {
    const UVPolygon q = left_half();
    TexelImage img = bake_uv({q}, W, H, 0);
    ASSERT_EQ(img.width, W);
    ASSERT_EQ(img.height, H);
    ASSERT_EQ(img.rgb.size(), size_t(W * H * 3));
    ASSERT_EQ(img.covered.size(), size_t(W * H));
    for (int y = 0; y < H; ++y)
        for (int x = 0; x < W; ++x) {
            const Vec2 c = centre(x, y);
            // Texel centres u = (x + 0.5)/16 are inside u < 0.5 exactly for x < 8.
            const bool in = x < 8;
            EXPECT_EQ(img.covered[size_t(y) * W + x], in ? 1 : 0) << x << "," << y;
            RGB want;
            if (in) {
                const double s = c.u / 0.5, t = c.v;  // the quad is axis-aligned: s, t are affine in uv
                want = q.value[0] * ((1 - s) * (1 - t)) + q.value[1] * (s * (1 - t)) + q.value[2] * (s * t) +
                       q.value[3] * ((1 - s) * t);
            }
            const RGB got = texel(img, x, y);
            for (int k = 0; k < 3; ++k) EXPECT_NEAR(got[k], want[k], 1e-6) << x << "," << y << " channel " << k;
        }
}

TEST(BakeUV, GeneralQuadInvertsItsBilinearMap) {
    // A non-parallelogram quad. Corner values sampled from an affine function g of uv: the
    // bilinear interpolation of an affine function's corner values is that function at the
    // interpolated point, so every covered texel must hold g at its centre -- whatever (s, t)
    // the inverse map finds, as long as it maps back onto the texel centre.
    auto g = [](const Vec2& p) { return RGB{1 + 2 * p.u + 3 * p.v, 5 - p.u, 0.5 + p.v}; };
    UVPolygon q;
    q.nv = 4;
    q.uv = {Vec2{0.1, 0.05}, Vec2{0.9, 0.2}, Vec2{0.7, 0.95}, Vec2{0.2, 0.6}};
    for (int k = 0; k < 4; ++k) q.value[k] = g(q.uv[k]);
    TexelImage img = bake_uv({q}, W, H, 0);
    int covered = 0;
    for (int y = 0; y < H; ++y)
        for (int x = 0; x < W; ++x) {
            // The quad is convex and counter-clockwise: inside = left of all four edges.
            const Vec2 c = centre(x, y);
            double margin = 1e300;
            for (int k = 0; k < 4; ++k) {
                const Vec2 a = q.uv[k], b = q.uv[(k + 1) % 4];
                margin = std::min(margin, (b.u - a.u) * (c.v - a.v) - (b.v - a.v) * (c.u - a.u));
            }
            ASSERT_GT(std::fabs(margin), 1e-9) << "a texel centre on an edge: choose other corners";
            EXPECT_EQ(img.covered[size_t(y) * W + x], margin > 0 ? 1 : 0) << x << "," << y;
            if (!img.covered[size_t(y) * W + x]) continue;
            ++covered;
            const RGB got = texel(img, x, y), want = g(c);
            for (int k = 0; k < 3; ++k) EXPECT_NEAR(got[k], want[k], 2e-6) << x << "," << y;
        }
    EXPECT_GT(covered, 80);  // shoelace area 0.435 of 256 texels: about 111
}

TEST(BakeUV, TriangleInterpolatesBarycentrically) {
    // Triangle (0.5, 0), (1, 0), (1, 1). Its hypotenuse u = 0.5 + v/2 passes through no texel
    // centre: with u = (x + 0.5)/16 and v = (15.5 - y)/16, a centre is inside exactly when
    // 2x + y >= 31.
    UVPolygon t;
    t.nv = 3;
    t.uv = {Vec2{0.5, 0}, Vec2{1, 0}, Vec2{1, 1}};
    t.value = {RGB{1, 0, 0}, RGB{0, 1, 0}, RGB{0, 0, 1}};
    TexelImage img = bake_uv({t}, W, H, 0);
    for (int y = 0; y < H; ++y)
        for (int x = 0; x < W; ++x) {
            const bool in = 2 * x + y >= 31;
            EXPECT_EQ(img.covered[size_t(y) * W + x], in ? 1 : 0) << x << "," << y;
            if (!in) continue;
            // Barycentric weights by hand: p = a + w1 (b - a) + w2 (c - a) with b - a = (0.5, 0),
            // c - a = (0.5, 1): w2 = v, w1 = (u - 0.5)/0.5 - v.
            const Vec2 c = centre(x, y);
            const double w2 = c.v, w1 = (c.u - 0.5) / 0.5 - c.v, w0 = 1 - w1 - w2;
            const RGB got = texel(img, x, y);
            EXPECT_NEAR(got.x, w0, 1e-6);
            EXPECT_NEAR(got.y, w1, 1e-6);
            EXPECT_NEAR(got.z, w2, 1e-6);
        }
}

TEST(BakeUV, DilationFillsThatManyRings) {
    const UVPolygon q = left_half();
    for (int d : {1, 3}) {
        SCOPED_TRACE(d);
        TexelImage base = bake_uv({q}, W, H, 0);
        TexelImage img = bake_uv({q}, W, H, d);
        // Coverage is what the polygons cover, dilation or not.
        EXPECT_EQ(img.covered, base.covered);
        for (int y = 0; y < H; ++y)
            for (int x = 0; x < W; ++x) {
                const RGB got = texel(img, x, y);
                if (x < 8) {
                    for (int k = 0; k < 3; ++k) EXPECT_EQ(got[k], texel(base, x, y)[k]);
                } else if (x < 8 + d) {
                    // Filled: every corner value is positive, so is every mean of them.
                    EXPECT_GT(got.x, 0) << x << "," << y;
                    EXPECT_GT(got.z, 0) << x << "," << y;
                } else {
                    EXPECT_EQ(got.x, 0) << x << "," << y;
                    EXPECT_EQ(got.y, 0) << x << "," << y;
                    EXPECT_EQ(got.z, 0) << x << "," << y;
                }
            }
        // The first ring takes the mean of its filled 8-neighbours: column 7 at rows y-1, y,
        // y+1. Along a column the bilinear value is linear in v, so away from the top and
        // bottom rows that mean is column 7's own value at row y.
        for (int y = 1; y < H - 1; ++y)
            for (int k = 0; k < 3; ++k) EXPECT_NEAR(texel(img, 8, y)[k], texel(base, 7, y)[k], 1e-5) << y;
        // In the corner rows only two neighbours exist.
        for (int k = 0; k < 3; ++k)
            EXPECT_NEAR(texel(img, 8, 0)[k], 0.5 * (texel(base, 7, 0)[k] + texel(base, 7, 1)[k]), 1e-5);
    }
}

TEST(BakeUV, NoPolygonsGiveAnEmptyImage) {
    TexelImage img = bake_uv({}, 4, 3, 2);
    EXPECT_EQ(img.rgb, std::vector<float>(4 * 3 * 3, 0.0f));
    EXPECT_EQ(img.covered, std::vector<uint8_t>(4 * 3, 0));
}

}  // namespace
}  // namespace hirad
