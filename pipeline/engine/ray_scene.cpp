#include "pipeline/engine/ray_scene.h"

#include <tbb/parallel_for.h>

#include <functional>
#include <stdexcept>

namespace hirad {

template <class Corner>
void RayScene::build(size_t n, const int32_t* nv, Corner&& corner, bool values, const Glazing* glazing) {
    // The patches kept compact (face_table.h: about 112 bytes a patch and 24 a corner, where a
    // Patch is 328), made again when one is read.
    patches_.reserve(n);
    for (size_t i = 0; i < n; ++i) {
        Patch p;
        p.nv = nv[i];
        if (p.nv != 3 && p.nv != 4)
            throw std::invalid_argument("nv: patch " + std::to_string(i) + " has " + std::to_string(p.nv) +
                                        " corners (3 or 4)");
        for (int k = 0; k < 4; ++k) p.p[k] = corner(i, k);
        finish_patch(p, PatchCentroid::AreaWeighted);
        p.face = static_cast<uint32_t>(i);  // glazing is given per patch
        p.vertex = {0, 0, 0, 0};
        patches_.push_back(p);
    }
    patches_.seal();
    // Either value may be missing (zero), as may both (has_values false).
    has_values_ = values;
    if (glazing) glazing->validate();
    visibility_ = std::make_unique<Visibility>(patches_, glazing);
}

RayScene::RayScene(const double* corners, const int32_t* nv, size_t n, const double* corner_radiance,
                   const double* corner_irradiance, const Glazing* glazing)
    : patches_(PatchCentroid::AreaWeighted) {
    using At = std::function<Vec3(size_t, int)>;
    auto at = [](const double* a) -> At {
        return [a](size_t i, int k) { const double* c = a + (i * 4 + k) * 3; return Vec3{c[0], c[1], c[2]}; };
    };
    build(n, nv, at(corners), corner_radiance && corner_irradiance, glazing);
    auto fill = [n](CornerValues& out, const double* value) {
        out = CornerValues(n);
        if (value)
            for (size_t i = 0; i < 12 * n; ++i) out.corners(i / 12).v[i % 12] = static_cast<float>(value[i]);
    };
    fill(radiance_, corner_radiance);
    fill(irradiance_, corner_irradiance);
}

RayScene::RayScene(const double* points, size_t num_points, const int32_t* faces, const int32_t* nv, size_t n,
                   const double* point_radiance, const double* point_irradiance, const Glazing* glazing)
    : patches_(PatchCentroid::AreaWeighted) {
    for (size_t i = 0; i < n; ++i)
        for (int k = 0; k < 4; ++k)
            if (faces[4 * i + k] < 0 || size_t(faces[4 * i + k]) >= num_points)
                throw std::invalid_argument("faces: corner " + std::to_string(k) + " of face " + std::to_string(i) +
                                            " is point " + std::to_string(faces[4 * i + k]) + ", outside the " +
                                            std::to_string(num_points) + " points");
    using At = std::function<Vec3(size_t, int)>;
    auto at = [faces](const double* a) -> At {
        return [a, faces](size_t i, int k) {
            const double* c = a + size_t(faces[4 * i + k]) * 3;
            return Vec3{c[0], c[1], c[2]};
        };
    };
    build(n, nv, at(points), point_radiance && point_irradiance, glazing);
    // The values stay indexed: the faces' four points each, shared by both, and a float RGB a
    // point (zeros for a missing one).
    auto index = std::make_shared<std::vector<std::array<uint32_t, 4>>>(n);
    for (size_t i = 0; i < n; ++i)
        for (int k = 0; k < 4; ++k) (*index)[i][k] = static_cast<uint32_t>(faces[4 * i + k]);
    auto fill = [&](CornerValues& out, const double* value) {
        std::vector<std::array<float, 3>> v(num_points, std::array<float, 3>{0.0f, 0.0f, 0.0f});
        if (value)
            for (size_t q = 0; q < num_points; ++q)
                for (int a = 0; a < 3; ++a) v[q][a] = static_cast<float>(value[3 * q + a]);
        out = CornerValues(index, std::move(v));
    };
    fill(radiance_, point_radiance);
    fill(irradiance_, point_irradiance);
}

std::vector<float> RayScene::render(const Camera& camera, int samples) const {
    if (camera.width <= 0 || camera.height <= 0) throw std::invalid_argument("image size must be positive");
    return render_radiance(patches_, *visibility_, radiance_, camera, samples);
}

ProbeResult RayScene::probe(const std::vector<Vec3>& points, const std::vector<Vec3>& normals,
                            double max_distance) const {
    if (normals.size() != points.size()) throw std::invalid_argument("points and normals differ in length");
    const size_t n = points.size();
    ProbeResult r;
    r.patch.resize(n);
    r.distance.resize(n);
    r.irradiance.assign(n, RGB{});
    r.radiance.assign(n, RGB{});
    tbb::parallel_for(size_t(0), n, [&](size_t q) {
        const RayHit hit = visibility_->closest_point(points[q], normals[q], max_distance);
        r.patch[q] = hit.patch;
        r.distance[q] = hit.patch >= 0 ? hit.t : -1;
        if (hit.patch < 0) return;
        const int nv = patches_.nv(size_t(hit.patch));
        r.irradiance[q] = interpolate_corners(nv, irradiance_[hit.patch], hit.u, hit.v);
        r.radiance[q] = interpolate_corners(nv, radiance_[hit.patch], hit.u, hit.v);
    });
    return r;
}

LiftResult RayScene::lift_samples(std::vector<Vec3> points, const std::vector<Vec3>& normals, double epsilon,
                                  double reach, const std::vector<Vec3>* anchors) const {
    LiftResult r;
    hirad::lift_samples(patches_, *visibility_, points, normals, epsilon, reach, r.moved, anchors);
    r.points = std::move(points);
    return r;
}

void RayScene::set_luminaires(std::vector<Luminaire> luminaires) {
    for (const Luminaire& l : luminaires) l.validate();
    luminaires_ = std::move(luminaires);
}

VolumeProbes RayScene::volume_probes(const std::vector<Vec3>& points, int rays, uint64_t seed) const {
    std::vector<ProbeMoments> m = probe_moments(patches_, *visibility_, radiance_, points, rays, seed);
    if (!luminaires_.empty()) {
        std::vector<RGB> s0(m.size());
        std::vector<std::array<RGB, 3>> s1(m.size());
        luminaire_moments(luminaires_, visibility_.get(), points.data(), points.size(), s0.data(), s1.data());
        for (size_t q = 0; q < m.size(); ++q) {
            m[q].s0 += s0[q];
            for (int a = 0; a < 3; ++a) m[q].s1[a] += s1[q][a];
        }
        // The L2 part: a luminaire reaches a probe as a few deltas of radiance (one per point of
        // the luminaire, or per direction of a distant light), so its SH projection is the sum of
        // each delta's irradiance-free contribution v times Y_k(its direction). The summed
        // moments above cannot give Y's quadratic terms, so each point goes on its own: a copy of
        // the luminaire with that one point (weight 1, its tint) gives v / w_k at every probe,
        // with the same shadow rays and transmittance as the moments.
        for (const Luminaire& l : luminaires_)
            for (size_t k = 0; k < l.points.size(); ++k) {
                if (!(l.weights[k] > 0)) continue;
                Luminaire one = l;
                one.points = {l.points[k]};
                one.weights = {1.0};
                if (!l.tints.empty()) one.tints = {l.tints[k]};
                one.interleave = false;
                std::vector<RGB> e(m.size());
                std::vector<std::array<RGB, 3>> unused(m.size());
                luminaire_moments({one}, visibility_.get(), points.data(), points.size(), e.data(), unused.data());
                for (size_t q = 0; q < m.size(); ++q) {
                    if (e[q].x == 0 && e[q].y == 0 && e[q].z == 0) continue;
                    const Vec3 d = l.distant ? normalize(l.points[k]) : normalize(l.points[k] - points[q]);
                    double y[9];
                    sh2_basis(d, y);
                    const RGB v = e[q] * l.weights[k];
                    for (int b = 0; b < 9; ++b) m[q].sh2[b] += v * y[b];
                }
            }
    }
    VolumeProbes v;
    for (const ProbeMoments& p : m) {
        v.s0.push_back(p.s0);
        v.s1.push_back(p.s1);
        v.sh2.push_back(p.sh2);
        v.back_fraction.push_back(p.back_fraction);
        v.hit_fraction.push_back(p.hit_fraction);
        v.nearest.push_back(p.nearest);
    }
    return v;
}

Illuminance RayScene::illuminance(const std::vector<Vec3>& points, const std::vector<Vec3>& normals,
                                  const std::vector<RGB>& emitted, const IlluminanceOptions& options) const {
    Illuminance e = illuminance_at(patches_, *visibility_, radiance_, emitted, points, normals, options);
    if (!luminaires_.empty()) {
        std::vector<RGB> d(points.size());
        std::vector<Vec3> unit(normals.size());
        for (size_t q = 0; q < unit.size(); ++q) unit[q] = normalize(normals[q]);
        luminaire_irradiance(luminaires_, visibility_.get(), points.data(), unit.data(), points.size(), d.data(),
                             visibility_->ray_offset());
        for (size_t q = 0; q < d.size(); ++q) e.direct[q] += d[q];
    }
    return e;
}

HemisphereHits RayScene::hemisphere_hits(const std::vector<Vec3>& points, const std::vector<Vec3>& normals, int rays,
                                         uint64_t seed) const {
    return hirad::hemisphere_hits(patches_, *visibility_, points, normals, rays, seed);
}

std::vector<float> RayScene::direct_transmittance(const std::vector<Vec3>& points, const std::vector<Vec3>& normals,
                                                  const std::vector<Vec3>& directions) const {
    if (normals.size() != points.size()) throw std::invalid_argument("points and normals differ in length");
    std::vector<float> out(points.size() * directions.size());
    distant_transmittance(*visibility_, points.data(), normals.data(), points.size(), unit_directions(directions),
                          visibility_->ray_offset(), out.data());
    return out;
}

RayCastResult RayScene::ray_cast(const std::vector<Vec3>& o, const std::vector<Vec3>& d) const {
    return cast_rays(patches_, *visibility_, o, d);
}

RayCastResult cast_rays(const PatchView& patches, const Visibility& visibility, const std::vector<Vec3>& o,
                        const std::vector<Vec3>& d) {
    if (o.size() != d.size()) throw std::invalid_argument("origins and directions differ in length");
    const size_t n = o.size();
    RayCastResult r;
    r.patch.assign(n, -1);
    r.t.assign(n, -1);
    r.points.assign(n, Vec3{});
    r.normals.assign(n, Vec3{});
    r.back.assign(n, 0);
    r.u.assign(n, 0.0);
    r.v.assign(n, 0.0);
    tbb::parallel_for(size_t(0), n, [&](size_t q) {
        const Vec3 dir = normalize(d[q]);
        const RayHit h = visibility.intersect(o[q], dir);
        if (h.patch < 0) return;
        r.patch[q] = h.patch;
        r.t[q] = h.t;
        r.points[q] = o[q] + dir * h.t;
        r.normals[q] = patches.normal(size_t(h.patch));
        r.back[q] = dot(r.normals[q], dir) >= 0;
        r.u[q] = h.u;
        r.v[q] = h.v;
    });
    return r;
}

RayCastResult RayScene::camera_rays(const Camera& cam) const {
    if (cam.width <= 0 || cam.height <= 0 || uint64_t(cam.width) * uint64_t(cam.height) > kMaxRenderPixels)
        throw std::length_error("camera_rays: image size " + std::to_string(cam.width) + " x " +
                                std::to_string(cam.height) + " outside 1 .. 8192 x 8192 pixels");
    const size_t n = size_t(cam.width) * cam.height;
    std::vector<Vec3> o(n, cam.position), d(n);
    for (int y = 0; y < cam.height; ++y)
        for (int x = 0; x < cam.width; ++x) d[size_t(y) * cam.width + x] = camera_direction(cam, x + 0.5, y + 0.5);
    return ray_cast(o, d);
}

}  // namespace hirad
