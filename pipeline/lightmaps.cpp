#include "lightmaps.h"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>

#include "patches.h"

namespace hirad {

namespace {

double cross2(const Vec2& a, const Vec2& b) { return a.u * b.v - a.v * b.u; }
Vec2 sub(const Vec2& a, const Vec2& b) { return {a.u - b.u, a.v - b.v}; }

// Barycentric coordinates of p in triangle abc; false when outside (with a small tolerance
// so that texel centres on a shared edge are covered by one side or the other).
bool barycentric(const Vec2& a, const Vec2& b, const Vec2& c, const Vec2& p, double& wb, double& wc) {
    double d = cross2(sub(b, a), sub(c, a));
    if (std::fabs(d) < 1e-20) return false;
    wb = cross2(sub(p, a), sub(c, a)) / d;
    wc = cross2(sub(b, a), sub(p, a)) / d;
    const double eps = -1e-9;
    return wb >= eps && wc >= eps && 1 - wb - wc >= eps;
}

}  // namespace

TexelImage bake_uv(const std::vector<UVPolygon>& polygons, int width, int height, int dilation) {
    TexelImage img;
    img.width = width;
    img.height = height;
    img.rgb.assign(size_t(width) * height * 3, 0.0f);
    img.covered.assign(size_t(width) * height, 0);
    for (const UVPolygon& poly : polygons) {
        double umin = 1e300, umax = -1e300, vmin = 1e300, vmax = -1e300;
        for (int k = 0; k < poly.nv; ++k) {
            umin = std::min(umin, poly.uv[k].u); umax = std::max(umax, poly.uv[k].u);
            vmin = std::min(vmin, poly.uv[k].v); vmax = std::max(vmax, poly.uv[k].v);
        }
        int x0 = std::max(0, static_cast<int>(std::floor(umin * width - 0.5)));
        int x1 = std::min(width - 1, static_cast<int>(std::ceil(umax * width - 0.5)));
        int y0 = std::max(0, static_cast<int>(std::floor((1 - vmax) * height - 0.5)));
        int y1 = std::min(height - 1, static_cast<int>(std::ceil((1 - vmin) * height - 0.5)));
        for (int y = y0; y <= y1; ++y)
            for (int x = x0; x <= x1; ++x) {
                Vec2 p{(x + 0.5) / width, 1 - (y + 0.5) / height};
                RGB value;
                bool inside = false;
                for (int k = 1; k + 1 < poly.nv && !inside; ++k) {
                    double wb, wc;
                    if (!barycentric(poly.uv[0], poly.uv[k], poly.uv[k + 1], p, wb, wc)) continue;
                    inside = true;
                    if (poly.nv == 3) {
                        value = poly.value[0] * (1 - wb - wc) + poly.value[1] * wb + poly.value[2] * wc;
                    } else {
                        // Start Newton from the triangle's estimate of (s, t).
                        double s = k == 1 ? wb + wc : wb, t = k == 1 ? wc : wb + wc;
                        inverse_bilinear(poly.uv, p, s, t);
                        value = poly.value[0] * ((1 - s) * (1 - t)) + poly.value[1] * (s * (1 - t)) +
                                poly.value[2] * (s * t) + poly.value[3] * ((1 - s) * t);
                    }
                }
                if (!inside) continue;
                size_t idx = size_t(y) * width + x;
                img.covered[idx] = 1;
                img.rgb[3 * idx] = static_cast<float>(value.x);
                img.rgb[3 * idx + 1] = static_cast<float>(value.y);
                img.rgb[3 * idx + 2] = static_cast<float>(value.z);
            }
    }
    // Dilation: each ring takes the mean of its already-filled 8-neighbours.
    std::vector<uint8_t> filled = img.covered;
    for (int ring = 0; ring < dilation; ++ring) {
        std::vector<uint8_t> next = filled;
        std::vector<float> rgb = img.rgb;
        bool changed = false;
        for (int y = 0; y < height; ++y)
            for (int x = 0; x < width; ++x) {
                size_t idx = size_t(y) * width + x;
                if (filled[idx]) continue;
                double acc[3] = {0, 0, 0};
                int n = 0;
                for (int dy = -1; dy <= 1; ++dy)
                    for (int dx = -1; dx <= 1; ++dx) {
                        int xx = x + dx, yy = y + dy;
                        if (xx < 0 || yy < 0 || xx >= width || yy >= height) continue;
                        size_t j = size_t(yy) * width + xx;
                        if (!filled[j]) continue;
                        for (int c = 0; c < 3; ++c) acc[c] += img.rgb[3 * j + c];
                        ++n;
                    }
                if (!n) continue;
                for (int c = 0; c < 3; ++c) rgb[3 * idx + c] = static_cast<float>(acc[c] / n);
                next[idx] = 1;
                changed = true;
            }
        filled.swap(next);
        img.rgb.swap(rgb);
        if (!changed) break;
    }
    return img;
}

}  // namespace hirad
