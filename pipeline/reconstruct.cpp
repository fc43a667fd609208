#include "reconstruct.h"

#include <algorithm>
#include <cmath>
#include <unordered_map>

namespace hirad {

DisplayMesh build_display_mesh(const PatchSet& set, double crease_angle_degrees) {
    const double cos_crease = std::cos(crease_angle_degrees * kPi / 180.0);
    const auto& patches = set.patches;
    DisplayMesh mesh;
    mesh.corners.resize(patches.size());
    // Incidences (patch, corner) of every welded vertex, in patch order.
    std::vector<uint32_t> first(set.vertices.size() + 1, 0);
    for (const Patch& p : patches)
        for (int k = 0; k < p.nv; ++k) ++first[p.vertex[k] + 1];
    for (size_t v = 0; v < set.vertices.size(); ++v) first[v + 1] += first[v];
    std::vector<std::pair<uint32_t, int>> incidence(first.back());
    std::vector<uint32_t> cursor(first.begin(), first.end() - 1);
    for (uint32_t i = 0; i < patches.size(); ++i)
        for (int k = 0; k < patches[i].nv; ++k) incidence[cursor[patches[i].vertex[k]]++] = {i, k};

    // Split each vertex into one point per group of patches whose normals agree within the
    // crease angle (greedy, against the first normal of each group).
    std::vector<std::pair<Vec3, uint32_t>> groups;
    for (size_t v = 0; v < set.vertices.size(); ++v) {
        groups.clear();
        for (uint32_t k = first[v]; k < first[v + 1]; ++k) {
            const auto [pi, corner] = incidence[k];
            const Vec3& n = patches[pi].normal;
            uint32_t point = UINT32_MAX;
            for (const auto& [gn, gp] : groups)
                if (dot(gn, n) >= cos_crease) { point = gp; break; }
            if (point == UINT32_MAX) {
                point = static_cast<uint32_t>(mesh.points.size());
                mesh.points.push_back(set.vertices[v]);
                mesh.point_mesh.push_back(set.vertex_mesh[v]);
                groups.emplace_back(n, point);
            }
            mesh.corners[pi][corner] = point;
        }
    }
    for (uint32_t i = 0; i < patches.size(); ++i)
        if (patches[i].nv == 3) mesh.corners[i][3] = mesh.corners[i][2];

    // Boundary points: ends of edges used by exactly one patch.
    std::unordered_map<uint64_t, uint32_t> edge_use;
    for (uint32_t i = 0; i < patches.size(); ++i)
        for (int k = 0; k < patches[i].nv; ++k) {
            uint64_t a = mesh.corners[i][k], b = mesh.corners[i][(k + 1) % patches[i].nv];
            if (a > b) std::swap(a, b);
            ++edge_use[(a << 32) | b];
        }
    mesh.boundary.assign(mesh.points.size(), 0);
    for (const auto& [edge, uses] : edge_use)
        if (uses == 1) {
            mesh.boundary[edge >> 32] = 1;
            mesh.boundary[edge & 0xFFFFFFFFu] = 1;
        }
    return mesh;
}

std::vector<RGB> vertex_values(const PatchSet& set, const DisplayMesh& mesh, const std::vector<RGB>& patch_values) {
    const auto& patches = set.patches;
    const size_t np = mesh.points.size();
    std::vector<RGB> mean(np);
    std::vector<uint32_t> count(np, 0);
    for (uint32_t i = 0; i < patches.size(); ++i)
        for (int k = 0; k < patches[i].nv; ++k) {
            mean[mesh.corners[i][k]] += patch_values[i];
            ++count[mesh.corners[i][k]];
        }
    for (size_t v = 0; v < np; ++v)
        if (count[v]) mean[v] = mean[v] / count[v];

    // Nearest interior neighbour of each boundary point along patch edges.
    std::vector<uint32_t> nearest(np, UINT32_MAX);
    std::vector<double> nearest_d(np, 1e300);
    auto consider = [&](uint32_t b, uint32_t i) {
        if (!mesh.boundary[b] || mesh.boundary[i]) return;
        double d = length(mesh.points[b] - mesh.points[i]);
        if (d < nearest_d[b] || (d == nearest_d[b] && i < nearest[b])) { nearest_d[b] = d; nearest[b] = i; }
    };
    for (uint32_t i = 0; i < patches.size(); ++i)
        for (int k = 0; k < patches[i].nv; ++k)
            for (int l = 0; l < patches[i].nv; ++l)
                if (l != k) consider(mesh.corners[i][k], mesh.corners[i][l]);

    std::vector<RGB> out = mean;
    for (size_t v = 0; v < np; ++v) {
        if (!mesh.boundary[v] || nearest[v] == UINT32_MAX) continue;
        RGB e = mean[v] * 2.0 - mean[nearest[v]];
        out[v] = {std::max(e.x, 0.0), std::max(e.y, 0.0), std::max(e.z, 0.0)};
    }
    return out;
}

}  // namespace hirad
