// The scene as the engine sees it: world-space planar faces (triangles and planar convex
// quads) in metres, each with a diffuse reflectance and an emitted exitance. Built from the
// flat arrays the USD reader produces; geometry it cannot use is counted, never fatal.
#pragma once
#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "pipeline/core/vecmath.h"

namespace hirad {

struct Face {
    std::array<Vec3, 4> p;    // corners, counter-clockwise seen from the front (normal) side
    std::array<Vec2, 4> uv;   // texture coordinates of the corners (zero when the mesh has none)
    int nv = 3;               // 3 or 4
    uint32_t mesh = 0;        // index of the input mesh
    uint32_t source_face = 0; // index of the face within that mesh's authored faces
    RGB reflectance;          // diffuse albedo per channel, in [0, 1)
    RGB emission;             // emitted exitance in W/m^2 (pi x emitted radiance)
    double transmittance = 0; // glazing: normal transmittance tau0 (visibility.h), 0 opaque
    Vec3 normal() const;
    double area() const;
};

// What was dropped while building, reported to the user in one warning.
struct SceneStats {
    uint64_t input_faces = 0;
    uint64_t degenerate_faces = 0;   // zero area, fewer than 3 distinct corners
    uint64_t nonfinite_faces = 0;    // a NaN or infinite corner
    uint64_t self_intersecting_faces = 0;  // polygons whose edges cross (in their plane)
    uint64_t triangulated_faces = 0; // non-quad polygons and non-planar or concave quads
    uint64_t nonmanifold_edges = 0;  // edges shared by more than two faces (kept, only counted)
};

struct SceneInput {
    // Flat polygon soup, already in world space and metres.
    const double* points = nullptr;            // (num_points, 3)
    size_t num_points = 0;
    const int32_t* face_vertex_counts = nullptr;  // (num_faces)
    const int32_t* face_vertex_indices = nullptr; // sum of counts
    size_t num_faces = 0;
    const int32_t* face_mesh = nullptr;        // (num_faces) mesh index
    const int32_t* face_source = nullptr;      // (num_faces) authored face index within its mesh
    const double* face_reflectance = nullptr;  // (num_faces, 3)
    const double* face_emission = nullptr;     // (num_faces, 3) exitance W/m^2
    const double* corner_uv = nullptr;         // (sum of counts, 2) or null
    const double* face_transmittance = nullptr; // (num_faces) glazing's normal transmittance, or null
};

struct Scene {
    std::vector<Face> faces;
    SceneStats stats;
    bool has_uv = false;

    // Splits polygons into triangles and planar convex quads (ear clipping in the polygon's
    // plane, so concave polygons come out right) and drops what has no area or is not finite.
    // Self-intersecting polygons are skipped and counted. Materials are not dropped but refused: a reflectance outside [0, 1] or a negative or
    // non-finite emission on any face throws std::invalid_argument with the number of such
    // faces and the first one (the USD reader reports them by prim before they get here).
    static Scene build(const SceneInput& in);

    // Axis-aligned bounds of all faces.
    void bounds(Vec3& lo, Vec3& hi) const;
};

// Ear-clipping triangulation of a simple polygon (possibly concave) given in 3D; returns
// triples of indices into `poly`. Exposed for tests.
std::vector<std::array<int, 3>> triangulate_polygon(const std::vector<Vec3>& poly);

// Whether two edges of the polygon that share no corner cross, in the plane of its dominant
// axes (touching is not crossing: a weakly simple "keyhole" polygon is still triangulated).
// Scene::build skips such faces and counts them. Exposed for tests.
bool polygon_self_intersects(const std::vector<Vec3>& poly);

}  // namespace hirad
