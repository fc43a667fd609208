// Meshing: every scene face is cut into a regular grid of patches no larger than the
// configured area and edge length. Patches are the elements the flat method solves for and
// become the leaves of the hierarchy later.
#pragma once
#include <array>
#include <memory>
#include <cstdint>
#include <initializer_list>
#include <vector>

#include "pipeline/geometry/scene.h"

namespace hirad {

struct MeshingOptions {
    double max_area = 0.01;        // m^2
    double max_edge_length = 0.1;  // m
    // The most patches meshing may make: the count is estimated from the faces before
    // anything is built, and a larger one refused with the numbers (a 1e30 coordinate, a
    // wrong metersPerUnit or a tiny max_area would otherwise allocate without end).
    uint64_t max_patches = 50000000;
};

struct Patch {
    std::array<Vec3, 4> p;   // corners, counter-clockwise around `normal`
    std::array<Vec2, 4> uv;  // corner texture coordinates interpolated from the face
    int nv = 4;              // 3 or 4
    Vec3 normal;
    Vec3 centroid;
    double area = 0;
    RGB reflectance;
    RGB emission;            // the source term, W/m^2: self-emitted exitance + rho x direct
    RGB direct;              // luminaires' irradiance, mean over the patch (luminaire.h), W/m^2
    uint32_t mesh = 0;
    uint32_t face = 0;       // index into Scene::faces
    bool back = false;       // the back of a glazed face (Hierarchy::glass): receives from behind it
    std::array<uint32_t, 4> vertex;  // indices into PatchSet::vertices (welded per mesh)

    // Its own emission, without the luminaires' share rho x direct that `emission` holds.
    RGB self_emission() const { return emission - mul(reflectance, direct); }

    // A point on the patch from coordinates in the unit square (quads: bilinear; triangles:
    // the square folded onto the triangle so stratified squares stay stratified).
    Vec3 point(double s, double t) const;
    // The inverse for a point x on the patch (its projection onto the patch's plane, for a
    // point off it): the (s, t) with point(s, t) = x, clamped to the square. `guess` starts
    // the Newton iterations of quads.
    Vec2 coordinates(const Vec3& x, Vec2 guess = {0.5, 0.5}) const;
};

// Patch::point over corners p0..p3 (a triangle's p3 is not read).
inline Vec3 polygon_point(const Vec3& p0, const Vec3& p1, const Vec3& p2, const Vec3& p3, int nv, double s, double t) {
    if (nv == 4)
        return p0 * ((1 - s) * (1 - t)) + p1 * (s * (1 - t)) + p2 * (s * t) + p3 * ((1 - s) * t);
    if (s + t > 1) { s = 1 - s; t = 1 - t; }
    return p0 + (p1 - p0) * s + (p2 - p0) * t;
}

// The four children of a patch at its edge midpoints (and a quad's centre; a triangle's fourth
// child is the middle one), with their texture coordinates; each child is a copy of the patch
// with its own corners (p, uv; area, normal and centroid still to be finished). Hierarchical
// subdivision and the final gather's second bounce cut elements the same way.
void split_in_four(const Patch& s, Patch kids[4]);

// Finishing a patch whose corners (p, uv, nv) are set: its area and unit normal from Newell's
// formula, its centroid, and for a triangle corner 3 = corner 2. Meshing uses the
// area-weighted centroid; the hierarchy the mean of the corners, which its cluster splits
// are median splits of (and which its elements keep, so that every solution keeps its bits).
enum class PatchCentroid { AreaWeighted, CornerMean };
void finish_patch(Patch& patch, PatchCentroid centroid);
// The centroid finish_patch gives a patch whose corners (p, nv) are set.
Vec3 patch_centroid(const Patch& patch, PatchCentroid centroid);

// (s, t) of p in the bilinear quad q: corner 0 at (0, 0), 1 at (1, 0), 2 at (1, 1), 3 at
// (0, 1). Newton iterations from the (s, t) given; clamped to [0, 1].
void inverse_bilinear(const std::array<Vec2, 4>& q, const Vec2& p, double& s, double& t);

struct PatchSet {
    std::vector<Patch> patches;
    std::vector<Vec3> vertices;          // shared corners; a vertex belongs to one mesh
    std::vector<uint32_t> vertex_mesh;   // mesh of each vertex
};

// Interpolates corner values at a patch's parametric point (u, v) as Embree reports it:
// bilinear over quads (u along corner 0-1, v along 0-3), barycentric over triangles.
inline RGB interpolate_corners(int nv, const std::array<RGB, 4>& c, double u, double v) {
    if (nv == 3) return c[0] * (1 - u - v) + c[1] * u + c[2] * v;
    return c[0] * ((1 - u) * (1 - v)) + c[1] * (u * (1 - v)) + c[2] * (u * v) + c[3] * ((1 - u) * v);
}

// A face's four corner values as a finished solution's field keeps them (ray_scene.h and the
// outputs that read it: render, probes, illuminance): float, so that a million display faces'
// radiance and irradiance take 96 MB, not 192. Float's 24 bits (6e-8 relative) are far below
// any solution's own error, and the USD primvars are float too; interpolation is in double.
struct CornerRGB {
    std::array<float, 12> v{};
    CornerRGB() = default;
    CornerRGB(const RGB& a, const RGB& b, const RGB& c, const RGB& d) : CornerRGB(std::array<RGB, 4>{a, b, c, d}) {}
    CornerRGB(const std::array<RGB, 4>& c) {  // NOLINT: implicit, from double corners
        for (int k = 0; k < 4; ++k)
            for (int a = 0; a < 3; ++a) v[3 * k + a] = static_cast<float>(c[k][a]);
    }
    RGB operator[](int k) const { return {v[3 * k], v[3 * k + 1], v[3 * k + 2]}; }
    // Assignable only as a named object: CornerValues' faces are read by value.
    CornerRGB(const CornerRGB&) = default;
    CornerRGB& operator=(const CornerRGB&) & = default;
};
// Per face, its corners' values (CornerRGB): spelled out, 48 bytes a face; or indexed, as a
// display mesh holds them, four point indices a face (shared by a field's radiance and
// irradiance) into float RGB per point: 16 bytes a face and 12 a point, about half. A face's
// CornerRGB is the same floats either way.
class CornerValues {
public:
    CornerValues() = default;
    explicit CornerValues(size_t faces, const CornerRGB& value = {}) : corners_(faces, value) {}  // spelled out
    CornerValues(std::initializer_list<CornerRGB> faces) : corners_(faces) {}  // spelled out
    void push_back(const CornerRGB& c) { corners_.push_back(c); }  // spelled out: one face more
    CornerValues(std::shared_ptr<const std::vector<std::array<uint32_t, 4>>> index,
                 std::vector<std::array<float, 3>> points)
        : index_(std::move(index)), points_(std::move(points)) {}
    size_t size() const { return index_ ? index_->size() : corners_.size(); }
    CornerRGB operator[](size_t i) const {
        if (!index_) return corners_[i];
        CornerRGB c;
        const std::array<uint32_t, 4>& f = (*index_)[i];
        for (int k = 0; k < 4; ++k)
            for (int a = 0; a < 3; ++a) c.v[3 * k + a] = points_[f[k]][a];
        return c;
    }
    CornerRGB& corners(size_t i) { return corners_[i]; }  // spelled out: face i's, to set

private:
    std::vector<CornerRGB> corners_;
    std::shared_ptr<const std::vector<std::array<uint32_t, 4>>> index_;
    std::vector<std::array<float, 3>> points_;
};

inline RGB interpolate_corners(int nv, const CornerRGB& c, double u, double v) {
    return interpolate_corners(nv, std::array<RGB, 4>{c[0], c[1], c[2], c[3]}, u, v);
}

// Throws std::invalid_argument for limits that are not positive finite numbers and
// std::length_error when the patches would be more than options.max_patches.
PatchSet mesh_patches(const Scene& scene, const MeshingOptions& options);

// A lower bound on the patches mesh_patches makes of one face (the grid its edge limit
// asks for, or its area over max_area if more), as a double: it may exceed every integer
// type for a face of absurd size.
double estimate_face_patches(const Face& face, const MeshingOptions& options);

// A patch set over given patches (the leaves of a hierarchy), their corners welded per mesh
// where the points are bit-identical.
PatchSet weld_patches(std::vector<Patch> patches);

}  // namespace hirad
