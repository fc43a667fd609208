#include "pipeline/geometry/hemicube.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>

namespace hirad {

namespace {

constexpr uint32_t kNoOwner = std::numeric_limits<uint32_t>::max();

// Near plane of every face, in metres. Clipping there only drops the part of a polygon
// within 1e-7 m of the hemicube's forward plane, which projects outside the face unless
// the polygon passes within 1e-7 m of the eye.
constexpr double kNearDepth = 1e-7;

// A face's view space as a signed permutation of the local frame coordinates (t, b, n):
// u (screen x) and v (screen y) across the face, w forward along its axis.
struct FaceAxes {
    int u, v, w;
    double w_sign;
};
// Top face looks along n; the side faces look along +t, -t, +b, -b with v = elevation, so
// their cells (v/w in [0, 1]) cover exactly the upper half above the tangent plane. The
// handedness of each view does not matter: the delta form factors are symmetric in u and
// the rasteriser accepts either winding.
constexpr FaceAxes kFaces[5] = {
    {0, 1, 2, 1.0}, {1, 2, 0, 1.0}, {1, 2, 0, -1.0}, {0, 2, 1, 1.0}, {0, 2, 1, -1.0},
};

// Cell grid of one face: columns span u/w in [-1, 1], rows span v/w from y0 (-1 top, 0 sides).
struct FaceGrid {
    int cols, rows;
    double y0, cell;
};

// Per-thread z-buffer of all five faces (top first, then the four sides), reused across calls.
struct ZBuffer {
    std::vector<double> inv_depth;  // 1/w of the nearest patch so far; 0 = empty
    std::vector<uint32_t> owner;
};

Vec3 to_face(const Vec3& local, const FaceAxes& f) {
    return {local[f.u], local[f.v], f.w_sign * local[f.w]};
}

// Sutherland-Hodgman against w > kNearDepth. A convex polygon of n vertices gains at most
// one vertex, so `out` needs n + 1 slots.
int clip_near(const Vec3* in, int n, Vec3* out) {
    int m = 0;
    for (int k = 0; k < n; ++k) {
        const Vec3& a = in[k];
        const Vec3& b = in[(k + 1) % n];
        const bool a_in = a.z > kNearDepth, b_in = b.z > kNearDepth;
        if (a_in) out[m++] = a;
        if (a_in != b_in) out[m++] = a + (b - a) * ((kNearDepth - a.z) / (b.z - a.z));
    }
    return m;
}

// First cell index whose centre is >= lo, and last whose centre is <= hi. Clamped in double
// before converting, since screen coordinates near the near plane can be enormous.
int first_cell(double lo, double origin, double cell, int count) {
    double c = std::ceil((lo - origin) / cell - 0.5);
    return static_cast<int>(std::clamp(c, 0.0, static_cast<double>(count)));
}
int last_cell(double hi, double origin, double cell, int count) {
    double c = std::floor((hi - origin) / cell - 0.5);
    return static_cast<int>(std::clamp(c, -1.0, static_cast<double>(count - 1)));
}

// Rasterises a convex polygon given in face view space, all vertices in front of the near
// plane, into one face's z-buffer. The polygon's plane N.P = d (view space) gives the depth
// exactly: 1/w = N.(u/w, v/w, 1) / d is affine in screen space, so no interpolation is needed.
// Each row is cut to the span allowed by every edge's half-plane, so only covered cells
// are visited.
void rasterise(const Vec3* poly, int n, const Vec3& plane_normal, double plane_d, const FaceGrid& g,
               uint32_t id, double* inv_depth, uint32_t* owner) {
    double sx[5], sy[5];
    double ymin = std::numeric_limits<double>::infinity(), ymax = -ymin;
    for (int k = 0; k < n; ++k) {
        sx[k] = poly[k].x / poly[k].z;
        sy[k] = poly[k].y / poly[k].z;
        ymin = std::min(ymin, sy[k]);
        ymax = std::max(ymax, sy[k]);
    }
    double twice_area = 0;
    for (int k = 0; k < n; ++k) {
        int l = (k + 1) % n;
        twice_area += sx[k] * sy[l] - sx[l] * sy[k];
    }
    if (twice_area == 0) return;  // seen edge-on
    const double s = twice_area > 0 ? 1.0 : -1.0;

    // Edge k is inside where A x + B y + C >= 0 (counter-clockwise after applying s).
    double ea[5], eb[5], ec[5];
    for (int k = 0; k < n; ++k) {
        int l = (k + 1) % n;
        double ex = sx[l] - sx[k], ey = sy[l] - sy[k];
        ea[k] = -s * ey;
        eb[k] = s * ex;
        ec[k] = s * (ey * sx[k] - ex * sy[k]);
    }

    const double inv_d = 1.0 / plane_d;
    const int r0 = first_cell(ymin, g.y0, g.cell, g.rows);
    const int r1 = last_cell(ymax, g.y0, g.cell, g.rows);
    for (int r = r0; r <= r1; ++r) {
        const double y = g.y0 + (r + 0.5) * g.cell;
        double lo = -1, hi = 1;
        bool empty = false;
        for (int k = 0; k < n; ++k) {
            const double val = eb[k] * y + ec[k];
            if (ea[k] > 0) lo = std::max(lo, -val / ea[k]);
            else if (ea[k] < 0) hi = std::min(hi, -val / ea[k]);
            else if (val < 0) empty = true;
        }
        if (empty || lo > hi) continue;
        const int c0 = first_cell(lo, -1.0, g.cell, g.cols);
        const int c1 = last_cell(hi, -1.0, g.cell, g.cols);
        const double row_depth = (plane_normal.y * y + plane_normal.z) * inv_d;
        const double dx = plane_normal.x * inv_d;
        double* depth_row = inv_depth + static_cast<size_t>(r) * g.cols;
        uint32_t* owner_row = owner + static_cast<size_t>(r) * g.cols;
        for (int c = c0; c <= c1; ++c) {
            const double x = -1.0 + (c + 0.5) * g.cell;
            const double d = row_depth + dx * x;
            if (d > depth_row[c]) {
                depth_row[c] = d;
                owner_row[c] = id;
            }
        }
    }
}

}  // namespace

Hemicube::Hemicube(const std::vector<Patch>& patches, const HemicubeOptions& options)
    : patches_(patches), options_(options) {
    const int res = options.resolution;
    // Side faces are res x res/2 cells of the same size as the top face's.
    if (res < 2 || res % 2 != 0) throw std::invalid_argument("hemicube resolution must be even and >= 2");
    if (options.points < 1) throw std::invalid_argument("hemicube points must be >= 1");
    const double cell = 2.0 / res, dA = cell * cell;
    top_delta_.resize(static_cast<size_t>(res) * res);
    for (int r = 0; r < res; ++r)
        for (int c = 0; c < res; ++c) {
            const double x = -1 + (c + 0.5) * cell, y = -1 + (r + 0.5) * cell;
            const double q = x * x + y * y + 1;
            top_delta_[static_cast<size_t>(r) * res + c] = dA / (kPi * q * q);
        }
    const int half = res / 2;
    side_delta_.resize(static_cast<size_t>(half) * res);
    for (int r = 0; r < half; ++r)
        for (int c = 0; c < res; ++c) {
            const double x = -1 + (c + 0.5) * cell, z = (r + 0.5) * cell;
            const double q = x * x + z * z + 1;
            side_delta_[static_cast<size_t>(r) * res + c] = z * dA / (kPi * q * q);
        }
}

void Hemicube::accumulate(const Vec3& x, const Vec3& n_in, uint32_t exclude, double weight,
                          std::vector<double>& accum) const {
    const Vec3 n = normalize(n_in);
    // Tangent from a world axis well away from n (some component of a unit vector is at most
    // 1/sqrt(3) < 0.6), so the cross product is well conditioned.
    const Vec3 axis = std::fabs(n.x) < 0.6 ? Vec3{1, 0, 0} : (std::fabs(n.y) < 0.6 ? Vec3{0, 1, 0} : Vec3{0, 0, 1});
    const Vec3 t = normalize(cross(n, axis));
    const Vec3 b = cross(n, t);

    const int res = options_.resolution;
    const size_t top_cells = static_cast<size_t>(res) * res;
    const size_t side_cells = static_cast<size_t>(res / 2) * res;
    const size_t total = top_cells + 4 * side_cells;
    thread_local ZBuffer zb;
    zb.inv_depth.assign(total, 0.0);
    zb.owner.assign(total, kNoOwner);

    const double cell = 2.0 / res;
    const FaceGrid grids[2] = {{res, res, -1.0, cell}, {res, res / 2, 0.0, cell}};

    for (uint32_t j = 0; j < patches_.size(); ++j) {
        if (j == exclude) continue;
        const Patch& pj = patches_[j];
        // Patches emit from their front only: x must be in front of j's plane.
        const Vec3 rel0 = pj.p[0] - x;
        const double plane_d = dot(pj.normal, rel0);
        if (!(plane_d < 0)) continue;

        Vec3 local[4];
        double max_height = -std::numeric_limits<double>::infinity();
        for (int k = 0; k < pj.nv; ++k) {
            const Vec3 r = pj.p[k] - x;
            local[k] = {dot(r, t), dot(r, b), dot(r, n)};
            max_height = std::max(max_height, local[k].z);
        }
        if (!(max_height > 0)) continue;  // entirely below the tangent plane
        const Vec3 local_normal{dot(pj.normal, t), dot(pj.normal, b), dot(pj.normal, n)};

        for (int f = 0; f < 5; ++f) {
            const FaceAxes& axes = kFaces[f];
            const bool side = f > 0;
            // Frustum culling: skip the face when every vertex is outside one of its planes
            // (u = +-w, v = +-w or v = 0 for sides, the near plane).
            Vec3 view[4];
            unsigned outside = ~0u;
            for (int k = 0; k < pj.nv; ++k) {
                view[k] = to_face(local[k], axes);
                const Vec3& p = view[k];
                unsigned code = (p.z <= kNearDepth ? 1u : 0u) | (p.x > p.z ? 2u : 0u) | (p.x < -p.z ? 4u : 0u) |
                                (p.y > p.z ? 8u : 0u) | ((side ? p.y < 0 : p.y < -p.z) ? 16u : 0u);
                outside &= code;
            }
            if (outside) continue;

            Vec3 clipped[5];
            const int m = clip_near(view, pj.nv, clipped);
            if (m < 3) continue;
            const size_t offset = side ? top_cells + (f - 1) * side_cells : 0;
            rasterise(clipped, m, to_face(local_normal, axes), plane_d, grids[side ? 1 : 0], j,
                      zb.inv_depth.data() + offset, zb.owner.data() + offset);
        }
    }

    for (size_t c = 0; c < top_cells; ++c)
        if (zb.owner[c] != kNoOwner) accum[zb.owner[c]] += weight * top_delta_[c];
    for (int f = 0; f < 4; ++f) {
        const uint32_t* owner = zb.owner.data() + top_cells + f * side_cells;
        for (size_t c = 0; c < side_cells; ++c)
            if (owner[c] != kNoOwner) accum[owner[c]] += weight * side_delta_[c];
    }
}

void Hemicube::row(uint32_t i, std::vector<std::pair<uint32_t, double>>& out) const {
    const Patch& pi = patches_[i];
    const int k = std::max(1, static_cast<int>(std::lround(std::sqrt(static_cast<double>(options_.points)))));
    double edge = 0;
    for (int e = 0; e < pi.nv; ++e) edge = std::max(edge, length(pi.p[(e + 1) % pi.nv] - pi.p[e]));
    // Lifting the eye off the surface puts coplanar neighbours strictly below the tangent
    // plane instead of leaving them to z-fight at depth zero.
    const Vec3 lift = pi.normal * (1e-6 * edge);
    const double weight = 1.0 / (static_cast<double>(k) * k);

    thread_local std::vector<double> accum;
    accum.assign(patches_.size(), 0.0);
    for (int a = 0; a < k; ++a)
        for (int c = 0; c < k; ++c)
            accumulate(pi.point((a + 0.5) / k, (c + 0.5) / k) + lift, pi.normal, i, weight, accum);

    out.clear();
    for (uint32_t j = 0; j < accum.size(); ++j)
        if (accum[j] != 0) out.emplace_back(j, accum[j]);
}

}  // namespace hirad
