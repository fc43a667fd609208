// Preview rendering from a stored solution: primary rays through a pinhole camera, exitant
// radiance B/pi interpolated bilinearly from the patch corners at the hit point.
#pragma once
#include <array>
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

// Returns height*width*3 floats, row 0 at the top. Pixels that see nothing are zero.
// `samples` per pixel on a stratified grid (rounded down to a square).
std::vector<float> render_radiance(const std::vector<Patch>& patches, const Visibility& visibility,
                                   const std::vector<std::array<RGB, 4>>& corner_radiance,
                                   const Camera& camera, int samples);

}  // namespace hirad
