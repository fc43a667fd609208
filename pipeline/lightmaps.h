// Texture baking of per-corner values into UV space, with dilation into empty texels so
// bilinear filtering never reads black from outside a chart.
#pragma once
#include <array>
#include <cstdint>
#include <vector>

#include "vecmath.h"

namespace hirad {

struct UVPolygon {
    std::array<Vec2, 4> uv;
    std::array<RGB, 4> value;
    int nv = 4;
};

struct TexelImage {
    int width = 0, height = 0;
    std::vector<float> rgb;         // height*width*3, row 0 at v = 1 (top)
    std::vector<uint8_t> covered;   // 1 where a polygon covers the texel centre
};

// Rasterises each polygon (texel centres inside it take the interpolated value), then fills
// up to `dilation` rings of empty texels from their covered neighbours.
TexelImage bake_uv(const std::vector<UVPolygon>& polygons, int width, int height, int dilation);

}  // namespace hirad
