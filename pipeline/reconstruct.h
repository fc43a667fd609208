// Reconstruction of smooth per-vertex values from per-patch values.
// An interior vertex takes the mean of the patches around it. A boundary vertex b is
// extrapolated through its nearest interior neighbour i so that (B_b + B_i) / 2 equals the
// mean of its own adjacent patches, clamped at zero. Vertices are split across creases
// sharper than the crease angle, so a floor does not blur into the wall it meets.
#pragma once
#include <array>
#include <cstdint>
#include <vector>

#include "patches.h"

namespace hirad {

struct DisplayMesh {
    std::vector<Vec3> points;
    std::vector<uint32_t> point_mesh;              // input mesh of each point
    std::vector<std::array<uint32_t, 4>> corners;  // per patch, into points (nv of them used)
    std::vector<uint8_t> boundary;                 // 1 for boundary points
};

// Splits welded patch vertices across creases and marks boundary points.
DisplayMesh build_display_mesh(const PatchSet& patches, double crease_angle_degrees);

// Per-point values from per-patch values by the rules above.
std::vector<RGB> vertex_values(const PatchSet& patches, const DisplayMesh& mesh,
                               const std::vector<RGB>& patch_values);

}  // namespace hirad
