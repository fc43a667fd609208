// Reconstruction of smooth per-vertex values from per-patch values, on a display mesh
// without cracks.
//
// An interior vertex takes the mean of the patches around it. A boundary vertex b is
// extrapolated through its nearest interior neighbour i so that (B_b + B_i) / 2 equals the
// mean of its own adjacent patches, clamped at zero. Vertices are split across creases
// sharper than the crease angle, so a floor does not blur into the wall it meets.
//
// Where a patch's edge has a vertex of finer neighbours at its midpoint (a T-vertex: the
// leaves of a hierarchy after 2:1 balancing), the patch is fanned into triangles around its
// centre so that every edge is shared by exactly two faces, and the T-vertex is anchored: it
// takes the value the coarse edge interpolates there, so values are continuous too.
#pragma once
#include <array>
#include <cstdint>
#include <utility>
#include <vector>

#include "pipeline/geometry/face_table.h"
#include "pipeline/geometry/patches.h"

namespace hirad {

// How a display face corner sits on its patch: 0-3 the patch's corner k, 4-7 the midpoint of
// the patch's edge k -> k+1, 8 the patch's centre.
enum : uint8_t { kCorner0 = 0, kEdgeMid0 = 4, kCentre = 8 };

struct DisplayMesh {
    std::vector<Vec3> points;
    std::vector<uint32_t> point_mesh;              // input mesh of each point
    std::vector<uint8_t> boundary;                 // 1 for boundary points
    std::vector<std::array<uint32_t, 4>> corners;  // per patch, its corner points (nv of them used)
    // Display faces: the patches themselves, or fans of triangles where a patch has T-vertices.
    std::vector<std::array<uint32_t, 4>> faces;
    std::vector<uint8_t> face_nv;
    std::vector<uint32_t> face_patch;
    std::vector<std::array<uint8_t, 4>> face_code;  // per face corner, see the enum above
    // Anchored points (T-vertices, fan centres) take a weighted sum of other points' values.
    std::vector<std::vector<std::pair<uint32_t, double>>> anchors;
};

// Splits welded patch vertices across creases, marks boundary points and fans patches with
// T-vertices. The same from a FaceTable welded by mesh (Welding::ByMesh: a solved hierarchy's
// leaves), with the same points, corners and faces as from the PatchSet weld_patches makes of
// the same patches.
DisplayMesh build_display_mesh(const PatchSet& patches, double crease_angle_degrees);
DisplayMesh build_display_mesh(const FaceTable& patches, double crease_angle_degrees);

// Per-point values from per-patch values by the rules above.
std::vector<RGB> vertex_values(const PatchSet& patches, const DisplayMesh& mesh,
                               const std::vector<RGB>& patch_values);
std::vector<RGB> vertex_values(const FaceTable& patches, const DisplayMesh& mesh,
                               const std::vector<RGB>& patch_values);

}  // namespace hirad
