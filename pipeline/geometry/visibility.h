// Visibility and ray queries against the patch geometry, through Embree 3.
//
// Glazing. A face with a normal transmittance tau0 > 0 (glass: UsdPreviewSurface opacity < 1
// or hirad:transmittance) lets light through along a ray with the factor
//   T(theta) = tau0 * r(cos theta),
// theta the angle between the ray and the glass's normal (either side), r the glass's relative
// angular transmittance (hirad.daylight.glazing: the Tregenza-Sharples polynomial of clear
// glass) tabulated at cos theta = k / (n - 1) and linear between. Only the direct rays of
// luminaires and of distant lights (sun, sky) pass glass (segments_transmittance): the light
// arrives through the window in its own direction. So does interreflected light in a
// hierarchical bake: its links and the final gather see through glass with the same factor (a
// thin sheet: clear glass does not scatter what it lets through), and the rays that read the
// solved surface (pictures, probes, grids) go on through panes (intersect_through_glass).
// segments_visible treats glass as opaque (the flat method's form factors).
// Several panes multiply. An Embree occlusion filter does it: it rejects a hit on glass after
// multiplying the ray's factor, so the traversal goes on to the next surface.
#pragma once
#include <algorithm>
#include <atomic>
#include <cstdint>
#include <vector>

#include <sys/types.h>  // ssize_t, as Embree's monitor gives it

#include "pipeline/geometry/face_table.h"
#include "pipeline/geometry/patches.h"

typedef struct RTCDeviceTy* RTCDevice;
typedef struct RTCSceneTy* RTCScene;

namespace hirad {

struct RayHit {
    int32_t patch = -1;  // -1 when the ray escapes
    double t = 0;
    double u = 0, v = 0; // Embree's quad coordinates: bilinear within the patch
};

// The glazing of a scene: per engine face (Patch::face) its normal transmittance (0: opaque), and
// the relative angular transmittance r(cos theta) at n >= 2 evenly spaced cosines 0 .. 1.
struct Glazing {
    std::vector<double> face_transmittance;
    std::vector<double> angular;   // empty: r = 1 at every angle
    bool any() const;
    double relative(double cos_theta) const;  // r, linear in the table
    // Throws std::invalid_argument for values outside [0, 1], a table shorter than 2 or not finite.
    void validate() const;
};

// The polygons a Visibility traces, by index: a vector of patches, or a hierarchy's faces
// (FaceTable, face_table.h), whose patches are made on demand.
class PatchView {
public:
    PatchView(const std::vector<Patch>& patches) : vector_(&patches) {}  // NOLINT: implicit
    PatchView(const FaceTable& faces) : table_(&faces) {}                // NOLINT: implicit
    size_t size() const { return vector_ ? vector_->size() : table_->size(); }
    // Patch i: a reference into the vector, or `scratch` made from the table.
    const Patch& get(size_t i, Patch& scratch) const {
        if (vector_) return (*vector_)[i];
        scratch = (*table_)[i];
        return scratch;
    }
    const Vec3& normal(size_t i) const { return vector_ ? (*vector_)[i].normal : table_->normal(i); }
    int nv(size_t i) const { return vector_ ? (*vector_)[i].nv : table_->nv(i); }
    uint32_t face(size_t i) const { return vector_ ? (*vector_)[i].face : table_->face(i); }
    const FaceTable* table() const { return table_; }

private:
    const std::vector<Patch>* vector_ = nullptr;
    const FaceTable* table_ = nullptr;
};

class Visibility {
public:
    // `glazing` (may be null, or have no glass) is copied for the patches' faces. Only the first
    // `count` patches are traced (a hierarchy's faces without the backs of its glazed faces,
    // which lie on their fronts).
    explicit Visibility(PatchView patches, const Glazing* glazing = nullptr, size_t count = SIZE_MAX);
    ~Visibility();
    Visibility(const Visibility&) = delete;
    Visibility& operator=(const Visibility&) = delete;

    // visible[k] = 1 when the open segment from[k] -> to[k] hits nothing. Rays are traced in
    // packets of 16 (rtcOccluded16), a last batch of fewer than 9 one by one. The ends are expected to be lifted off their surfaces
    // already; the last `end_gap` fraction of each segment is not tested.
    void segments_visible(const Vec3* from, const Vec3* to, size_t count, uint8_t* visible,
                          double end_gap = 1e-4) const;

    // The transmittance of each open segment: 0 when an opaque surface blocks it, else the
    // product of the factors T(theta) of the glass it crosses (1 with no glass on the way).
    void segments_transmittance(const Vec3* from, const Vec3* to, size_t count, float* transmittance,
                                double end_gap = 1e-4) const;
    // A distance from `origin` beyond which nothing of the scene lies (past its bounding box):
    // a segment that long in any direction is a ray to infinity (distant lights).
    double reach(const Vec3& origin) const;
    bool has_glass() const { return !prim_transmittance_.empty(); }
    // T(theta) = tau0 r(cos theta) of patch `prim` for a ray at |cos theta| = `abs_cos` to its
    // normal: the factor segments_transmittance multiplies per pane; 0 for an opaque patch.
    double glass_transmittance(int32_t prim, double abs_cos) const;

    RayHit intersect(const Vec3& origin, const Vec3& direction, double tnear = 0,
                     double tfar = 1e30) const;

    // The first surface along the ray that is not glass; the glass met before it is passed.
    // `panes` (may be null) receives each pane crossed, nearest first (at most kMaxPanes; a
    // ray that meets more stops at the last), and `transmittance` the product of their factors
    // T(theta). Without glass in the scene this is intersect. Each crossing restarts the ray
    // just past the pane (a shared edge of one pane's patches is met once).
    static constexpr int kMaxPanes = 8;
    RayHit intersect_through_glass(const Vec3& origin, const Vec3& direction, double tnear = 0,
                                   double tfar = 1e30, std::vector<RayHit>* panes = nullptr,
                                   double* transmittance = nullptr) const;

    // Closest point on the surface within max_distance; with a non-zero normal, only patches
    // facing the same way (cosine > 0.5) qualify. Returns the patch and bilinear (u,v).
    RayHit closest_point(const Vec3& point, const Vec3& normal, double max_distance) const;

    uint64_t rays_cast() const { return rays_.load(); }
    // Bytes Embree holds for this scene now (its BVH, its copies of the vertices and indices),
    // and the most it held, during the build: counted by the device's memory monitor.
    uint64_t bytes() const { return uint64_t(std::max<int64_t>(bytes_.load(), 0)); }
    uint64_t peak_bytes() const { return uint64_t(std::max<int64_t>(peak_bytes_.load(), 0)); }
    // Length of the scene's bounding box diagonal; used to scale ray offsets.
    double scene_size() const { return scene_size_; }
    // How far a ray leaving a surface starts off it (along the surface's normal, or past a
    // pane of glass), so that the surface it leaves does not stop it at t = 0: 1e-5 of the
    // scene's size, every such ray in hirad (form factors, links, the gather, luminaires,
    // sensors on a surface, the reference). Float vertices of a 100 m scene are exact to
    // about 4e-6 m, below this 1 mm; geometry closer than it to a surface is not resolved.
    double ray_offset() const { return kRayOffset * scene_size_; }
    static constexpr double kRayOffset = 1e-5;

private:
    RTCDevice device_ = nullptr;
    RTCScene scene_ = nullptr;
    PatchView patches_;
    double scene_size_ = 1;
    Vec3 lo_{0, 0, 0}, hi_{0, 0, 0};
    std::vector<float> prim_transmittance_;  // per patch (empty: no glass)
    std::vector<float> angular_;             // r(cos theta) table
    template <typename Out>
    void occlusion(const Vec3* from, const Vec3* to, size_t count, Out* out, bool through_glass,
                   double end_gap) const;
    mutable std::atomic<uint64_t> rays_{0};
    std::atomic<int64_t> bytes_{0}, peak_bytes_{0};
    static bool count_bytes(void* self, ssize_t bytes, bool post);
};

// The surfaces a ray that reads a solved surface sees through clear glass, from the result of
// intersect_through_glass (`panes`, `hit`, `pass`): visit(pane, weight) for each pane crossed
// from its front (its own radiosity: what it reflects), weight the glass before it, then
// visit(hit, pass) for the surface past the glass. Backs give nothing (one-sided).
template <typename Visit>
void visit_through_glass(const Visibility& vis, const PatchView& patches, const Vec3& dir,
                         const std::vector<RayHit>& panes, const RayHit& hit, double pass, Visit&& visit) {
    double before = 1;
    const double len = length(dir) > 0 ? length(dir) : 1.0;
    for (const RayHit& g : panes) {
        const double c = dot(patches.normal(size_t(g.patch)), dir) / len;
        if (c < 0) visit(g, before);
        before *= vis.glass_transmittance(g.patch, std::fabs(c));
    }
    if (hit.patch >= 0 && dot(patches.normal(size_t(hit.patch)), dir) < 0) visit(hit, pass);
}

// The sum of value(surface) x weight over what visit_through_glass visits.
template <typename Value>
RGB seen_through_glass(const Visibility& vis, const PatchView& patches, const Vec3& dir,
                       const std::vector<RayHit>& panes, const RayHit& hit, double pass, Value&& value) {
    RGB sum;
    visit_through_glass(vis, patches, dir, panes, hit, pass,
                        [&](const RayHit& at, double weight) { sum += value(at) * weight; });
    return sum;
}

}  // namespace hirad
