// Preview rendering: primary rays from a pinhole camera onto the patches.
#include "pipeline/outputs/render.h"

#include <gtest/gtest.h>

#include <cmath>
#include <vector>

namespace hirad {
namespace {

// The square [-1, 1]^2 in the plane z = 0, facing +z (or -z when flipped).
std::vector<Patch> square(bool facing_camera) {
    Patch p;
    p.nv = 4;
    if (facing_camera) p.p = {Vec3{-1, -1, 0}, Vec3{1, -1, 0}, Vec3{1, 1, 0}, Vec3{-1, 1, 0}};
    else p.p = {Vec3{-1, -1, 0}, Vec3{-1, 1, 0}, Vec3{1, 1, 0}, Vec3{1, -1, 0}};
    p.normal = {0, 0, facing_camera ? 1.0 : -1.0};
    p.area = 4;
    return {p};
}

// Camera at z = 5 looking down -z, 40 degrees vertical field: the image spans
// +-5 tan(20 deg) = +-1.82 at the square's distance, so its corners see past the square.
Camera camera() {
    Camera c;
    c.position = {0, 0, 5};
    c.forward = {0, 0, -1};
    c.up = {0, 1, 0};
    c.vertical_fov_degrees = 40;
    c.width = 33;  // odd: the centre pixel's ray is the optical axis
    c.height = 33;
    return c;
}

RGB pixel(const std::vector<float>& img, const Camera& c, int x, int y) {
    const float* p = &img[(size_t(y) * c.width + x) * 3];
    return {p[0], p[1], p[2]};
}

TEST(Render, ConstantRadianceQuadFacingTheCamera) {
    std::vector<Patch> patches = square(true);
    Visibility vis(patches);
    const Camera cam = camera();
    CornerValues radiance = {{RGB{2, 2, 2}, RGB{2, 2, 2}, RGB{2, 2, 2}, RGB{2, 2, 2}}};
    std::vector<float> img = render_radiance(patches, vis, radiance, cam, 4);
    ASSERT_EQ(img.size(), size_t(cam.width * cam.height * 3));
    const RGB centre = pixel(img, cam, 16, 16);
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(centre[c], 2.0, 1e-6);
    for (int y : {0, cam.height - 1})
        for (int x : {0, cam.width - 1})
            for (int c = 0; c < 3; ++c) EXPECT_EQ(pixel(img, cam, x, y)[c], 0.0f) << x << "," << y;
}

TEST(Render, BackFaceShowsNothing) {
    std::vector<Patch> patches = square(false);
    Visibility vis(patches);
    const Camera cam = camera();
    CornerValues radiance = {{RGB{2, 2, 2}, RGB{2, 2, 2}, RGB{2, 2, 2}, RGB{2, 2, 2}}};
    std::vector<float> img = render_radiance(patches, vis, radiance, cam, 1);
    for (float v : img) EXPECT_EQ(v, 0.0f);
}

TEST(Render, RadianceIsInterpolatedAtTheHitPointWithRowZeroAtTheTop) {
    // Corner radiance sampled from an affine g(x, y) on the square: bilinear interpolation
    // reproduces g, so a pixel shows g where its ray meets z = 0. With one sample per pixel,
    // pixel (px, py) looks along forward + right * a half_w + up * b half_h with
    // a = (px + 0.5)/w * 2 - 1, b = 1 - (py + 0.5)/h * 2, and meets z = 0 at 5 times that.
    auto g = [](double x, double y) { return RGB{2 + 0.5 * x, 2 + 0.25 * y, 3 - 0.5 * x + 0.5 * y}; };
    std::vector<Patch> patches = square(true);
    Visibility vis(patches);
    const Camera cam = camera();
    std::array<RGB, 4> corners;
    for (int k = 0; k < 4; ++k) corners[k] = g(patches[0].p[k].x, patches[0].p[k].y);
    std::vector<float> img = render_radiance(patches, vis, {corners}, cam, 1);
    const double half_h = std::tan(20.0 * kPi / 180.0), half_w = half_h;
    int checked = 0;
    for (int py = 0; py < cam.height; ++py)
        for (int px = 0; px < cam.width; ++px) {
            const double x = 5 * ((px + 0.5) / cam.width * 2 - 1) * half_w;
            const double y = 5 * (1 - (py + 0.5) / cam.height * 2) * half_h;
            if (std::fabs(x) > 0.98 || std::fabs(y) > 0.98) continue;  // clear of the square's rim
            ++checked;
            const RGB got = pixel(img, cam, px, py), want = g(x, y);
            for (int c = 0; c < 3; ++c) EXPECT_NEAR(got[c], want[c], 1e-4) << px << "," << py;
        }
    EXPECT_GT(checked, 200);
    // Top rows see +y: the green channel is larger at the top than at the bottom.
    EXPECT_GT(pixel(img, cam, 16, 10).y, pixel(img, cam, 16, 22).y);
}

}  // namespace
}  // namespace hirad

namespace hirad {
namespace {

// An image too large to allocate is refused with its numbers, before anything is allocated
// (100000 x 100000 float RGB would be 120 GB); a size that is not positive is an error too.
TEST(Render, ImpossibleSizesAreRefusedWithTheNumbers) {
    std::vector<Patch> patches = square(true);
    Visibility vis(patches);
    CornerValues radiance(1);
    Camera cam = camera();
    cam.width = 100000;
    cam.height = 100000;
    try {
        render_radiance(patches, vis, radiance, cam, 1);
        ADD_FAILURE() << "no error";
    } catch (const std::length_error& e) {
        EXPECT_NE(std::string(e.what()).find("100000 x 100000 = 10000000000 pixels"), std::string::npos) << e.what();
    }
    cam.width = 8192;
    cam.height = 8193;  // one row over the bound
    EXPECT_THROW(render_radiance(patches, vis, radiance, cam, 1), std::length_error);
    cam.width = 0;
    cam.height = 16;
    EXPECT_THROW(render_radiance(patches, vis, radiance, cam, 1), std::invalid_argument);
    cam.width = -3;
    EXPECT_THROW(render_radiance(patches, vis, radiance, cam, 1), std::invalid_argument);
}

}  // namespace
}  // namespace hirad
