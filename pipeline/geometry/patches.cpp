#include "pipeline/geometry/patches.h"

#include <algorithm>
#include <cmath>
#include <climits>
#include <cstdint>
#include <cstring>
#include <string>
#include <sstream>
#include <stdexcept>
#include <unordered_map>

namespace hirad {

Vec3 Patch::point(double s, double t) const { return polygon_point(p[0], p[1], p[2], p[3], nv, s, t); }

void inverse_bilinear(const std::array<Vec2, 4>& q, const Vec2& p, double& s, double& t) {
    auto cross2 = [](const Vec2& a, const Vec2& b) { return a.u * b.v - a.v * b.u; };
    for (int it = 0; it < 8; ++it) {
        Vec2 f{(1 - s) * (1 - t) * q[0].u + s * (1 - t) * q[1].u + s * t * q[2].u + (1 - s) * t * q[3].u - p.u,
               (1 - s) * (1 - t) * q[0].v + s * (1 - t) * q[1].v + s * t * q[2].v + (1 - s) * t * q[3].v - p.v};
        Vec2 ds{(1 - t) * (q[1].u - q[0].u) + t * (q[2].u - q[3].u), (1 - t) * (q[1].v - q[0].v) + t * (q[2].v - q[3].v)};
        Vec2 dt{(1 - s) * (q[3].u - q[0].u) + s * (q[2].u - q[1].u), (1 - s) * (q[3].v - q[0].v) + s * (q[2].v - q[1].v)};
        double det = cross2(ds, dt);
        if (std::fabs(det) < 1e-30) break;
        s -= cross2(f, dt) / det;
        t -= cross2(ds, f) / det;
    }
    s = std::clamp(s, 0.0, 1.0);
    t = std::clamp(t, 0.0, 1.0);
}

void split_in_four(const Patch& s, Patch kids[4]) {
    auto mid = [](const Vec3& a, const Vec3& b) { return (a + b) * 0.5; };
    auto mid2 = [](const Vec2& a, const Vec2& b) { return Vec2{(a.u + b.u) * 0.5, (a.v + b.v) * 0.5}; };
    if (s.nv == 4) {
        const Vec3 m01 = mid(s.p[0], s.p[1]), m12 = mid(s.p[1], s.p[2]), m23 = mid(s.p[2], s.p[3]), m30 = mid(s.p[3], s.p[0]);
        const Vec3 c = mid(m01, m23);
        const Vec2 u01 = mid2(s.uv[0], s.uv[1]), u12 = mid2(s.uv[1], s.uv[2]), u23 = mid2(s.uv[2], s.uv[3]),
                   u30 = mid2(s.uv[3], s.uv[0]), uc = mid2(u01, u23);
        const Vec3 corners[4][4] = {{s.p[0], m01, c, m30}, {m01, s.p[1], m12, c}, {c, m12, s.p[2], m23}, {m30, c, m23, s.p[3]}};
        const Vec2 uvs[4][4] = {{s.uv[0], u01, uc, u30}, {u01, s.uv[1], u12, uc}, {uc, u12, s.uv[2], u23}, {u30, uc, u23, s.uv[3]}};
        for (int k = 0; k < 4; ++k) {
            kids[k] = s;
            for (int c2 = 0; c2 < 4; ++c2) { kids[k].p[c2] = corners[k][c2]; kids[k].uv[c2] = uvs[k][c2]; }
        }
    } else {
        const Vec3 m01 = mid(s.p[0], s.p[1]), m12 = mid(s.p[1], s.p[2]), m20 = mid(s.p[2], s.p[0]);
        const Vec2 u01 = mid2(s.uv[0], s.uv[1]), u12 = mid2(s.uv[1], s.uv[2]), u20 = mid2(s.uv[2], s.uv[0]);
        const Vec3 corners[4][3] = {{s.p[0], m01, m20}, {m01, s.p[1], m12}, {m20, m12, s.p[2]}, {m12, m20, m01}};
        const Vec2 uvs[4][3] = {{s.uv[0], u01, u20}, {u01, s.uv[1], u12}, {u20, u12, s.uv[2]}, {u12, u20, u01}};
        for (int k = 0; k < 4; ++k) {
            kids[k] = s;
            for (int c2 = 0; c2 < 3; ++c2) { kids[k].p[c2] = corners[k][c2]; kids[k].uv[c2] = uvs[k][c2]; }
        }
    }
}

Vec2 Patch::coordinates(const Vec3& x, Vec2 guess) const {
    // In a frame of the patch's plane: the corners and x projected onto it.
    const Vec3 e1 = normalize(p[1] - p[0]), e2 = cross(normal, e1);
    auto flat = [&](const Vec3& y) { return Vec2{dot(y - p[0], e1), dot(y - p[0], e2)}; };
    const Vec2 at = flat(x);
    if (nv == 3) {
        const Vec2 b = flat(p[1]), c = flat(p[2]);
        const double d = b.u * c.v - b.v * c.u;
        if (std::fabs(d) < 1e-30) return {0, 0};
        double s = (at.u * c.v - at.v * c.u) / d, t = (b.u * at.v - b.v * at.u) / d;
        s = std::clamp(s, 0.0, 1.0);
        t = std::clamp(t, 0.0, 1.0 - s);
        return {s, t};
    }
    double s = guess.u, t = guess.v;
    inverse_bilinear({flat(p[0]), flat(p[1]), flat(p[2]), flat(p[3])}, at, s, t);
    return {s, t};
}

void finish_patch(Patch& patch, PatchCentroid centroid) {
    if (patch.nv == 3) {
        patch.p[3] = patch.p[2];
        patch.uv[3] = patch.uv[2];
    }
    // Newell's normal: twice the area, along the normal of a planar polygon of any shape.
    Vec3 n;
    for (int k = 0; k < patch.nv; ++k) n += cross(patch.p[k], patch.p[(k + 1) % patch.nv]);
    patch.area = 0.5 * length(n);
    patch.normal = normalize(n);
    patch.centroid = patch_centroid(patch, centroid);
}

Vec3 patch_centroid(const Patch& patch, PatchCentroid centroid) {
    if (centroid == PatchCentroid::CornerMean) {
        Vec3 c;
        for (int k = 0; k < patch.nv; ++k) c += patch.p[k];
        return c / patch.nv;
    }
    // Area-weighted centroid over a fan of triangles.
    Vec3 c;
    double total = 0;
    for (int k = 1; k + 1 < patch.nv; ++k) {
        double a = 0.5 * length(cross(patch.p[k] - patch.p[0], patch.p[k + 1] - patch.p[0]));
        c += (patch.p[0] + patch.p[k] + patch.p[k + 1]) * (a / 3);
        total += a;
    }
    return total > 0 ? c / total : patch.p[0];
}

namespace {

// The point i/n of the way from a to b, computed the same way whichever face asks and
// whichever way round that face runs along the edge (from the lexicographically smaller end,
// with the step counted in integers so that 1 - i/n is never rounded), so that the points two
// faces put on their shared edge are bit-identical and weld exactly. The ends are the corners
// themselves.
Vec3 edge_point(const Vec3& a, const Vec3& b, int i, int n) {
    if (i <= 0) return a;
    if (i >= n) return b;
    bool a_first = a.x < b.x || (a.x == b.x && (a.y < b.y || (a.y == b.y && a.z <= b.z)));
    return a_first ? a + (b - a) * (double(i) / n) : b + (a - b) * (double(n - i) / n);
}

Vec2 lerp2(const Vec2& a, const Vec2& b, double t) { return {a.u + (b.u - a.u) * t, a.v + (b.v - a.v) * t}; }

struct Welder {
    std::unordered_map<std::string, uint32_t> index;
    PatchSet& out;
    uint32_t vertex(uint32_t mesh, const Vec3& p) {
        std::string key(sizeof(uint32_t) + sizeof(Vec3), '\0');
        std::memcpy(&key[0], &mesh, sizeof(uint32_t));
        Vec3 q = p + Vec3{0, 0, 0};  // turns -0.0 into +0.0 so equal points share a key
        std::memcpy(&key[sizeof(uint32_t)], &q, sizeof(Vec3));
        auto [it, inserted] = index.emplace(key, static_cast<uint32_t>(out.vertices.size()));
        if (inserted) {
            out.vertices.push_back(p);
            out.vertex_mesh.push_back(mesh);
        }
        return it->second;
    }
};

}  // namespace

double estimate_face_patches(const Face& f, const MeshingOptions& options) {
    const double area = f.area();
    double grid;
    if (f.nv == 4) {
        const double lu = std::max(length(f.p[1] - f.p[0]), length(f.p[2] - f.p[3]));
        const double lv = std::max(length(f.p[3] - f.p[0]), length(f.p[2] - f.p[1]));
        grid = std::max(1.0, std::ceil(lu / options.max_edge_length)) * std::max(1.0, std::ceil(lv / options.max_edge_length));
    } else {
        const double longest = std::max({length(f.p[1] - f.p[0]), length(f.p[2] - f.p[1]), length(f.p[0] - f.p[2])});
        const double k = std::max(1.0, std::ceil(longest / options.max_edge_length));
        grid = k * k;
    }
    return std::max(grid, std::ceil(area / options.max_area));
}

namespace {

[[noreturn]] void too_many_patches(const Scene& scene, const MeshingOptions& options, double total, uint32_t worst,
                                   double worst_count) {
    Vec3 lo, hi;
    scene.bounds(lo, hi);
    std::ostringstream msg;
    msg.precision(3);
    msg << "meshing would make at least " << total << " patches, more than the limit of " << options.max_patches
        << " (meshing.max_patches); the largest share, " << worst_count << ", is face " << worst << " (mesh "
        << scene.faces[worst].mesh << ", area " << scene.faces[worst].area() << " m^2); the scene spans "
        << length(hi - lo) << " m. Raise meshing.max_patch_area (" << options.max_area
        << " m^2) or max_edge_length (" << options.max_edge_length
        << " m), or check the scene's units (metersPerUnit) and coordinates";
    throw std::length_error(msg.str());
}

}  // namespace

PatchSet mesh_patches(const Scene& scene, const MeshingOptions& options) {
    const double max_edge = options.max_edge_length;
    const double max_area = options.max_area;
    if (!(std::isfinite(max_edge) && max_edge > 0) || !(std::isfinite(max_area) && max_area > 0)) {
        std::ostringstream msg;
        msg << "meshing: max_edge_length (" << max_edge << ") and max_patch_area (" << max_area
            << ") must be positive finite numbers";
        throw std::invalid_argument(msg.str());
    }
    if (options.max_patches > uint64_t(INT32_MAX))  // a face's grid is counted in int
        throw std::invalid_argument("meshing: max_patches " + std::to_string(options.max_patches) +
                                    " is above the most patches the engine indexes, " + std::to_string(INT32_MAX));
    // How much will be built, before building it.
    double total = 0, worst_count = 0;
    uint32_t worst = 0;
    for (uint32_t fi = 0; fi < scene.faces.size(); ++fi) {
        const double n = estimate_face_patches(scene.faces[fi], options);
        if (!(n <= double(options.max_patches))) too_many_patches(scene, options, n, fi, n);  // also NaN
        total += n;
        if (n > worst_count) worst_count = n, worst = fi;
        if (total > double(options.max_patches)) too_many_patches(scene, options, total, worst, worst_count);
    }
    PatchSet out;
    Welder welder{{}, out};
    for (uint32_t fi = 0; fi < scene.faces.size(); ++fi) {
        const Face& f = scene.faces[fi];
        const double area = f.area();
        Patch base;
        base.reflectance = f.reflectance;
        base.emission = f.emission;
        base.mesh = f.mesh;
        base.face = fi;
        base.nv = f.nv;
        if (f.nv == 4) {
            // A grid of nu x nv sub-quads; u runs along edge 0-1, v along edge 0-3.
            int nu = static_cast<int>(std::ceil(std::max(length(f.p[1] - f.p[0]), length(f.p[2] - f.p[3])) / max_edge));
            int nv = static_cast<int>(std::ceil(std::max(length(f.p[3] - f.p[0]), length(f.p[2] - f.p[1])) / max_edge));
            nu = std::max(nu, 1);
            nv = std::max(nv, 1);
            const double lu = std::max(length(f.p[1] - f.p[0]), length(f.p[2] - f.p[3]));
            const double lv = std::max(length(f.p[3] - f.p[0]), length(f.p[2] - f.p[1]));
            // The area per unit (s, t) of a planar quad is affine in s and t, so the largest
            // cell of the grid is one of the four corner cells: bound those, not the mean.
            auto bilinear = [&](double s, double t) {
                return f.p[0] * ((1 - s) * (1 - t)) + f.p[1] * (s * (1 - t)) + f.p[2] * (s * t) + f.p[3] * ((1 - s) * t);
            };
            auto cell_area = [&](int i, int j) {
                Vec3 a = bilinear(double(i) / nu, double(j) / nv), b = bilinear(double(i + 1) / nu, double(j) / nv);
                Vec3 c = bilinear(double(i + 1) / nu, double(j + 1) / nv), d = bilinear(double(i) / nu, double(j + 1) / nv);
                return 0.5 * length(cross(c - a, d - b));
            };
            auto largest_cell = [&] {
                return std::max({cell_area(0, 0), cell_area(nu - 1, 0), cell_area(0, nv - 1), cell_area(nu - 1, nv - 1)});
            };
            while (largest_cell() > max_area) {
                if (lu / nu >= lv / nv) ++nu; else ++nv;
                // A skewed quad's corner cells may need more than the estimate.
                if (out.patches.size() + uint64_t(nu) * uint64_t(nv) > options.max_patches)
                    too_many_patches(scene, options, double(out.patches.size()) + double(nu) * nv, fi, double(nu) * nv);
            }
            auto grid_point = [&](int i, int j) -> Vec3 {
                double s = double(i) / nu, t = double(j) / nv;
                if (j == 0) return edge_point(f.p[0], f.p[1], i, nu);
                if (j == nv) return edge_point(f.p[3], f.p[2], i, nu);
                if (i == 0) return edge_point(f.p[0], f.p[3], j, nv);
                if (i == nu) return edge_point(f.p[1], f.p[2], j, nv);
                return f.p[0] * ((1 - s) * (1 - t)) + f.p[1] * (s * (1 - t)) + f.p[2] * (s * t) + f.p[3] * ((1 - s) * t);
            };
            auto grid_uv = [&](int i, int j) -> Vec2 {
                double s = double(i) / nu, t = double(j) / nv;
                return lerp2(lerp2(f.uv[0], f.uv[1], s), lerp2(f.uv[3], f.uv[2], s), t);
            };
            for (int j = 0; j < nv; ++j)
                for (int i = 0; i < nu; ++i) {
                    Patch patch = base;
                    const int ci[4] = {i, i + 1, i + 1, i};
                    const int cj[4] = {j, j, j + 1, j + 1};
                    for (int k = 0; k < 4; ++k) {
                        patch.p[k] = grid_point(ci[k], cj[k]);
                        patch.uv[k] = grid_uv(ci[k], cj[k]);
                        patch.vertex[k] = welder.vertex(f.mesh, patch.p[k]);
                    }
                    finish_patch(patch, PatchCentroid::AreaWeighted);
                    out.patches.push_back(patch);
                }
        } else {
            // k^2 sub-triangles from a barycentric grid (i along 0-1, j along 0-2).
            double longest = std::max({length(f.p[1] - f.p[0]), length(f.p[2] - f.p[1]), length(f.p[0] - f.p[2])});
            int k = std::max(1, static_cast<int>(std::ceil(longest / max_edge)));
            while (area / (double(k) * k) > max_area) ++k;
            auto tri_point = [&](int i, int j) -> Vec3 {
                if (j == 0) return edge_point(f.p[0], f.p[1], i, k);
                if (i == 0) return edge_point(f.p[0], f.p[2], j, k);
                if (i + j == k) return edge_point(f.p[1], f.p[2], j, k);
                return f.p[0] + (f.p[1] - f.p[0]) * (double(i) / k) + (f.p[2] - f.p[0]) * (double(j) / k);
            };
            auto tri_uv = [&](int i, int j) -> Vec2 {
                double s = double(i) / k, t = double(j) / k;
                return {f.uv[0].u + (f.uv[1].u - f.uv[0].u) * s + (f.uv[2].u - f.uv[0].u) * t,
                        f.uv[0].v + (f.uv[1].v - f.uv[0].v) * s + (f.uv[2].v - f.uv[0].v) * t};
            };
            auto emit = [&](int i0, int j0, int i1, int j1, int i2, int j2) {
                Patch patch = base;
                patch.nv = 3;
                const int ci[3] = {i0, i1, i2}, cj[3] = {j0, j1, j2};
                for (int c = 0; c < 3; ++c) {
                    patch.p[c] = tri_point(ci[c], cj[c]);
                    patch.uv[c] = tri_uv(ci[c], cj[c]);
                    patch.vertex[c] = welder.vertex(f.mesh, patch.p[c]);
                }
                patch.vertex[3] = patch.vertex[2];
                finish_patch(patch, PatchCentroid::AreaWeighted);
                out.patches.push_back(patch);
            };
            for (int j = 0; j < k; ++j)
                for (int i = 0; i + j < k; ++i) {
                    emit(i, j, i + 1, j, i, j + 1);
                    if (i + j + 1 < k) emit(i + 1, j, i + 1, j + 1, i, j + 1);
                }
        }
    }
    return out;
}

PatchSet weld_patches(std::vector<Patch> patches) {
    PatchSet out;
    Welder welder{{}, out};
    for (Patch& p : patches) {
        for (int k = 0; k < p.nv; ++k) p.vertex[k] = welder.vertex(p.mesh, p.p[k]);
        if (p.nv == 3) p.vertex[3] = p.vertex[2];
    }
    out.patches = std::move(patches);
    return out;
}

}  // namespace hirad
