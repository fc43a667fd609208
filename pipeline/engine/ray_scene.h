// A solved surface as one ray-tracing scene: the patches (corners and corner count) in one
// Embree BVH, built once, with optional exitant radiance and irradiance at every patch
// corner. Everything that traces rays against a finished solution queries it:
//   render          pinhole camera, radiance interpolated at the first hit (render.h)
//   probe           the closest surface point to each query point and its values
//   lift_samples    lightmap sample points lifted off their surface and out of geometry
//   volume_probes   full-sphere radiance moments at points in empty space (volume.h)
//   ray_cast        first hits of arbitrary rays
//   illuminance     a calculation grid's sensors: exact direct light plus gathered indirect
//                   light at points anywhere, facing any way (illuminance.h)
// Units: metres; radiance W/(m^2 sr), irradiance W/m^2.
#pragma once
#include <array>
#include <cstdint>
#include <memory>
#include <vector>

#include "pipeline/geometry/luminaire.h"
#include "pipeline/geometry/patches.h"
#include "pipeline/geometry/visibility.h"
#include "pipeline/outputs/illuminance.h"
#include "pipeline/outputs/render.h"
#include "pipeline/outputs/volume.h"

namespace hirad {

struct ProbeResult {
    std::vector<int32_t> patch;       // closest patch (-1: none within max_distance)
    std::vector<double> distance;     // to it, m (-1 when none)
    std::vector<RGB> irradiance;      // interpolated at the closest point, W/m^2
    std::vector<RGB> radiance;        // W/(m^2 sr)
};

struct RayCastResult {
    std::vector<int32_t> patch;       // first patch hit (-1: the ray escapes)
    std::vector<double> t;            // distance along the normalised direction (-1: none)
    std::vector<Vec3> points;         // hit points
    std::vector<Vec3> normals;        // the hit patch's normal
    std::vector<uint8_t> back;        // 1 when the ray hit the patch's back face
    std::vector<double> u, v;         // the hit's coordinates on its patch (interpolate_corners)
};

// First hits of rays against `patches` and their BVH (RayScene and Engine::ray_cast).
RayCastResult cast_rays(const PatchView& patches, const Visibility& visibility,
                        const std::vector<Vec3>& origins, const std::vector<Vec3>& directions);

struct LiftResult {
    std::vector<Vec3> points;         // lifted off the surface, out of geometry
    std::vector<uint8_t> moved;       // 1 where a point had to be moved out of geometry
};

// Full-sphere radiance moments per point in empty space (volume.h).
struct VolumeProbes {
    std::vector<RGB> s0;                    // integral of L over the sphere
    std::vector<std::array<RGB, 3>> s1;     // [a]: integral of L w_a
    std::vector<std::array<RGB, 9>> sh2;    // [k]: integral of L Y_k, the real L2 SH (volume.h)
    std::vector<double> back_fraction;      // rays that hit a back face
    std::vector<double> hit_fraction;       // rays that hit anything
    std::vector<double> nearest;            // closest hit distance, m (-1: nothing hit)
};

class RayScene {
public:
    // Patches from corner arrays: `corners` (n, 4, 3), `nv` (n) of 3 or 4 (triangles ignore
    // their fourth corner). Radiance and irradiance (n, 4, 3) per corner may be null (then
    // render and probe values are zero).
    // `glazing` (optional): per patch (face_transmittance indexed by patch) and the angular
    // table, so that luminaires and distant lights shine through windows (visibility.h).
    RayScene(const double* corners, const int32_t* nv, size_t n, const double* corner_radiance,
             const double* corner_irradiance, const Glazing* glazing = nullptr);
    // The same from an indexed mesh: `points` (num_points, 3), each patch's corner points
    // `faces` (n, 4), and radiance and irradiance per point (num_points, 3, or null): what a
    // display mesh holds, 16 bytes a face and 72 a point instead of 288 bytes a face for its
    // corners and their two values spelled out. The patches and their corner values are the
    // same bits as from those spelled-out arrays. Throws std::invalid_argument for an index
    // outside the points.
    RayScene(const double* points, size_t num_points, const int32_t* faces, const int32_t* nv, size_t n,
             const double* point_radiance, const double* point_irradiance, const Glazing* glazing = nullptr);
    RayScene(const RayScene&) = delete;
    RayScene& operator=(const RayScene&) = delete;

    size_t size() const { return patches_.size(); }
    bool has_values() const { return has_values_; }
    // Luminaires (luminaire.h) whose light illuminance and volume_probes add, exactly at
    // their points; render does not show them (they are not surfaces).
    void set_luminaires(std::vector<Luminaire> luminaires);

    std::vector<float> render(const Camera& camera, int samples) const;  // (height, width, 3)
    // With a non-zero normal, only surfaces facing the same way qualify.
    ProbeResult probe(const std::vector<Vec3>& points, const std::vector<Vec3>& normals, double max_distance) const;
    // Lightmap samples: each point lifted `epsilon` along its normal and, if that lands inside
    // geometry, moved out within `reach` (towards its anchor when given; volume.h).
    LiftResult lift_samples(std::vector<Vec3> points, const std::vector<Vec3>& normals, double epsilon, double reach,
                            const std::vector<Vec3>* anchors = nullptr) const;
    VolumeProbes volume_probes(const std::vector<Vec3>& points, int rays, uint64_t seed) const;
    // Illuminance at sensors (illuminance.h): `emitted` per patch is its self-emitted radiance;
    // the luminaires' light is part of `direct`.
    Illuminance illuminance(const std::vector<Vec3>& points, const std::vector<Vec3>& normals,
                            const std::vector<RGB>& emitted, const IlluminanceOptions& options) const;
    // The rays of illuminance's indirect part, traced once (illuminance.h).
    HemisphereHits hemisphere_hits(const std::vector<Vec3>& points, const std::vector<Vec3>& normals, int rays,
                                   uint64_t seed) const;
    // Far directions at sensors (luminaire.h, distant_transmittance), the lift of illuminance.
    std::vector<float> direct_transmittance(const std::vector<Vec3>& points, const std::vector<Vec3>& normals,
                                            const std::vector<Vec3>& directions) const;
    RayCastResult ray_cast(const std::vector<Vec3>& origins, const std::vector<Vec3>& directions) const;
    // ray_cast of one ray through each pixel centre of the camera (row 0 at the top).
    RayCastResult camera_rays(const Camera& camera) const;

private:
    // The patches from patch i's corner k (either form of the arrays) and their BVH; each
    // constructor sets the values.
    template <class Corner>
    void build(size_t n, const int32_t* nv, Corner&& corner, bool values, const Glazing* glazing);
    FaceTable patches_;
    CornerValues radiance_, irradiance_;
    bool has_values_ = false;
    std::unique_ptr<Visibility> visibility_;   // over patches_, built once
    std::vector<Luminaire> luminaires_;
};

}  // namespace hirad
