// The input faces of a hierarchy, stored compactly, and each face's Patch made from them on
// demand.
//
// A Patch is 328 bytes: four double corners and texture coordinates, its normal, centroid and
// area, its material and light. Held for every input face, it was the largest array of a large
// bake: 201.7 MB of a 615k-triangle floor's 1.2 GB heap, 3.2 GB of the 9.84M-triangle
// building's (bench/README.md, stop 44). Here a face keeps its corners as indices into its
// points (welded where the bits agree: a mesh's shared vertices are stored once), its
// reflectance as an index into the distinct reflectances, its unit normal (the solvers' walks
// read it for every face) and area, its emission and direct light (set again as luminaires
// light it), and its texture coordinates only once a face has non-zero ones: about 124 bytes
// a face of a triangle mesh without texture coordinates. operator[] gives the Patch with its corners,
// coordinates, fields, normal and area as stored and its centroid made again by the table's
// rule (patch_centroid: the same bits as finish_patch): the Patch it was made from.
#pragma once
#include <array>
#include <cstddef>
#include <cstdint>
#include <vector>

#include "pipeline/geometry/patches.h"

namespace hirad {

// Points by mesh and position, -0.0 and +0.0 one position, the first point's bits kept
// (weld_patches' rule): open addressing over indices, about 40 bytes a point.
class MeshPoints {
public:
    std::vector<Vec3> points;
    std::vector<uint32_t> meshes;   // per point
    uint32_t index(uint32_t mesh, const Vec3& p);      // its index, added if new
    int64_t find(uint32_t mesh, const Vec3& p) const;  // its index, -1 if absent
    void seal();                                       // no more points: the table goes
    size_t bytes() const {
        return points.capacity() * sizeof(Vec3) + (meshes.capacity() + slots_.capacity()) * sizeof(uint32_t);
    }

private:
    size_t slot(uint32_t mesh, const Vec3& p) const;
    std::vector<uint32_t> slots_;   // index + 1, 0 empty; at most half full
};

// How corners are shared. Bits: one point for every corner with the same bits, whatever its
// mesh (the hierarchy's faces, a RayScene). ByMesh: one point per mesh and position, with -0.0
// and +0.0 one position, the first corner's bits kept (weld_patches' rule, which the display
// mesh is built on: a solved hierarchy's leaves, Engine::use_leaves_as_patches).
enum class Welding : uint8_t { Bits, ByMesh };

class FaceTable {
public:
    // `centroid`: the rule the patches were finished with (the hierarchy's corner mean; a
    // RayScene's area-weighted), by which a patch's centroid is made again.
    explicit FaceTable(PatchCentroid centroid = PatchCentroid::CornerMean, Welding welding = Welding::Bits)
        : centroid_(centroid), welding_(welding) {}
    FaceTable(FaceTable&&) = default;
    FaceTable& operator=(FaceTable&&) = default;

    // Adds a finished patch (finish_patch with PatchCentroid::CornerMean) as the next face.
    void push_back(const Patch& p);
    void reserve(size_t n);
    // Lets go of the welding index and spare capacity once every face is in.
    void seal();

    size_t size() const { return records_.size(); }
    bool empty() const { return records_.empty(); }

    // Face f as a Patch (see the top of this file).
    Patch operator[](size_t f) const {
        Patch p;
        get(f, p);
        return p;
    }
    void get(size_t f, Patch& p) const;

    int nv(size_t f) const { return records_[f].nv; }
    bool back(size_t f) const { return records_[f].back != 0; }
    uint32_t mesh(size_t f) const { return records_[f].mesh; }
    uint32_t face(size_t f) const { return records_[f].face; }
    const Vec3& corner(size_t f, int k) const { return pts()[records_[f].corner[k]]; }
    // Corner k's index in points(): the faces' shared vertices (an indexed mesh for Embree).
    uint32_t corner_index(size_t f, int k) const { return records_[f].corner[k]; }
    const std::vector<Vec3>& point_list() const { return pts(); }
    Welding welding() const { return welding_; }
    // Welding::ByMesh: the mesh of point v (its corners' faces').
    uint32_t point_mesh(size_t v) const { return by_mesh_.meshes[v]; }
    const Vec3& normal(size_t f) const { return records_[f].normal; }
    // Patch::centroid of face f by the table's rule, without making the patch.
    Vec3 centroid(size_t f) const;
    double area(size_t f) const { return area_[f]; }
    // Patch::point of face f, without making the patch.
    Vec3 point(size_t f, double s, double t) const {
        const Record& r = records_[f];
        const std::vector<Vec3>& q = pts();
        return polygon_point(q[r.corner[0]], q[r.corner[1]], q[r.corner[2]], q[r.corner[3]],
                             r.nv, s, t);
    }
    const RGB& reflectance(size_t f) const { return reflectances_[records_[f].reflectance]; }
    const RGB& emission(size_t f) const { return emission_.empty() ? kNoLight : emission_[f]; }
    const RGB& direct(size_t f) const { return direct_.empty() ? kNoLight : direct_[f]; }
    // What luminaires give face f (Patch::direct) and its source term with it (Patch::emission).
    // (Not from several threads at once: the first light a table holds makes its array.)
    void set_light(size_t f, const RGB& direct, const RGB& emission) {
        light(direct_, f) = direct;
        light(emission_, f) = emission;
    }

    // Bytes held (for reports and tests).
    size_t bytes() const;
    size_t points() const { return pts().size(); }

private:
    struct Record {  // what sampling a face reads, together: its corners' indices and normal
        Vec3 normal;
        uint32_t corner[4];
        uint32_t mesh = 0, face = 0, reflectance = 0;
        uint8_t nv = 0, back = 0;
    };
    std::vector<Record> records_;
    std::vector<Vec3> points_;
    std::vector<double> area_;
    std::vector<RGB> reflectances_;
    // Emission and direct light, each made only once a face has some (all bits zero until
    // then: a ray scene's display faces have neither, 48 bytes a face).
    std::vector<RGB> emission_, direct_;
    static inline const RGB kNoLight{};
    RGB& light(std::vector<RGB>& v, size_t f);
    std::vector<std::array<Vec2, 4>> uv_;   // empty while every face's are zero
    // Welding: open addressing over points_ (and over reflectances_), by the values' bits.
    std::vector<uint32_t> point_slots_, reflectance_slots_;
    MeshPoints by_mesh_;                    // Welding::ByMesh: the points (points_ unused)
    const std::vector<Vec3>& pts() const { return welding_ == Welding::ByMesh ? by_mesh_.points : points_; }
    PatchCentroid centroid_ = PatchCentroid::CornerMean;
    Welding welding_ = Welding::Bits;
    uint32_t point_index(const Vec3& p, uint32_t mesh);
    uint32_t reflectance_index(const RGB& r);
};

}  // namespace hirad
