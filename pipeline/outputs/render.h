// Preview rendering from a stored solution: primary rays through a pinhole camera, exitant
// radiance B/pi interpolated bilinearly from the patch corners at the hit point.
#pragma once
#include <array>
#include <cstdint>
#include <vector>

#include "pipeline/geometry/patches.h"
#include "pipeline/geometry/visibility.h"

namespace hirad {

struct Camera {
    Vec3 position{0, 0, 0};
    Vec3 forward{0, 0, -1};
    Vec3 up{0, 1, 0};
    double vertical_fov_degrees = 40;
    int width = 512, height = 512;
};

// The largest image rendered: 8192 x 8192 pixels (805 MB of float RGB). A larger one is
// refused with the numbers before anything is allocated.
constexpr uint64_t kMaxRenderPixels = uint64_t(8192) * 8192;

// The pinhole camera's ray direction (not normalised) through the image-plane point (x, y),
// in pixels from the image's top-left corner (x to the right, y down): pixel (i, j)'s centre is
// (i + 1/2, j + 1/2). The one camera model of every render (the preview, the lightmap view).
Vec3 camera_direction(const Camera& camera, double x, double y);

// Returns height*width*3 floats, row 0 at the top. Pixels that see nothing are zero.
// `samples` per pixel on a stratified grid (rounded down to a square). Throws
// std::invalid_argument for a size that is not positive, std::length_error for one above
// kMaxRenderPixels.
std::vector<float> render_radiance(const PatchView& patches, const Visibility& visibility,
                                   const CornerValues& corner_radiance,
                                   const Camera& camera, int samples);

}  // namespace hirad
