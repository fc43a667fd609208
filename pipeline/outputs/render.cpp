#include "pipeline/outputs/render.h"

#include <tbb/parallel_for.h>

#include <cmath>
#include <stdexcept>
#include <string>

namespace hirad {

Vec3 camera_direction(const Camera& cam, double x, double y) {
    const Vec3 forward = normalize(cam.forward);
    const Vec3 right = normalize(cross(forward, cam.up));
    const Vec3 up = cross(right, forward);
    const double half_h = std::tan(cam.vertical_fov_degrees * kPi / 360.0);
    const double half_w = half_h * double(cam.width) / cam.height;
    const double px = x / cam.width * 2 - 1;
    const double py = 1 - y / cam.height * 2;
    return forward + right * (px * half_w) + up * (py * half_h);
}

std::vector<float> render_radiance(const PatchView& patches, const Visibility& visibility,
                                   const CornerValues& corner_radiance, const Camera& cam,
                                   int samples) {
    const int w = cam.width, h = cam.height;
    if (w <= 0 || h <= 0)
        throw std::invalid_argument("render: image size " + std::to_string(w) + " x " + std::to_string(h) +
                                    " pixels: width and height must be positive");
    if (uint64_t(w) * uint64_t(h) > kMaxRenderPixels)
        throw std::length_error("render: image size " + std::to_string(w) + " x " + std::to_string(h) + " = " +
                                std::to_string(uint64_t(w) * uint64_t(h)) + " pixels, more than the " +
                                std::to_string(kMaxRenderPixels) + " (8192 x 8192) an image may have");
    std::vector<float> image(size_t(w) * h * 3, 0.0f);
    const int g = std::max(1, static_cast<int>(std::sqrt(double(std::max(samples, 1)))));
    tbb::parallel_for(0, h, [&](int y) {
        std::vector<RayHit> panes;
        for (int x = 0; x < w; ++x) {
            RGB sum;
            for (int sy = 0; sy < g; ++sy)
                for (int sx = 0; sx < g; ++sx) {
                    const Vec3 dir = camera_direction(cam, x + (sx + 0.5) / g, y + (sy + 0.5) / g);
                    // through clear glass; back faces emit nothing
                    double pass = 1;
                    const RayHit hit = visibility.intersect_through_glass(cam.position, normalize(dir), 0, 1e30,
                                                                          &panes, &pass);
                    sum += seen_through_glass(visibility, patches, dir, panes, hit, pass, [&](const RayHit& at) {
                        return interpolate_corners(patches.nv(size_t(at.patch)), corner_radiance[at.patch], at.u, at.v);
                    });
                }
            sum = sum / double(g * g);
            float* px = &image[(size_t(y) * w + x) * 3];
            px[0] = static_cast<float>(sum.x);
            px[1] = static_cast<float>(sum.y);
            px[2] = static_cast<float>(sum.z);
        }
    });
    return image;
}

}  // namespace hirad
