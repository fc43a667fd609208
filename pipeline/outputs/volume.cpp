#include "pipeline/outputs/volume.h"

#include <tbb/parallel_for.h>

#include <cmath>
#include <stdexcept>

namespace hirad {

namespace {

// An orthonormal tangent pair for n.
void tangents(const Vec3& n, Vec3& t1, Vec3& t2) {
    const Vec3 a = std::fabs(n.x) < 0.9 ? Vec3{1, 0, 0} : Vec3{0, 1, 0};
    t1 = normalize(cross(n, a));
    t2 = cross(n, t1);
}

}  // namespace

void sh2_basis(const Vec3& d, double y[9]) {
    // Exact constants of the real, orthonormal SH (volume.h): 1/2 sqrt(1/pi), 1/2 sqrt(3/pi),
    // 1/2 sqrt(15/pi), 1/4 sqrt(5/pi), 1/4 sqrt(15/pi).
    static const double k0 = 0.5 * std::sqrt(1 / kPi), k1 = 0.5 * std::sqrt(3 / kPi),
                        k2 = 0.5 * std::sqrt(15 / kPi), k3 = 0.25 * std::sqrt(5 / kPi),
                        k4 = 0.25 * std::sqrt(15 / kPi);
    const double x = d.x, yy = d.y, z = d.z;
    y[0] = k0;
    y[1] = k1 * yy;
    y[2] = k1 * z;
    y[3] = k1 * x;
    y[4] = k2 * x * yy;
    y[5] = k2 * yy * z;
    y[6] = k3 * (3 * z * z - 1);
    y[7] = k2 * x * z;
    y[8] = k4 * (x * x - yy * yy);
}

std::vector<ProbeMoments> probe_moments(const PatchView& patches, const Visibility& visibility,
                                        const CornerValues& corner_radiance,
                                        const std::vector<Vec3>& points, int rays, uint64_t seed) {
    const int k = std::max(1, static_cast<int>(std::ceil(std::sqrt(static_cast<double>(std::max(rays, 1))))));
    const int n = k * k;
    const double weight = 4 * kPi / n;  // equal-area strata
    std::vector<ProbeMoments> out(points.size());
    tbb::parallel_for(size_t(0), points.size(), [&](size_t q) {
        Rng rng(hash_pair(q, 0x5eed, seed));
        ProbeMoments m;
        int back = 0, hits = 0;
        std::vector<RayHit> panes;
        for (int i = 0; i < k; ++i)
            for (int j = 0; j < k; ++j) {
                // z uniform in [-1, 1] and phi uniform: equal area on the sphere (Archimedes).
                const double z = 1 - 2 * (i + rng.uniform()) / k;
                const double phi = 2 * kPi * (j + rng.uniform()) / k;
                const double r = std::sqrt(std::max(0.0, 1 - z * z));
                const Vec3 d{r * std::cos(phi), r * std::sin(phi), z};
                // through clear glass (the panes' own light and what lies past them)
                double pass = 1;
                const RayHit hit = visibility.intersect_through_glass(points[q], d, 0, 1e30, &panes, &pass);
                const double first = panes.empty() ? hit.t : panes.front().t;
                if (hit.patch < 0 && panes.empty()) continue;
                ++hits;
                if (m.nearest < 0 || first < m.nearest) m.nearest = first;
                if (hit.patch >= 0 && panes.empty() && dot(patches.normal(size_t(hit.patch)), d) >= 0) {
                    ++back;  // the back of a one-sided surface
                    continue;
                }
                const RGB l = seen_through_glass(visibility, patches, d, panes, hit, pass, [&](const RayHit& at) {
                                  return interpolate_corners(patches.nv(size_t(at.patch)), corner_radiance[at.patch], at.u, at.v);
                              }) * weight;
                m.s0 += l;
                m.s1[0] += l * d.x;
                m.s1[1] += l * d.y;
                m.s1[2] += l * d.z;
                double y[9];
                sh2_basis(d, y);
                for (int b = 0; b < 9; ++b) m.sh2[b] += l * y[b];
            }
        m.back_fraction = static_cast<double>(back) / n;
        m.hit_fraction = static_cast<double>(hits) / n;
        out[q] = m;
    });
    return out;
}

void lift_samples(const PatchView& patches, const Visibility& visibility, std::vector<Vec3>& points,
                  const std::vector<Vec3>& normals, double epsilon, double reach, std::vector<uint8_t>& moved,
                  const std::vector<Vec3>* anchors) {
    if (normals.size() != points.size()) throw std::invalid_argument("points and normals differ in length");
    if (anchors && anchors->size() != points.size()) throw std::invalid_argument("points and anchors differ in length");
    moved.assign(points.size(), 0);
    tbb::parallel_for(size_t(0), points.size(), [&](size_t q) {
        const Vec3 n = normalize(normals[q]);
        Vec3 x = points[q] + n * epsilon;
        if (length(n) == 0) return;
        Vec3 t1, t2;
        tangents(n, t1, t2);
        const double c = std::sqrt(0.5);
        const Vec3 dirs[9] = {n, t1, -t1, t2, -t2, (t1 + t2) * c, (t1 - t2) * c, (t2 - t1) * c, -(t1 + t2) * c};
        Vec3 towards;
        if (anchors) towards = normalize((*anchors)[q] - x);
        const bool steer = length(towards) > 0;
        double best = reach, best_score = -1e30;
        Vec3 best_dir;
        bool inside = false;
        for (const Vec3& d : dirs) {
            const RayHit hit = visibility.intersect(x, d, 0, reach);
            if (hit.patch < 0 || dot(patches.normal(size_t(hit.patch)), d) <= 0) continue;
            // nearest exit, or (steered) the exit most towards the anchor, nearest on ties
            const double score = steer ? dot(d, towards) - 1e-6 * hit.t : -hit.t;
            if (score > best_score) {
                best_score = score;
                best = hit.t;
                best_dir = d;
                inside = true;
            }
        }
        if (!inside) {
            points[q] = x;
            return;
        }
        points[q] = x + best_dir * (best + epsilon) + n * epsilon;
        moved[q] = 1;
    });
}

}  // namespace hirad
