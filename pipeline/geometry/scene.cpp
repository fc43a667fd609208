#include "pipeline/geometry/scene.h"

#include <algorithm>
#include <cmath>
#include <map>
#include <sstream>
#include <stdexcept>

namespace hirad {

namespace {

// Newell's normal: robust for any planar (or nearly planar) polygon; its length is twice
// the area.
Vec3 newell(const Vec3* p, int n) {
    Vec3 acc;
    for (int i = 0; i < n; ++i) acc += cross(p[i], p[(i + 1) % n]);
    return acc;
}

double cross2(double ax, double ay, double bx, double by) { return ax * by - ay * bx; }

bool point_in_triangle_2d(const double* a, const double* b, const double* c, const double* p) {
    double d1 = cross2(b[0] - a[0], b[1] - a[1], p[0] - a[0], p[1] - a[1]);
    double d2 = cross2(c[0] - b[0], c[1] - b[1], p[0] - b[0], p[1] - b[1]);
    double d3 = cross2(a[0] - c[0], a[1] - c[1], p[0] - c[0], p[1] - c[1]);
    return d1 >= 0 && d2 >= 0 && d3 >= 0;
}

// The polygon in 2D, projected onto the plane of its dominant normal axes and oriented so
// that it runs counter-clockwise.
std::vector<std::array<double, 2>> project_ccw(const std::vector<Vec3>& poly) {
    const int n = static_cast<int>(poly.size());
    Vec3 nrm = newell(poly.data(), n);
    int drop = 2;
    if (std::fabs(nrm.x) >= std::fabs(nrm.y) && std::fabs(nrm.x) >= std::fabs(nrm.z)) drop = 0;
    else if (std::fabs(nrm.y) >= std::fabs(nrm.z)) drop = 1;
    int ax = (drop + 1) % 3, ay = (drop + 2) % 3;
    bool flip = nrm[drop] < 0;
    std::vector<std::array<double, 2>> q(n);
    for (int i = 0; i < n; ++i) q[i] = {poly[i][ax], flip ? -poly[i][ay] : poly[i][ay]};
    return q;
}

// Sign of the turn a -> b -> c: +1 left, -1 right, 0 collinear.
int orientation(const std::array<double, 2>& a, const std::array<double, 2>& b, const std::array<double, 2>& c) {
    const double d = cross2(b[0] - a[0], b[1] - a[1], c[0] - a[0], c[1] - a[1]);
    return d > 0 ? 1 : (d < 0 ? -1 : 0);
}

}  // namespace

bool polygon_self_intersects(const std::vector<Vec3>& poly) {
    const size_t n = poly.size();
    if (n < 4) return false;
    const std::vector<std::array<double, 2>> q = project_ccw(poly);
    for (size_t i = 0; i < n; ++i) {
        const auto &a = q[i], &b = q[(i + 1) % n];
        // Edges that share no corner with edge i: j from i + 2, and not the edge before i.
        for (size_t j = i + 2; j < n; ++j) {
            if ((j + 1) % n == i) continue;
            const auto &c = q[j], &d = q[(j + 1) % n];
            if (orientation(a, b, c) * orientation(a, b, d) < 0 && orientation(c, d, a) * orientation(c, d, b) < 0)
                return true;
        }
    }
    return false;
}

Vec3 Face::normal() const { return normalize(newell(p.data(), nv)); }
double Face::area() const { return 0.5 * length(newell(p.data(), nv)); }

std::vector<std::array<int, 3>> triangulate_polygon(const std::vector<Vec3>& poly) {
    const int n = static_cast<int>(poly.size());
    std::vector<std::array<int, 3>> tris;
    if (n < 3) return tris;
    // Project onto the plane's dominant axes, keeping orientation so that the polygon is
    // counter-clockwise in 2D.
    const std::vector<std::array<double, 2>> q = project_ccw(poly);

    std::vector<int> idx(n);
    for (int i = 0; i < n; ++i) idx[i] = i;
    int guard = 0;
    while (idx.size() > 3 && guard < 4 * n * n) {
        const int m = static_cast<int>(idx.size());
        bool clipped = false;
        for (int k = 0; k < m; ++k) {
            int ia = idx[(k + m - 1) % m], ib = idx[k], ic = idx[(k + 1) % m];
            const double *a = q[ia].data(), *b = q[ib].data(), *c = q[ic].data();
            double turn = cross2(b[0] - a[0], b[1] - a[1], c[0] - b[0], c[1] - b[1]);
            if (turn <= 0) continue;  // reflex or collinear corner: not an ear
            bool contains = false;
            for (int other : idx) {
                if (other == ia || other == ib || other == ic) continue;
                if (point_in_triangle_2d(a, b, c, q[other].data())) { contains = true; break; }
            }
            if (contains) continue;
            tris.push_back({ia, ib, ic});
            idx.erase(idx.begin() + k);
            clipped = true;
            break;
        }
        ++guard;
        if (!clipped) {
            // A numerically collinear remainder (a self-intersecting polygon never gets here:
            // Scene::build skips it): close it as a fan so the surface is still covered, but
            // never with a triangle turned the other way (it would face backwards).
            for (size_t k = 1; k + 1 < idx.size(); ++k) {
                const double *a = q[idx[0]].data(), *b = q[idx[k]].data(), *c = q[idx[k + 1]].data();
                if (cross2(b[0] - a[0], b[1] - a[1], c[0] - a[0], c[1] - a[1]) > 0)
                    tris.push_back({idx[0], idx[k], idx[k + 1]});
            }
            return tris;
        }
    }
    if (idx.size() == 3) tris.push_back({idx[0], idx[1], idx[2]});
    return tris;
}

namespace {

// Materials the solve cannot take: every face's reflectance must be finite and in [0, 1],
// its emission finite and not negative. Throws std::invalid_argument with the count and the
// first such face.
void check_materials(const SceneInput& in) {
    uint64_t bad = 0;
    size_t first = 0;
    for (size_t f = 0; f < in.num_faces; ++f) {
        bool ok = true;
        for (int c = 0; c < 3; ++c) {
            const double r = in.face_reflectance[3 * f + c], e = in.face_emission[3 * f + c];
            ok = ok && std::isfinite(r) && r >= 0 && r <= 1 && std::isfinite(e) && e >= 0;
        }
        if (in.face_transmittance) {
            const double t = in.face_transmittance[f];
            const double rmax = std::max({in.face_reflectance[3 * f], in.face_reflectance[3 * f + 1],
                                          in.face_reflectance[3 * f + 2]});
            ok = ok && t >= 0 && t <= 1 && rmax + t <= 1 + 1e-12;  // what glass reflects and lets through
        }
        if (!ok && bad++ == 0) first = f;
    }
    if (bad == 0) return;
    auto rgb = [](const double* v) {
        std::ostringstream o;
        o << "(" << v[0] << ", " << v[1] << ", " << v[2] << ")";
        return o.str();
    };
    std::ostringstream msg;
    msg << "scene: " << bad << " of " << in.num_faces
        << " faces have a reflectance outside [0, 1], an emission that is negative or not finite, or a transmittance "
           "outside [0, 1] or above 1 - reflectance; the first is face "
        << first << " (mesh " << in.face_mesh[first] << ", authored face "
        << (in.face_source ? in.face_source[first] : int32_t(first)) << "): reflectance "
        << rgb(in.face_reflectance + 3 * first) << ", emission " << rgb(in.face_emission + 3 * first);
    throw std::invalid_argument(msg.str());
}

}  // namespace

Scene Scene::build(const SceneInput& in) {
    check_materials(in);
    Scene scene;
    scene.has_uv = in.corner_uv != nullptr;
    scene.stats.input_faces = in.num_faces;
    // Every usable face's edges, as (lower, higher) vertex pairs: sorted, a pair met more than
    // twice is a non-manifold edge. (A hash map of counts took a node and a bucket an edge,
    // about 40 bytes, 0.6 GB at 10 M triangles; this holds 8 bytes a face corner.)
    std::vector<uint64_t> edges;
    // The faces reserved once: a triangle or a kept quad gives one face, a polygon of n > 4
    // corners at most n - 2; only quads that are not planar and convex (two triangles) grow
    // the vector past this. Grown by doubling instead, a 615k-triangle scene held 232 MiB of
    // faces where 130 MiB were used, at the engine's peak (its hierarchy is built beside them).
    size_t expected = 0, corners = 0;
    for (size_t f = 0; f < in.num_faces; ++f) {
        const int count = in.face_vertex_counts[f];
        expected += count > 4 ? static_cast<size_t>(count - 2) : 1;
        corners += count > 0 ? static_cast<size_t>(count) : 0;
    }
    scene.faces.reserve(expected);
    edges.reserve(corners);
    size_t offset = 0;
    for (size_t f = 0; f < in.num_faces; ++f) {
        const int count = in.face_vertex_counts[f];
        const size_t first = offset;
        offset += count;
        std::vector<Vec3> poly;
        std::vector<Vec2> uvs;
        bool finite = true;
        for (int k = 0; k < count; ++k) {
            int32_t vi = in.face_vertex_indices[first + k];
            if (vi < 0 || static_cast<size_t>(vi) >= in.num_points) { finite = false; break; }
            Vec3 p{in.points[3 * vi], in.points[3 * vi + 1], in.points[3 * vi + 2]};
            if (!isfinite(p)) { finite = false; break; }
            Vec2 uv;
            if (in.corner_uv) uv = {in.corner_uv[2 * (first + k)], in.corner_uv[2 * (first + k) + 1]};
            // Drop repeated corners (zero-length edges) so they don't fake a degenerate face.
            if (!poly.empty() && length(p - poly.back()) <= 1e-12) continue;
            poly.push_back(p);
            uvs.push_back(uv);
        }
        if (!finite) { ++scene.stats.nonfinite_faces; continue; }
        if (poly.size() > 1 && length(poly.front() - poly.back()) <= 1e-12) { poly.pop_back(); uvs.pop_back(); }
        if (poly.size() < 3) { ++scene.stats.degenerate_faces; continue; }

        for (int k = 0; k < count; ++k) {
            uint64_t a = static_cast<uint32_t>(in.face_vertex_indices[first + k]);
            uint64_t b = static_cast<uint32_t>(in.face_vertex_indices[first + (k + 1) % count]);
            if (a > b) std::swap(a, b);
            edges.push_back((a << 32) | b);
        }

        const int n = static_cast<int>(poly.size());
        Vec3 nrm = newell(poly.data(), n);
        double area = 0.5 * length(nrm);
        double extent = 0;
        for (const Vec3& p : poly) extent = std::max(extent, length(p - poly[0]));
        if (!(area > 1e-16) || area <= 1e-10 * extent * extent) {
            ++scene.stats.degenerate_faces;
            continue;
        }
        Vec3 unit = nrm / (2 * area);

        Face base;
        base.mesh = static_cast<uint32_t>(in.face_mesh[f]);
        base.source_face = in.face_source ? static_cast<uint32_t>(in.face_source[f]) : static_cast<uint32_t>(f);
        base.reflectance = {in.face_reflectance[3 * f], in.face_reflectance[3 * f + 1], in.face_reflectance[3 * f + 2]};
        base.emission = {in.face_emission[3 * f], in.face_emission[3 * f + 1], in.face_emission[3 * f + 2]};
        base.transmittance = in.face_transmittance ? in.face_transmittance[f] : 0.0;

        bool keep_quad = false;
        if (n == 4) {
            // A quad stays a quad when it is planar and strictly convex.
            double off_plane = std::fabs(dot(poly[3] - poly[0], unit));
            bool convex = true;
            for (int k = 0; k < 4; ++k) {
                Vec3 turn = cross(poly[(k + 1) % 4] - poly[k], poly[(k + 2) % 4] - poly[(k + 1) % 4]);
                if (dot(turn, unit) <= 0) convex = false;
            }
            keep_quad = convex && off_plane <= 1e-5 * extent;
        }
        if (n == 3 || keep_quad) {
            Face face = base;
            face.nv = n;
            for (int k = 0; k < n; ++k) { face.p[k] = poly[k]; face.uv[k] = uvs[k]; }
            scene.faces.push_back(face);
            continue;
        }
        // A polygon whose edges cross has no one surface (which lobes count, which way do
        // they face?): ear clipping would cover some lobes twice, some backwards. Skipped and
        // counted.
        if (polygon_self_intersects(poly)) {
            ++scene.stats.self_intersecting_faces;
            continue;
        }
        ++scene.stats.triangulated_faces;
        for (const auto& t : triangulate_polygon(poly)) {
            Face face = base;
            face.nv = 3;
            for (int k = 0; k < 3; ++k) { face.p[k] = poly[t[k]]; face.uv[k] = uvs[t[k]]; }
            if (face.area() <= 1e-10 * extent * extent) continue;  // sliver from collinear corners
            scene.faces.push_back(face);
        }
    }
    std::sort(edges.begin(), edges.end());
    for (size_t i = 0; i < edges.size();) {
        size_t j = i + 1;
        while (j < edges.size() && edges[j] == edges[i]) ++j;
        if (j - i > 2) ++scene.stats.nonmanifold_edges;
        i = j;
    }
    return scene;
}

void Scene::bounds(Vec3& lo, Vec3& hi) const {
    lo = {1e300, 1e300, 1e300};
    hi = {-1e300, -1e300, -1e300};
    for (const Face& f : faces)
        for (int k = 0; k < f.nv; ++k)
            for (int a = 0; a < 3; ++a) {
                lo[a] = std::min(lo[a], f.p[k][a]);
                hi[a] = std::max(hi[a], f.p[k][a]);
            }
}

}  // namespace hirad
