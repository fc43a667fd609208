#include "pipeline/geometry/visibility.h"

#include <embree3/rtcore.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>
#include <type_traits>

namespace hirad {

namespace {

// Closest point on triangle abc to p (the Voronoi-region walk), with barycentrics (v, w)
// such that the point is a + v (b - a) + w (c - a).
Vec3 closest_on_triangle(const Vec3& p, const Vec3& a, const Vec3& b, const Vec3& c, double& v, double& w) {
    Vec3 ab = b - a, ac = c - a, ap = p - a;
    double d1 = dot(ab, ap), d2 = dot(ac, ap);
    if (d1 <= 0 && d2 <= 0) { v = 0; w = 0; return a; }
    Vec3 bp = p - b;
    double d3 = dot(ab, bp), d4 = dot(ac, bp);
    if (d3 >= 0 && d4 <= d3) { v = 1; w = 0; return b; }
    double vc = d1 * d4 - d3 * d2;
    if (vc <= 0 && d1 >= 0 && d3 <= 0) { v = d1 / (d1 - d3); w = 0; return a + ab * v; }
    Vec3 cp = p - c;
    double d5 = dot(ab, cp), d6 = dot(ac, cp);
    if (d6 >= 0 && d5 <= d6) { v = 0; w = 1; return c; }
    double vb = d5 * d2 - d1 * d6;
    if (vb <= 0 && d2 >= 0 && d6 <= 0) { w = d2 / (d2 - d6); v = 0; return a + ac * w; }
    double va = d3 * d6 - d5 * d4;
    if (va <= 0 && (d4 - d3) >= 0 && (d5 - d6) >= 0) {
        double t = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        v = 1 - t; w = t;
        return b + (c - b) * t;
    }
    double denom = 1 / (va + vb + vc);
    v = vb * denom; w = vc * denom;
    return a + ab * v + ac * w;
}

// The context of an occlusion query: Embree's, then what the glass filter needs. Every query of
// this class passes one; `factor` is null where glass is opaque (links).
constexpr int kPanes = 8;  // distinct panes remembered per ray

struct GlassContext {
    RTCIntersectContext base;
    float* factor;                   // per ray id: the product of the glass crossed so far
    float (*crossed)[kPanes];        // per ray id: the distances of the panes counted
    int* panes;                      // per ray id: how many
    const float* prim_transmittance; // per primitive
    const float* angular;            // r(cos theta) at n evenly spaced cosines
    int angular_n;
    const PatchView* patches;
};

float relative_from(const float* table, int n, double c) {
    if (n < 2) return 1.0f;
    c = std::clamp(c, 0.0, 1.0) * (n - 1);
    const int k = std::min(int(c), n - 2);
    const double f = c - k;
    return static_cast<float>(table[k] * (1 - f) + table[k + 1] * f);
}

// Glass lets a direct ray through with its factor tau0 r(cos theta); opaque surfaces stop it.
// A rejected hit (valid = 0) makes Embree go on along the ray.
void glass_filter(const RTCFilterFunctionNArguments* args) {
    const auto* ctx = reinterpret_cast<const GlassContext*>(args->context);
    if (!ctx->factor) return;
    for (unsigned i = 0; i < args->N; ++i) {
        if (args->valid[i] != -1) continue;
        const unsigned prim = RTCHitN_primID(args->hit, args->N, i);
        const float tau = ctx->prim_transmittance[prim];
        if (!(tau > 0)) continue;
        args->valid[i] = 0;
        // A ray through an edge or corner shared by several patches of one pane meets each of
        // them at the same distance (Embree's watertight test reports them all, in any order):
        // one pane counts once.
        const unsigned id = RTCRayN_id(args->ray, args->N, i);
        const float t = RTCRayN_tfar(args->ray, args->N, i);
        bool again = false;
        for (int k = 0; k < ctx->panes[id]; ++k)
            if (std::fabs(ctx->crossed[id][k] - t) <= 1e-6f * std::max(1.0f, std::fabs(t))) again = true;
        if (again) continue;
        if (ctx->panes[id] < kPanes) ctx->crossed[id][ctx->panes[id]++] = t;
        const Vec3 d{RTCRayN_dir_x(args->ray, args->N, i), RTCRayN_dir_y(args->ray, args->N, i),
                     RTCRayN_dir_z(args->ray, args->N, i)};
        const double len = length(d);
        const double c = len > 0 ? std::fabs(dot(d, ctx->patches->normal(prim))) / len : 1.0;
        ctx->factor[id] *= tau * relative_from(ctx->angular, ctx->angular_n, c);
    }
}

struct PointQueryState {
    const PatchView* patches;
    Vec3 point, normal;
    bool use_normal;
    RayHit best;
    double best_distance;
};

bool point_query(RTCPointQueryFunctionArguments* args) {
    auto* st = static_cast<PointQueryState*>(args->userPtr);
    if (st->use_normal && dot(st->patches->normal(args->primID), st->normal) < 0.5) return false;
    Patch scratch;
    const Patch& patch = st->patches->get(args->primID, scratch);
    // Quads as two triangles (0,1,2) and (0,2,3) for the distance.
    double v, w, u_quad = 0, v_quad = 0;
    Vec3 q = closest_on_triangle(st->point, patch.p[0], patch.p[1], patch.p[2], v, w);
    if (patch.nv == 3) { u_quad = v; v_quad = w; }
    else { u_quad = v + w; v_quad = w; }
    if (patch.nv == 4) {
        double v2, w2;
        Vec3 q2 = closest_on_triangle(st->point, patch.p[0], patch.p[2], patch.p[3], v2, w2);
        if (length(q2 - st->point) < length(q - st->point)) { q = q2; u_quad = v2; v_quad = v2 + w2; }
    }
    double d = length(q - st->point);
    if (d < st->best_distance) {
        st->best_distance = d;
        // Quads: the closest point's coordinates in the patch's own bilinear map (the two
        // triangles' coordinates agree with it only on parallelograms).
        if (patch.nv == 4) {
            const Vec2 c = patch.coordinates(q, {u_quad, v_quad});
            u_quad = c.u;
            v_quad = c.v;
        }
        st->best = {static_cast<int32_t>(args->primID), d, u_quad, v_quad};
        args->query->radius = static_cast<float>(d);
        return true;
    }
    return false;
}

}  // namespace

bool Glazing::any() const {
    for (double t : face_transmittance)
        if (t > 0) return true;
    return false;
}

double Visibility::glass_transmittance(int32_t prim, double abs_cos) const {
    if (prim < 0 || size_t(prim) >= prim_transmittance_.size()) return 0.0;
    const float tau = prim_transmittance_[size_t(prim)];
    if (!(tau > 0)) return 0.0;
    return double(tau) * relative_from(angular_.data(), int(angular_.size()), abs_cos);
}

double Glazing::relative(double cos_theta) const {
    if (angular.size() < 2) return 1.0;
    const double c = std::clamp(cos_theta, 0.0, 1.0) * double(angular.size() - 1);
    const size_t k = std::min(size_t(c), angular.size() - 2);
    const double f = c - double(k);
    return angular[k] * (1 - f) + angular[k + 1] * f;
}

void Glazing::validate() const {
    for (size_t f = 0; f < face_transmittance.size(); ++f)
        if (!(face_transmittance[f] >= 0 && face_transmittance[f] <= 1))
            throw std::invalid_argument("glazing: the transmittance of face " + std::to_string(f) +
                                        " is outside [0, 1] or not finite");
    if (angular.size() == 1) throw std::invalid_argument("glazing: the angular table needs at least 2 values");
    for (double r : angular)
        if (!(r >= 0 && r <= 1)) throw std::invalid_argument("glazing: an angular transmittance is outside [0, 1]");
}

Visibility::Visibility(PatchView patches, const Glazing* glazing, size_t count) : patches_(patches) {
    // The same kernels on every machine that has them: Embree would pick AVX-512 where the CPU
    // has it, and its wider traversal reports hits that differ from the AVX2 kernels' in the
    // last bits of t, u and v, so a render (and anything read at a hit) would change bits
    // between machines. AVX2 is the widest ISA hirad lets Embree use.
    device_ = rtcNewDevice("isa=avx2");
    if (!device_) throw std::runtime_error("Embree: could not create a device");
    rtcSetDeviceMemoryMonitorFunction(device_, &Visibility::count_bytes, this);
    scene_ = rtcNewScene(device_);
    // Medium quality: the high-quality builder's spatial splits abort (an assertion on empty
    // clipped bounds) on the thin halves of triangles stored as quads in large display meshes.
    rtcSetSceneBuildQuality(scene_, RTC_BUILD_QUALITY_MEDIUM);
    // Robust (watertight) traversal and intersection: a ray along a shared edge of two patches,
    // common in architectural scenes (grid points aligned with a ceiling's element edges and a
    // sky direction along an axis), otherwise slips between them and sees the sky through a
    // closed ceiling. Compact: the tree's leaves index the vertex buffer instead of copying each
    // quad's four corners (one floor of the bench building, 615k faces: 36.0 MB held after the
    // build against 57.6, 69.5 MB at its peak against 91.2, the same hits to the bit and the
    // same solve time; tests/cpp/face_table_test.cpp).
    rtcSetSceneFlags(scene_, RTC_SCENE_FLAG_ROBUST | RTC_SCENE_FLAG_COMPACT);
    RTCGeometry geom = rtcNewGeometry(device_, RTC_GEOMETRY_TYPE_QUAD);
    const size_t n = std::min(count, patches.size());
    Vec3 lo{1e300, 1e300, 1e300}, hi{-1e300, -1e300, -1e300};
    auto bound = [&](const Vec3& p) {
        for (int a = 0; a < 3; ++a) {
            lo[a] = std::min(lo[a], p[a]);
            hi[a] = std::max(hi[a], p[a]);
        }
    };
    if (const FaceTable* table = patches.table()) {
        // A hierarchy's faces share their corners (face_table.h): one vertex each, as floats of
        // the same doubles, so the quads and their BVH are those of a vertex per corner (12
        // bytes a point here, against 48 a face).
        std::vector<uint8_t> used(table->points(), 0);
        auto* indices = static_cast<uint32_t*>(rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT4,
                                                                       4 * sizeof(uint32_t), n));
        for (size_t i = 0; i < n; ++i) {
            const int nv = table->nv(i);
            for (int k = 0; k < 4; ++k) {
                // Triangles are quads whose last corner repeats the third, which Embree accepts.
                const uint32_t v = table->corner_index(i, k < nv ? k : 2);
                indices[4 * i + k] = v;
                used[v] = 1;
            }
        }
        const std::vector<Vec3>& points = table->point_list();
        auto* vertices = static_cast<float*>(rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3,
                                                                     3 * sizeof(float), std::max<size_t>(points.size(), 1)));
        for (size_t v = 0; v < points.size(); ++v) {
            for (int a = 0; a < 3; ++a) vertices[3 * v + a] = static_cast<float>(points[v][a]);
            if (used[v]) bound(points[v]);  // the traced faces' corners only, as for patches
        }
    } else {
        auto* vertices = static_cast<float*>(rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3,
                                                                     3 * sizeof(float), 4 * n));
        auto* indices = static_cast<uint32_t*>(rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT4,
                                                                       4 * sizeof(uint32_t), n));
        Patch scratch;
        for (size_t i = 0; i < n; ++i) {
            const Patch& patch = patches.get(i, scratch);
            // Triangles are quads whose last corner repeats the third, which Embree accepts.
            for (int k = 0; k < 4; ++k) {
                const Vec3& p = patch.p[k < patch.nv ? k : 2];
                for (int a = 0; a < 3; ++a) vertices[3 * (4 * i + k) + a] = static_cast<float>(p[a]);
                bound(p);
                indices[4 * i + k] = static_cast<uint32_t>(4 * i + k);
            }
        }
    }
    if (n > 0) {
        scene_size_ = std::max(length(hi - lo), 1e-6);
        lo_ = lo;
        hi_ = hi;
    }
    if (glazing && glazing->any()) {
        prim_transmittance_.resize(n);
        for (size_t i = 0; i < n; ++i) {
            const uint32_t f = patches.face(i);
            prim_transmittance_[i] =
                f < glazing->face_transmittance.size() ? static_cast<float>(glazing->face_transmittance[f]) : 0.0f;
        }
        angular_.assign(glazing->angular.begin(), glazing->angular.end());
        rtcSetGeometryOccludedFilterFunction(geom, glass_filter);
    }
    rtcCommitGeometry(geom);
    rtcAttachGeometry(scene_, geom);
    rtcReleaseGeometry(geom);
    rtcCommitScene(scene_);
    if (rtcGetDeviceError(device_) != RTC_ERROR_NONE) throw std::runtime_error("Embree: scene build failed");
}

bool Visibility::count_bytes(void* self, ssize_t bytes, bool) {
    auto* v = static_cast<Visibility*>(self);
    const int64_t now = v->bytes_.fetch_add(bytes) + bytes;
    int64_t peak = v->peak_bytes_.load();
    while (now > peak && !v->peak_bytes_.compare_exchange_weak(peak, now)) {
    }
    return true;  // never refuse: a refused allocation would abort the build half done
}

Visibility::~Visibility() {
    if (scene_) rtcReleaseScene(scene_);
    if (device_) rtcReleaseDevice(device_);
}

template <typename Out>
void Visibility::occlusion(const Vec3* from, const Vec3* to, size_t count, Out* out, bool through_glass,
                           double end_gap) const {
    alignas(64) float factor[16];
    float crossed[16][kPanes];
    int panes[16];
    GlassContext context;
    context.crossed = crossed;
    context.panes = panes;
    rtcInitIntersectContext(&context.base);
    context.factor = through_glass && has_glass() ? factor : nullptr;
    context.prim_transmittance = prim_transmittance_.data();
    context.angular = angular_.data();
    context.angular_n = int(angular_.size());
    context.patches = &patches_;
    // A batch of 9 to 16 rays goes to Embree as one packet of 16; fewer, one ray at a time. The
    // final gather traces 1 to 8 rays a source (one point to a few points of one polygon), and a
    // packet of 16 with most lanes idle cost more than the single rays: the Modern Hall's
    // lightmap stage took 19.2 s with packets and 16.3 s with single rays below 9 (same bits,
    // bench/README.md). Full packets keep the flat form factors' 16-ray batches at their
    // packet throughput (9.7 against 8.6 Mrays/s single on cornell_10k).
    for (size_t base = 0; base < count; base += 16) {
        const size_t m = std::min<size_t>(16, count - base);
        for (size_t k = 0; k < 16; ++k) {  // every lane: the filter may be called for unused ones
            factor[k] = 1.0f;
            panes[k] = 0;
        }
        auto ray_of = [&](size_t k, float& ox, float& oy, float& oz, float& dx, float& dy, float& dz) {
            const Vec3& o = from[base + k];
            const Vec3 d = to[base + k] - o;
            if (!isfinite(o) || !isfinite(d)) throw std::runtime_error("visibility: a ray with a non-finite end point");
            ox = static_cast<float>(o.x);
            oy = static_cast<float>(o.y);
            oz = static_cast<float>(o.z);
            dx = static_cast<float>(d.x);
            dy = static_cast<float>(d.y);
            dz = static_cast<float>(d.z);
        };
        bool open[16];
        if (m < 9) {
            for (size_t k = 0; k < m; ++k) {
                alignas(16) RTCRay ray;
                ray_of(k, ray.org_x, ray.org_y, ray.org_z, ray.dir_x, ray.dir_y, ray.dir_z);
                ray.tnear = 0.0f;
                ray.tfar = static_cast<float>(1.0 - end_gap);
                ray.time = 0;
                ray.mask = 0xFFFFFFFF;
                ray.id = static_cast<unsigned>(k);
                ray.flags = 0;
                rtcOccluded1(scene_, &context.base, &ray);
                open[k] = ray.tfar >= 0;
            }
        } else {
            alignas(64) RTCRay16 rays;
            alignas(64) int valid[16];
            for (size_t k = 0; k < 16; ++k) {
                // Unused lanes still carry a well-formed ray: Embree's packet kernels may read them.
                const size_t src = std::min(k, m - 1);
                valid[k] = k < m ? -1 : 0;
                ray_of(src, rays.org_x[k], rays.org_y[k], rays.org_z[k], rays.dir_x[k], rays.dir_y[k], rays.dir_z[k]);
                rays.tnear[k] = 0.0f;
                rays.tfar[k] = static_cast<float>(1.0 - end_gap);
                rays.time[k] = 0;
                rays.mask[k] = 0xFFFFFFFF;
                rays.id[k] = static_cast<unsigned>(k);
                rays.flags[k] = 0;
            }
            rtcOccluded16(valid, scene_, &context.base, &rays);
            for (size_t k = 0; k < m; ++k) open[k] = rays.tfar[k] >= 0;
        }
        for (size_t k = 0; k < m; ++k) {
            if constexpr (std::is_same_v<Out, float>)
                out[base + k] = open[k] ? factor[k] : 0.0f;
            else
                out[base + k] = open[k] ? 1 : 0;
        }
    }
    rays_ += count;
}

void Visibility::segments_visible(const Vec3* from, const Vec3* to, size_t count, uint8_t* visible,
                                  double end_gap) const {
    occlusion(from, to, count, visible, false, end_gap);
}

void Visibility::segments_transmittance(const Vec3* from, const Vec3* to, size_t count, float* transmittance,
                                        double end_gap) const {
    occlusion(from, to, count, transmittance, true, end_gap);
}

double Visibility::reach(const Vec3& origin) const {
    double far = 0;
    for (int c = 0; c < 8; ++c) {
        const Vec3 corner{(c & 1) ? hi_.x : lo_.x, (c & 2) ? hi_.y : lo_.y, (c & 4) ? hi_.z : lo_.z};
        far = std::max(far, length(corner - origin));
    }
    return 1.01 * far + 1e-3 * scene_size_ + 1e-6;
}

RayHit Visibility::intersect(const Vec3& origin, const Vec3& direction, double tnear, double tfar) const {
    GlassContext glass{};
    rtcInitIntersectContext(&glass.base);
    RTCIntersectContext& context = glass.base;
    RTCRayHit rh;
    rh.ray.org_x = static_cast<float>(origin.x);
    rh.ray.org_y = static_cast<float>(origin.y);
    rh.ray.org_z = static_cast<float>(origin.z);
    rh.ray.dir_x = static_cast<float>(direction.x);
    rh.ray.dir_y = static_cast<float>(direction.y);
    rh.ray.dir_z = static_cast<float>(direction.z);
    rh.ray.tnear = static_cast<float>(tnear);
    rh.ray.tfar = static_cast<float>(std::min(tfar, 1e30));
    rh.ray.time = 0;
    rh.ray.mask = 0xFFFFFFFF;
    rh.ray.id = 0;
    rh.ray.flags = 0;
    rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
    rh.hit.primID = RTC_INVALID_GEOMETRY_ID;
    rtcIntersect1(scene_, &context, &rh);
    ++rays_;
    RayHit hit;
    if (rh.hit.geomID == RTC_INVALID_GEOMETRY_ID) return hit;
    hit.patch = static_cast<int32_t>(rh.hit.primID);
    hit.t = rh.ray.tfar;
    hit.u = rh.hit.u;
    hit.v = rh.hit.v;
    return hit;
}

RayHit Visibility::intersect_through_glass(const Vec3& origin, const Vec3& direction, double tnear, double tfar,
                                          std::vector<RayHit>* panes, double* transmittance) const {
    if (panes) panes->clear();
    double pass = 1;
    RayHit hit = intersect(origin, direction, tnear, tfar);
    double travelled = 0;  // along `direction` from `origin` to the current ray's origin
    for (int k = 0; has_glass() && hit.patch >= 0 && k < kMaxPanes; ++k) {
        const double len = length(direction);
        const double c = dot(patches_.normal(size_t(hit.patch)), direction) / (len > 0 ? len : 1);
        const double t_glass = glass_transmittance(hit.patch, std::fabs(c));
        if (!(t_glass > 0)) break;
        hit.t += travelled;
        if (panes) panes->push_back(hit);
        pass *= t_glass;
        // Onwards from just past the pane, lifted off its plane on the far side.
        const double lift = ray_offset();
        const double step = hit.t + (std::fabs(c) > 1e-6 ? lift / std::fabs(c) / (len > 0 ? len : 1) : lift);
        travelled = step;
        if (step >= tfar) { hit = RayHit{}; break; }
        hit = intersect(origin + direction * step, direction, 0, tfar - step);
    }
    if (hit.patch >= 0) hit.t += travelled;
    if (transmittance) *transmittance = pass;
    return hit;
}

RayHit Visibility::closest_point(const Vec3& point, const Vec3& normal, double max_distance) const {
    PointQueryState state{&patches_, point, normalize(normal), length(normal) > 0, RayHit{}, max_distance};
    RTCPointQuery query;
    query.x = static_cast<float>(point.x);
    query.y = static_cast<float>(point.y);
    query.z = static_cast<float>(point.z);
    query.time = 0;
    query.radius = static_cast<float>(max_distance);
    RTCPointQueryContext context;
    rtcInitPointQueryContext(&context);
    rtcPointQuery(scene_, &query, &context, point_query, &state);
    return state.best;
}

}  // namespace hirad
