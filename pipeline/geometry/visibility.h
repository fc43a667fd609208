// Visibility and ray queries against the patch geometry, through Embree 3.
#pragma once
#include <atomic>
#include <cstdint>
#include <vector>

#include "pipeline/geometry/patches.h"

typedef struct RTCDeviceTy* RTCDevice;
typedef struct RTCSceneTy* RTCScene;

namespace hirad {

struct RayHit {
    int32_t patch = -1;  // -1 when the ray escapes
    double t = 0;
    double u = 0, v = 0; // Embree's quad coordinates: bilinear within the patch
};

class Visibility {
public:
    explicit Visibility(const std::vector<Patch>& patches);
    ~Visibility();
    Visibility(const Visibility&) = delete;
    Visibility& operator=(const Visibility&) = delete;

    // visible[k] = 1 when the open segment from[k] -> to[k] hits nothing. Rays are traced in
    // packets of 16 (rtcOccluded16). The ends are expected to be lifted off their surfaces
    // already; the last `end_gap` fraction of each segment is not tested.
    void segments_visible(const Vec3* from, const Vec3* to, size_t count, uint8_t* visible,
                          double end_gap = 1e-4) const;

    RayHit intersect(const Vec3& origin, const Vec3& direction, double tnear = 0,
                     double tfar = 1e30) const;

    // Closest point on the surface within max_distance; with a non-zero normal, only patches
    // facing the same way (cosine > 0.5) qualify. Returns the patch and bilinear (u,v).
    RayHit closest_point(const Vec3& point, const Vec3& normal, double max_distance) const;

    uint64_t rays_cast() const { return rays_.load(); }
    // Length of the scene's bounding box diagonal; used to scale ray offsets.
    double scene_size() const { return scene_size_; }

private:
    RTCDevice device_ = nullptr;
    RTCScene scene_ = nullptr;
    const std::vector<Patch>& patches_;
    double scene_size_ = 1;
    mutable std::atomic<uint64_t> rays_{0};
};

}  // namespace hirad
