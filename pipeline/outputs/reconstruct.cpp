#include "pipeline/outputs/reconstruct.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <array>
#include <stdexcept>
#include <utility>

namespace hirad {

namespace {

// A welded vertex's position within its mesh, compared bit for bit. Kept in a sorted vector
// and found by binary search: on a million patches that is 32 bytes a vertex, where a hash map
// of string keys took about 130.
struct PointKey {
    uint32_t mesh = 0;
    std::array<uint64_t, 3> bits{};
    bool operator<(const PointKey& o) const { return mesh != o.mesh ? mesh < o.mesh : bits < o.bits; }
    bool operator==(const PointKey& o) const { return mesh == o.mesh && bits == o.bits; }
};

PointKey point_key(uint32_t mesh, const Vec3& p) {
    PointKey key;
    key.mesh = mesh;
    const Vec3 q = p + Vec3{0, 0, 0};  // -0.0 and +0.0 share a key
    std::memcpy(key.bits.data(), &q, sizeof(Vec3));
    return key;
}

}  // namespace

// What the display mesh reads of the patches, from a PatchSet or from a FaceTable welded by mesh.
struct SetSource {
    const PatchSet& s;
    size_t size() const { return s.patches.size(); }
    int nv(uint32_t i) const { return s.patches[i].nv; }
    uint32_t vertex(uint32_t i, int k) const { return s.patches[i].vertex[k]; }
    const Vec3& normal(uint32_t i) const { return s.patches[i].normal; }
    const Vec3& corner(uint32_t i, int k) const { return s.patches[i].p[k]; }
    uint32_t mesh(uint32_t i) const { return s.patches[i].mesh; }
    Vec3 centroid(uint32_t i) const { return s.patches[i].centroid; }
    size_t vertices() const { return s.vertices.size(); }
    const Vec3& vertex_point(size_t v) const { return s.vertices[v]; }
    uint32_t vertex_mesh(size_t v) const { return s.vertex_mesh[v]; }
};

struct TableSource {
    const FaceTable& t;
    size_t size() const { return t.size(); }
    int nv(uint32_t i) const { return t.nv(i); }
    uint32_t vertex(uint32_t i, int k) const { return t.corner_index(i, k); }
    const Vec3& normal(uint32_t i) const { return t.normal(i); }
    const Vec3& corner(uint32_t i, int k) const { return t.corner(i, k); }
    uint32_t mesh(uint32_t i) const { return t.mesh(i); }
    Vec3 centroid(uint32_t i) const { return t.centroid(i); }
    size_t vertices() const { return t.points(); }
    const Vec3& vertex_point(size_t v) const { return t.point_list()[v]; }
    uint32_t vertex_mesh(size_t v) const { return t.point_mesh(v); }
};

template <class Src>
DisplayMesh build_display(const Src& set, double crease_angle_degrees) {
    const double cos_crease = std::cos(crease_angle_degrees * kPi / 180.0);
    const uint32_t n = static_cast<uint32_t>(set.size());
    DisplayMesh mesh;
    mesh.corners.resize(n);
    // Incidences (patch, corner) of every welded vertex, in patch order.
    std::vector<uint32_t> first(set.vertices() + 1, 0);
    for (uint32_t i = 0; i < n; ++i)
        for (int k = 0; k < set.nv(i); ++k) ++first[set.vertex(i, k) + 1];
    for (size_t v = 0; v < set.vertices(); ++v) first[v + 1] += first[v];
    std::vector<std::pair<uint32_t, int>> incidence(first.back());
    std::vector<uint32_t> cursor(first.begin(), first.end() - 1);
    for (uint32_t i = 0; i < n; ++i)
        for (int k = 0; k < set.nv(i); ++k) incidence[cursor[set.vertex(i, k)]++] = {i, k};

    // Split each vertex into one point per group of patches whose normals agree within the
    // crease angle (greedy, against the first normal of each group).
    std::vector<std::vector<std::pair<Vec3, uint32_t>>> groups(set.vertices());
    auto new_point = [&](uint32_t v) {
        mesh.points.push_back(set.vertex_point(v));
        mesh.point_mesh.push_back(set.vertex_mesh(v));
        return static_cast<uint32_t>(mesh.points.size() - 1);
    };
    auto point_for = [&](uint32_t v, const Vec3& n) {
        for (const auto& [gn, gp] : groups[v])
            if (dot(gn, n) >= cos_crease) return gp;
        uint32_t p = new_point(v);
        groups[v].emplace_back(n, p);
        return p;
    };
    for (size_t v = 0; v < set.vertices(); ++v)
        for (uint32_t k = first[v]; k < first[v + 1]; ++k) {
            const auto [pi, corner] = incidence[k];
            mesh.corners[pi][corner] = point_for(static_cast<uint32_t>(v), set.normal(pi));
        }
    for (uint32_t i = 0; i < n; ++i)
        if (set.nv(i) == 3) mesh.corners[i][3] = mesh.corners[i][2];
    mesh.anchors.resize(mesh.points.size());

    // T-vertices: a welded vertex of the same mesh exactly at the midpoint of a patch edge
    // (midpoints are computed as (a + b) / 2 everywhere, so they match bit for bit).
    std::vector<std::pair<PointKey, uint32_t>> welded(set.vertices());
    for (uint32_t v = 0; v < set.vertices(); ++v) welded[v] = {point_key(set.vertex_mesh(v), set.vertex_point(v)), v};
    std::sort(welded.begin(), welded.end());  // the key, then the lowest vertex first among equal keys
    auto find_welded = [&](const PointKey& key) -> int64_t {
        auto it = std::lower_bound(welded.begin(), welded.end(), key,
                                   [](const std::pair<PointKey, uint32_t>& e, const PointKey& k) { return e.first < k; });
        return it != welded.end() && it->first == key ? int64_t(it->second) : -1;
    };
    for (uint32_t i = 0; i < n; ++i) {
        const int nv = set.nv(i);
        const uint32_t patch_mesh = set.mesh(i);
        std::array<int64_t, 4> mid_point{-1, -1, -1, -1};
        bool any = false;
        for (int k = 0; k < nv; ++k) {
            const int64_t v = find_welded(point_key(patch_mesh, (set.corner(i, k) + set.corner(i, (k + 1) % nv)) * 0.5));
            if (v < 0) continue;
            const uint32_t point = point_for(static_cast<uint32_t>(v), set.normal(i));
            if (point >= mesh.anchors.size()) mesh.anchors.resize(point + 1);
            mesh.anchors[point] = {{mesh.corners[i][k], 0.5}, {mesh.corners[i][(k + 1) % nv], 0.5}};
            mid_point[k] = point;
            any = true;
        }
        if (!any) {
            mesh.faces.push_back(mesh.corners[i]);
            mesh.face_nv.push_back(static_cast<uint8_t>(nv));
            mesh.face_patch.push_back(i);
            mesh.face_code.push_back({0, 1, 2, static_cast<uint8_t>(nv == 4 ? 3 : 2)});
            continue;
        }
        // Fan around the centre, which takes the mean of the corners.
        mesh.points.push_back(set.centroid(i));
        mesh.point_mesh.push_back(patch_mesh);
        const uint32_t centre = static_cast<uint32_t>(mesh.points.size() - 1);
        mesh.anchors.resize(mesh.points.size());
        for (int k = 0; k < nv; ++k) mesh.anchors[centre].emplace_back(mesh.corners[i][k], 1.0 / nv);
        for (int k = 0; k < nv; ++k) {
            const uint32_t a = mesh.corners[i][k], b = mesh.corners[i][(k + 1) % nv];
            const uint8_t ca = static_cast<uint8_t>(k), cb = static_cast<uint8_t>((k + 1) % nv);
            auto tri = [&](uint32_t x, uint32_t y, uint8_t cx, uint8_t cy) {
                mesh.faces.push_back({centre, x, y, y});
                mesh.face_nv.push_back(3);
                mesh.face_patch.push_back(i);
                mesh.face_code.push_back({kCentre, cx, cy, cy});
            };
            if (mid_point[k] >= 0) {
                const uint32_t m = static_cast<uint32_t>(mid_point[k]);
                const uint8_t cm = static_cast<uint8_t>(kEdgeMid0 + k);
                tri(a, m, ca, cm);
                tri(m, b, cm, cb);
            } else {
                tri(a, b, ca, cb);
            }
        }
    }
    mesh.anchors.resize(mesh.points.size());

    // Boundary points: ends of display edges used by exactly one face.
    // (Sorted, then counted in runs: 8 bytes an edge, where a hash map took about 40.)
    std::vector<uint64_t> edges;
    edges.reserve(mesh.faces.size() * 4);
    for (size_t f = 0; f < mesh.faces.size(); ++f)
        for (int k = 0; k < mesh.face_nv[f]; ++k) {
            uint64_t a = mesh.faces[f][k], b = mesh.faces[f][(k + 1) % mesh.face_nv[f]];
            if (a > b) std::swap(a, b);
            edges.push_back((a << 32) | b);
        }
    std::sort(edges.begin(), edges.end());
    mesh.boundary.assign(mesh.points.size(), 0);
    for (size_t i = 0; i < edges.size();) {
        size_t j = i + 1;
        while (j < edges.size() && edges[j] == edges[i]) ++j;
        if (j - i == 1) {
            mesh.boundary[edges[i] >> 32] = 1;
            mesh.boundary[edges[i] & 0xFFFFFFFFu] = 1;
        }
        i = j;
    }
    return mesh;
}

template <class Src>
std::vector<RGB> values_at_points(const Src& set, const DisplayMesh& mesh, const std::vector<RGB>& patch_values) {
    const uint32_t n = static_cast<uint32_t>(set.size());
    const size_t np = mesh.points.size();
    std::vector<RGB> mean(np);
    std::vector<uint32_t> count(np, 0);
    for (uint32_t i = 0; i < n; ++i)
        for (int k = 0; k < set.nv(i); ++k) {
            mean[mesh.corners[i][k]] += patch_values[i];
            ++count[mesh.corners[i][k]];
        }
    for (size_t v = 0; v < np; ++v)
        if (count[v]) mean[v] = mean[v] / count[v];

    // Nearest interior neighbour of each boundary point along patch edges. T-vertices are not
    // boundary: they sit inside a coarser patch's edge.
    auto is_boundary = [&](uint32_t v) { return mesh.boundary[v] && mesh.anchors[v].empty(); };
    std::vector<uint32_t> nearest(np, UINT32_MAX);
    std::vector<double> nearest_d(np, 1e300);
    auto consider = [&](uint32_t b, uint32_t i) {
        if (!is_boundary(b) || mesh.boundary[i] || !mesh.anchors[i].empty()) return;
        double d = length(mesh.points[b] - mesh.points[i]);
        if (d < nearest_d[b] || (d == nearest_d[b] && i < nearest[b])) { nearest_d[b] = d; nearest[b] = i; }
    };
    for (uint32_t i = 0; i < n; ++i)
        for (int k = 0; k < set.nv(i); ++k)
            for (int l = 0; l < set.nv(i); ++l)
                if (l != k) consider(mesh.corners[i][k], mesh.corners[i][l]);

    std::vector<RGB> out = mean;
    for (size_t v = 0; v < np; ++v) {
        if (!is_boundary(static_cast<uint32_t>(v)) || nearest[v] == UINT32_MAX) continue;
        RGB e = mean[v] * 2.0 - mean[nearest[v]];
        out[v] = {std::max(e.x, 0.0), std::max(e.y, 0.0), std::max(e.z, 0.0)};
    }
    // Anchored points follow the points they hang on. An anchor may hang on another anchored
    // point (a corner that is itself a T-vertex of a coarser patch), so resolve repeatedly;
    // the chain is as deep as the hierarchy, a few passes settle it.
    for (int pass = 0; pass < 32; ++pass) {
        bool changed = false;
        for (size_t v = 0; v < np; ++v) {
            if (mesh.anchors[v].empty()) continue;
            RGB value;
            for (const auto& [p, w] : mesh.anchors[v]) value += out[p] * w;
            if (value.x != out[v].x || value.y != out[v].y || value.z != out[v].z) { out[v] = value; changed = true; }
        }
        if (!changed) break;
    }
    return out;
}


DisplayMesh build_display_mesh(const PatchSet& patches, double crease_angle_degrees) {
    return build_display(SetSource{patches}, crease_angle_degrees);
}

DisplayMesh build_display_mesh(const FaceTable& patches, double crease_angle_degrees) {
    if (patches.welding() != Welding::ByMesh) throw std::invalid_argument("build_display_mesh: a FaceTable welded by mesh");
    return build_display(TableSource{patches}, crease_angle_degrees);
}

std::vector<RGB> vertex_values(const PatchSet& patches, const DisplayMesh& mesh, const std::vector<RGB>& patch_values) {
    return values_at_points(SetSource{patches}, mesh, patch_values);
}

std::vector<RGB> vertex_values(const FaceTable& patches, const DisplayMesh& mesh, const std::vector<RGB>& patch_values) {
    return values_at_points(TableSource{patches}, mesh, patch_values);
}

}  // namespace hirad
