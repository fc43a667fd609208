#include "pipeline/outputs/illuminance.h"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

#include "pipeline/geometry/formfactors.h"

namespace hirad {

namespace {

void tangent_frame(const Vec3& n, Vec3& t1, Vec3& t2) {
    const Vec3 a = std::fabs(n.x) < 0.9 ? Vec3{1, 0, 0} : Vec3{0, 1, 0};
    t1 = normalize(cross(n, a));
    t2 = cross(n, t1);
}

Patch piece(const Patch& parent, std::array<Vec3, 4> p, int nv) {
    Patch q = parent;
    q.p = p;
    q.nv = nv;
    if (nv == 3) q.p[3] = q.p[2];
    finish_patch(q, PatchCentroid::AreaWeighted);
    return q;
}

// The indirect part's rays at sensor q: k x k cosine-distributed stratified directions (Malley:
// uniform on the disk, lifted), seeded by q, through clear glass; `hit(d, h, pass, panes)` for
// each ray (h the surface past the glass, patch -1 for none; pass the glass's factor; panes the
// glass crossed, visibility.h).
template <typename Hit>
void hemisphere_rays(const Visibility& visibility, const Vec3& x, const Vec3& nx, size_t q, int k, uint64_t seed,
                     double lift, Hit&& hit) {
    Vec3 t1, t2;
    tangent_frame(nx, t1, t2);
    Rng rng(hash_pair(q, 0x11C0ull, seed));
    std::vector<RayHit> panes;
    for (int i = 0; i < k; ++i)
        for (int j = 0; j < k; ++j) {
            const double r = std::sqrt((i + rng.uniform()) / k), phi = 2 * kPi * (j + rng.uniform()) / k;
            const double a = r * std::cos(phi), b = r * std::sin(phi), c = std::sqrt(std::max(0.0, 1 - r * r));
            const Vec3 d = normalize(t1 * a + t2 * b + nx * c);
            double pass = 1;
            const RayHit h = visibility.intersect_through_glass(x, d, lift, 1e30, &panes, &pass);
            hit(d, h, pass, panes);
        }
}

int rays_side(int rays) { return rays > 0 ? std::max(1, int(std::ceil(std::sqrt(double(rays))))) : 0; }

}  // namespace

HemisphereHits hemisphere_hits(const PatchView& patches, const Visibility& visibility,
                               const std::vector<Vec3>& points, const std::vector<Vec3>& normals, int rays,
                               uint64_t seed) {
    if (normals.size() != points.size()) throw std::invalid_argument("points and normals differ in length");
    if (rays < 1) throw std::invalid_argument("rays must be at least 1");
    const int k = rays_side(rays);
    const size_t m = size_t(k) * k, n = points.size();
    HemisphereHits out;
    out.rays = int(m);
    struct Entry { RayHit hit; double weight; };
    std::vector<std::vector<Entry>> per(n);  // per sensor, in ray order (then joined in sensor order)
    const double lift = 1e-7 * visibility.scene_size();
    tbb::parallel_for(size_t(0), n, [&](size_t q) {
        hemisphere_rays(visibility, points[q], normalize(normals[q]), q, k, seed, lift,
                        [&](const Vec3& d, const RayHit& h, double pass, const std::vector<RayHit>& panes) {
                            // what seen_through_glass reads (misses and backs give nothing)
                            visit_through_glass(visibility, patches, d, panes, h, pass,
                                                [&](const RayHit& at, double w) { per[q].push_back({at, w}); });
                        });
    });
    size_t total = 0;
    for (const auto& e : per) total += e.size();
    out.sensor.reserve(total), out.patch.reserve(total), out.u.reserve(total), out.v.reserve(total);
    out.weight.reserve(total);
    for (size_t q = 0; q < n; ++q)
        for (const Entry& e : per[q]) {
            out.sensor.push_back(int32_t(q));
            out.patch.push_back(e.hit.patch);
            out.u.push_back(e.hit.u);
            out.v.push_back(e.hit.v);
            out.weight.push_back(e.weight);
        }
    return out;
}

std::vector<Patch> patch_pieces(const Patch& patch, int g) {
    g = std::max(1, g);
    std::vector<Patch> out;
    out.reserve(size_t(g) * g);
    if (patch.nv == 4) {
        auto at = [&](int i, int j) {  // bilinear grid point: i along corner 0-1, j along 0-3
            const double s = double(i) / g, t = double(j) / g;
            return patch.p[0] * ((1 - s) * (1 - t)) + patch.p[1] * (s * (1 - t)) + patch.p[2] * (s * t) +
                   patch.p[3] * ((1 - s) * t);
        };
        for (int j = 0; j < g; ++j)
            for (int i = 0; i < g; ++i) out.push_back(piece(patch, {at(i, j), at(i + 1, j), at(i + 1, j + 1), at(i, j + 1)}, 4));
        return out;
    }
    auto at = [&](int i, int j) {  // barycentric grid: i steps towards corner 1, j towards corner 2
        return patch.p[0] + (patch.p[1] - patch.p[0]) * (double(i) / g) + (patch.p[2] - patch.p[0]) * (double(j) / g);
    };
    for (int j = 0; j < g; ++j)
        for (int i = 0; i + j < g; ++i) {
            out.push_back(piece(patch, {at(i, j), at(i + 1, j), at(i, j + 1), Vec3{}}, 3));
            if (i + j + 1 < g) out.push_back(piece(patch, {at(i + 1, j), at(i + 1, j + 1), at(i, j + 1), Vec3{}}, 3));
        }
    return out;
}

Illuminance illuminance_at(const PatchView& patches, const Visibility& visibility,
                           const CornerValues& corner_radiance, const std::vector<RGB>& emitted,
                           const std::vector<Vec3>& points, const std::vector<Vec3>& normals,
                           const IlluminanceOptions& o) {
    if (normals.size() != points.size()) throw std::invalid_argument("points and normals differ in length");
    if (emitted.size() != patches.size())
        throw std::invalid_argument("emitted_radiance: " + std::to_string(emitted.size()) + " rows for " +
                                    std::to_string(patches.size()) + " patches");
    if (corner_radiance.size() != patches.size()) throw std::invalid_argument("corner radiance: one row per patch");
    if (o.rays < 0 || o.emitter_samples < 1 || o.emitter_samples > 64)
        throw std::invalid_argument("rays must be >= 0 and emitter_samples in 1 .. 64");
    for (size_t q = 0; q < points.size(); ++q) {
        if (!isfinite(points[q]) || !isfinite(normals[q]) || !(length(normals[q]) > 0))
            throw std::invalid_argument("sensor " + std::to_string(q) + ": the point and a non-zero normal must be finite");
    }
    for (size_t i = 0; i < emitted.size(); ++i)
        if (!isfinite(emitted[i]) || emitted[i].x < 0 || emitted[i].y < 0 || emitted[i].z < 0)
            throw std::invalid_argument("emitted_radiance: patch " + std::to_string(i) + " is negative or not finite");

    // The emitters, each whole and cut once into pieces; a shadow ray ends just off the surface.
    // A sensor farther than kNear emitter diameters from an emitter reads it whole, with one
    // shadow ray to its centre; a nearer one reads its pieces, one ray each.
    struct Piece { Patch shape; Vec3 target; };
    struct Emitter { Piece whole; std::vector<Piece> pieces; RGB le; double diameter; };
    std::vector<Emitter> emitters;
    const double lift = 1e-7 * visibility.scene_size();       // the emitters' side of a shadow ray
    const double sensor_lift = visibility.ray_offset();
    for (size_t i = 0; i < patches.size(); ++i) {
        if (max_component(emitted[i]) <= 0) continue;
        Patch scratch;
        const Patch& w = patches.get(i, scratch);
        Emitter e{{w, w.centroid + w.normal * lift}, {}, emitted[i], 0};
        for (int a = 0; a < w.nv; ++a)
            for (int b = a + 1; b < w.nv; ++b) e.diameter = std::max(e.diameter, length(w.p[a] - w.p[b]));
        if (o.emitter_samples > 1)
            for (Patch& s : patch_pieces(w, o.emitter_samples)) e.pieces.push_back({s, s.centroid + s.normal * lift});
        emitters.push_back(std::move(e));
    }
    constexpr double kNear = 4;

    const size_t n = points.size();
    Illuminance out;
    out.direct.assign(n, RGB{});
    out.indirect.assign(n, RGB{});
    const int k = rays_side(o.rays);
    tbb::parallel_for(size_t(0), n, [&](size_t q) {
        const Vec3 x = points[q], nx = normalize(normals[q]);
        // direct: exact contour integrals, one shadow ray per piece that is seen at all
        std::vector<double> f;
        std::vector<RGB> le;
        std::vector<Vec3> from, to;
        auto add = [&](const Piece& piece, const RGB& l) {
            const Patch& s = piece.shape;
            const double ff = point_polygon_form_factor(x, nx, s.p.data(), s.nv, s.normal);
            if (!(ff > 0)) return;
            f.push_back(ff);
            le.push_back(l);
            from.push_back(x + nx * sensor_lift);
            to.push_back(piece.target);
        };
        for (const Emitter& e : emitters) {
            if (e.pieces.empty() || length(e.whole.shape.centroid - x) > kNear * e.diameter) {
                add(e.whole, e.le);
            } else {
                for (const Piece& piece : e.pieces) add(piece, e.le);
            }
        }
        if (!from.empty()) {
            std::vector<float> seen(from.size());  // through clear glass with its factor
            visibility.segments_transmittance(from.data(), to.data(), from.size(), seen.data());
            RGB e{};
            for (size_t a = 0; a < from.size(); ++a)
                if (seen[a] > 0) e += le[a] * (kPi * f[a] * double(seen[a]));
            out.direct[q] = e;
        }
        if (k == 0) return;
        // indirect: cosine-distributed stratified rays
        RGB sum{};
        hemisphere_rays(visibility, x, nx, q, k, o.seed, lift,
                        [&](const Vec3& d, const RayHit& h, double pass, const std::vector<RayHit>& panes) {
                            sum += seen_through_glass(visibility, patches, d, panes, h, pass, [&](const RayHit& at) {
                                RGB l = interpolate_corners(patches.nv(size_t(at.patch)), corner_radiance[at.patch],
                                                            at.u, at.v) -
                                        emitted[at.patch];
                                return RGB{std::max(0.0, l.x), std::max(0.0, l.y), std::max(0.0, l.z)};
                            });
                        });
        out.indirect[q] = sum * (kPi / (double(k) * k));
    });
    return out;
}

}  // namespace hirad
