#include "pipeline/geometry/formfactors.h"

#include <algorithm>
#include <cmath>

#include <tbb/parallel_for.h>

namespace hirad {

namespace {

// Keeps the part of the polygon strictly above the plane through x with normal n.
int clip_above(const Vec3& x, const Vec3& n, const Vec3* in, int count, Vec3* out) {
    int m = 0;
    for (int k = 0; k < count; ++k) {
        const Vec3& a = in[k];
        const Vec3& b = in[(k + 1) % count];
        double da = dot(a - x, n), db = dot(b - x, n);
        if (da > 0) out[m++] = a;
        if ((da > 0) != (db > 0)) out[m++] = a + (b - a) * (da / (da - db));
    }
    return m;
}

}  // namespace

namespace {

// Solid angle of the spherical triangle of unit vectors a, b, c (Van Oosterom and Strackee 1983).
double spherical_triangle_area(const Vec3& a, const Vec3& b, const Vec3& c) {
    const double num = std::abs(dot(a, cross(b, c)));
    const double den = 1 + dot(a, b) + dot(b, c) + dot(c, a);
    return 2 * std::atan2(num, den);
}

// The angle at vertex p of the spherical triangle p, q, r: between the great circles p-q and p-r.
double spherical_angle(const Vec3& p, const Vec3& q, const Vec3& r) {
    const Vec3 a = normalize(cross(p, q)), b = normalize(cross(p, r));
    return std::acos(std::clamp(dot(a, b), -1.0, 1.0));
}

// A direction uniform over the spherical triangle a, b, c of solid angle `area` (Arvo 1995:
// the sub-triangle a, b, c' of area u1 x area, then a point along the arc b-c' with z = cos of
// its arc from b drawn so that the density is uniform).
Vec3 sample_spherical_triangle(const Vec3& a, const Vec3& b, const Vec3& c, double area, double u1, double u2) {
    const double alpha = spherical_angle(a, b, c);
    const double cos_c = dot(a, b);
    const double sub = u1 * area;
    const double s = std::sin(sub - alpha), t = std::cos(sub - alpha);
    const double uu = t - std::cos(alpha), v = s + std::sin(alpha) * cos_c;
    const double den = (v * s + uu * t) * std::sin(alpha);
    const double q = den != 0 ? std::clamp(((v * t - uu * s) * std::cos(alpha) - v) / den, -1.0, 1.0) : 1.0;
    const Vec3 cp = a * q + normalize(c - a * dot(c, a)) * std::sqrt(std::max(0.0, 1 - q * q));
    const double z = 1 - u2 * (1 - dot(cp, b));
    const Vec3 w = cp - b * dot(cp, b);
    const double wl = length(w);
    if (!(wl > 0)) return b;
    return b * z + w * (std::sqrt(std::max(0.0, 1 - z * z)) / wl);
}

// sample_polygon_by_form_factor on the polygon already clipped to x's tangent plane (m >= 3
// corners), `p0` a corner of the unclipped polygon (its plane).
bool sample_clipped(const Vec3& x, const Vec3& n, const Vec3* clipped, int m, const Vec3& p0, const Vec3& poly_normal,
                    Rng& rng, Vec3& y, int tries) {
    // The clipped polygon as a fan of spherical triangles seen from x, drawn by solid angle.
    Vec3 dir[8];
    for (int k = 0; k < m; ++k) {
        const Vec3 e = clipped[k] - x;
        const double l = length(e);
        if (!(l > 0)) return false;
        dir[k] = e / l;
    }
    double cdf[8], total = 0;
    for (int k = 1; k + 1 < m; ++k) {
        total += spherical_triangle_area(dir[0], dir[k], dir[k + 1]);
        cdf[k] = total;
    }
    if (!(total > 1e-12)) return false;
    const double denom = dot(poly_normal, p0 - x);
    for (int i = 0; i < tries; ++i) {
        const double u0 = rng.uniform(), u1 = rng.uniform(), u2 = rng.uniform();
        const double pick = u0 * total;
        int k = 1;
        while (k + 2 < m && cdf[k] < pick) ++k;
        const double lo = k > 1 ? cdf[k - 1] : 0.0, area = cdf[k] - lo;
        if (!(area > 0)) continue;
        const Vec3 w = sample_spherical_triangle(dir[0], dir[k], dir[k + 1], area, std::clamp((pick - lo) / area, 0.0, 1.0), u1);
        const double cos_x = dot(w, n);
        if (!(u2 < cos_x)) continue;  // kept with probability cos theta_x
        const double along = dot(poly_normal, w);
        if (!(along < 0)) continue;
        y = x + w * (denom / along);
        return true;
    }
    return false;
}

// Lambert's contour sum over the polygon already clipped to x's tangent plane.
double clipped_form_factor(const Vec3& x, const Vec3& n, const Vec3* clipped, int m) {
    double sum = 0;
    for (int k = 0; k < m; ++k) {
        Vec3 a = clipped[k] - x, b = clipped[(k + 1) % m] - x;
        Vec3 c = cross(a, b);
        double lc = length(c);
        if (lc <= 0) continue;
        double gamma = std::atan2(lc, dot(a, b));
        sum += gamma * dot(n, c) / lc;
    }
    return std::fabs(sum) / (2 * kPi);
}

}  // namespace

bool sample_polygon_by_form_factor(const Vec3& x, const Vec3& n, const Vec3* poly, int nv, const Vec3& poly_normal,
                                   Rng& rng, Vec3& y, int tries) {
    if (dot(x - poly[0], poly_normal) <= 0) return false;  // behind the emitting side
    Vec3 clipped[8];
    const int m = clip_above(x, n, poly, nv, clipped);
    if (m < 3) return false;
    return sample_clipped(x, n, clipped, m, poly[0], poly_normal, rng, y, tries);
}

double point_polygon_form_factor(const Vec3& x, const Vec3& n, const Vec3* poly, int nv, const Vec3& poly_normal) {
    if (dot(x - poly[0], poly_normal) <= 0) return 0;  // behind the emitting side
    Vec3 clipped[8];
    const int m = clip_above(x, n, poly, nv, clipped);
    if (m < 3) return 0;
    return clipped_form_factor(x, n, clipped, m);
}

double point_polygon_form_factor_by_quadrature(const Vec3& x, const Vec3& n, const Vec3* poly, int nv,
                                               const Vec3& poly_normal, double area) {
    if (dot(x - poly[0], poly_normal) <= 0) return 0;  // behind the emitting side
    for (int k = 0; k < nv; ++k)
        if (!(dot(poly[k] - x, n) > 0)) return point_polygon_form_factor(x, n, poly, nv, poly_normal);
    auto kernel = [&](const Vec3& y) {
        const Vec3 d = y - x;
        const double r2 = dot(d, d);
        return std::max(0.0, dot(n, d)) * std::max(0.0, -dot(poly_normal, d)) / (kPi * r2 * r2);
    };
    if (nv == 3) {
        const Vec3 e1 = poly[1] - poly[0], e2 = poly[2] - poly[0];
        const double sum = kernel(poly[0] + e1 / 6.0 + e2 / 6.0) + kernel(poly[0] + e1 * (2 / 3.0) + e2 / 6.0) +
                           kernel(poly[0] + e1 / 6.0 + e2 * (2 / 3.0));
        return sum * area / 3;
    }
    // y(s, t) = (1-s)(1-t) p0 + s(1-t) p1 + s t p2 + (1-s) t p3 at the Gauss points of [0, 1]^2
    // (weights 1/4), times |dy/ds x dy/dt|.
    const double g[2] = {0.5 - 0.5 / std::sqrt(3.0), 0.5 + 0.5 / std::sqrt(3.0)};
    double sum = 0;
    for (double t : g)
        for (double s : g) {
            const Vec3 y = poly[0] * ((1 - s) * (1 - t)) + poly[1] * (s * (1 - t)) + poly[2] * (s * t) +
                           poly[3] * ((1 - s) * t);
            const Vec3 ds = (poly[1] - poly[0]) * (1 - t) + (poly[2] - poly[3]) * t;
            const Vec3 dt = (poly[3] - poly[0]) * (1 - s) + (poly[2] - poly[1]) * s;
            sum += 0.25 * length(cross(ds, dt)) * kernel(y);
        }
    return sum;
}

double point_polygon_form_factor_and_point(const Vec3& x, const Vec3& n, const Vec3* poly, int nv,
                                           const Vec3& poly_normal, Rng& rng, Vec3& y, bool& drawn) {
    drawn = false;
    if (dot(x - poly[0], poly_normal) <= 0) return 0;
    Vec3 clipped[8];
    const int m = clip_above(x, n, poly, nv, clipped);
    if (m < 3) return 0;
    const double f = clipped_form_factor(x, n, clipped, m);
    if (f <= 0) return f;
    drawn = sample_clipped(x, n, clipped, m, poly[0], poly_normal, rng, y, 32);
    return f;
}

double parallel_rectangles_form_factor(double a, double b, double c) {
    const double X = a / c, Y = b / c;
    const double X2 = X * X, Y2 = Y * Y;
    double t = std::log(std::sqrt((1 + X2) * (1 + Y2) / (1 + X2 + Y2)));
    t += X * std::sqrt(1 + Y2) * std::atan(X / std::sqrt(1 + Y2));
    t += Y * std::sqrt(1 + X2) * std::atan(Y / std::sqrt(1 + X2));
    t -= X * std::atan(X) + Y * std::atan(Y);
    return 2 * t / (kPi * X * Y);
}

double perpendicular_rectangles_form_factor(double l, double h, double w) {
    const double H = h / l, W = w / l;
    const double H2 = H * H, W2 = W * W;
    double t = W * std::atan(1 / W) + H * std::atan(1 / H) - std::sqrt(H2 + W2) * std::atan(1 / std::sqrt(H2 + W2));
    double l1 = (1 + W2) * (1 + H2) / (1 + W2 + H2);
    double l2 = W2 * (1 + W2 + H2) / ((1 + W2) * (W2 + H2));
    double l3 = H2 * (1 + H2 + W2) / ((1 + H2) * (H2 + W2));
    t += 0.25 * std::log(l1 * std::pow(l2, W2) * std::pow(l3, H2));
    return t / (kPi * W);
}

RayCastFormFactors::RayCastFormFactors(const std::vector<Patch>& patches, const Visibility& visibility,
                                       const RayCastOptions& options)
    : patches_(patches), visibility_(visibility), options_(options) {}

bool RayCastFormFactors::facing(uint32_t from, uint32_t to) const {
    // Some corner of `to` must lie in front of `from` and vice versa.
    const Patch& a = patches_[from];
    const Patch& b = patches_[to];
    bool b_in_front = false, a_in_front = false;
    const double eps = 1e-12 * visibility_.scene_size();
    for (int k = 0; k < b.nv; ++k) b_in_front |= dot(b.p[k] - a.centroid, a.normal) > eps;
    for (int k = 0; k < a.nv; ++k) a_in_front |= dot(a.p[k] - b.centroid, b.normal) > eps;
    return a_in_front && b_in_front;
}

namespace {

// Stratified jittered points on a patch: a g x g grid of cells, one point per cell. The
// target points use a shuffled cell order so that sample k on one patch is paired with an
// unrelated cell on the other.
void stratified(Rng& rng, int g, double* s, double* t) {
    for (int j = 0; j < g; ++j)
        for (int i = 0; i < g; ++i) {
            s[j * g + i] = (i + rng.uniform()) / g;
            t[j * g + i] = (j + rng.uniform()) / g;
        }
}

// Shuffles the target cells (Fisher-Yates) so ray k joins unrelated strata on the two patches.
void shuffle_cells(Rng& rng, int n, double* s, double* t) {
    for (int k = n - 1; k > 0; --k) {
        int r = static_cast<int>(rng.next() % uint64_t(k + 1));
        std::swap(s[k], s[r]);
        std::swap(t[k], t[r]);
    }
}

int grid_size(int samples) { return std::max(1, static_cast<int>(std::lround(std::sqrt(double(samples))))); }

}  // namespace

double RayCastFormFactors::form_factor(uint32_t i, uint32_t j) const {
    if (i == j || !facing(i, j)) return 0;
    const Patch& a = patches_[i];
    const Patch& b = patches_[j];
    const int g = grid_size(options_.samples), n = g * g;
    Rng rng(hash_pair(i, j, options_.seed ^ 0xA5A5A5A5ull));
    std::vector<double> s(n), t(n), s2(n), t2(n), f(n);
    stratified(rng, g, s.data(), t.data());
    stratified(rng, g, s2.data(), t2.data());
    shuffle_cells(rng, n, s2.data(), t2.data());
    std::vector<Vec3> from(n), to(n);
    const double lift = visibility_.ray_offset();
    for (int k = 0; k < n; ++k) {
        Vec3 x = a.point(s[k], t[k]);
        f[k] = point_polygon_form_factor(x, a.normal, b.p.data(), b.nv, b.normal);
        from[k] = x + a.normal * lift;
        to[k] = b.point(s2[k], t2[k]) + b.normal * lift;
    }
    std::vector<uint8_t> vis(n);
    visibility_.segments_visible(from.data(), to.data(), n, vis.data());
    double sum = 0;
    for (int k = 0; k < n; ++k) sum += f[k] * vis[k];
    return sum / n;
}

double RayCastFormFactors::coupling(uint32_t i, uint32_t j) const {
    std::vector<std::pair<uint32_t, float>> out;
    batch_couplings(i, {j}, out);
    return out.empty() ? 0.0 : out[0].second;
}

void RayCastFormFactors::couplings_of(uint32_t i, std::vector<std::pair<uint32_t, float>>& out) const {
    std::vector<uint32_t> partners;
    for (uint32_t j = 0; j < patches_.size(); ++j)
        if (j != i && facing(i, j)) partners.push_back(j);
    batch_couplings(i, partners, out);
}

void RayCastFormFactors::upper_couplings_of(uint32_t i, std::vector<std::pair<uint32_t, float>>& out) const {
    std::vector<uint32_t> partners;
    for (uint32_t j = i + 1; j < patches_.size(); ++j)
        if (facing(i, j)) partners.push_back(j);
    batch_couplings(i, partners, out);
}

void RayCastFormFactors::batch_couplings(uint32_t i, const std::vector<uint32_t>& all_partners,
                                         std::vector<std::pair<uint32_t, float>>& out) const {
    // Partners are processed in blocks, in parallel, and the blocks' results concatenated in
    // order, so the output does not depend on the thread count.
    constexpr size_t kBlock = 512;
    const size_t blocks = (all_partners.size() + kBlock - 1) / kBlock;
    std::vector<std::vector<std::pair<uint32_t, float>>> results(blocks);
    auto run_block = [&](size_t blk) {
        std::vector<uint32_t> partners(all_partners.begin() + blk * kBlock,
                                       all_partners.begin() + std::min(all_partners.size(), (blk + 1) * kBlock));
        couplings_block(i, partners, results[blk]);
    };
    if (blocks > 1) tbb::parallel_for(size_t(0), blocks, run_block);
    else if (blocks == 1) run_block(0);
    for (const auto& r : results) out.insert(out.end(), r.begin(), r.end());
}

void RayCastFormFactors::couplings_block(uint32_t i, const std::vector<uint32_t>& partners,
                                         std::vector<std::pair<uint32_t, float>>& out) const {
    const int g = grid_size(options_.samples), n = g * g;
    const double lift = visibility_.ray_offset();
    std::vector<Vec3> from, to;
    std::vector<double> weight;
    std::vector<uint32_t> owner;
    std::vector<double> s(n), t(n), s2(n), t2(n);
    from.reserve(partners.size() * n);
    to.reserve(partners.size() * n);
    for (uint32_t pi = 0; pi < partners.size(); ++pi) {
        uint32_t j = partners[pi];
        // The pair is always sampled on its smaller patch (ties: lower index), with random
        // numbers keyed by the unordered pair: coupling(i, j) == coupling(j, i) bit for bit.
        uint32_t lo = std::min(i, j), hi = std::max(i, j);
        bool lo_samples = patches_[lo].area <= patches_[hi].area;
        const Patch& a = patches_[lo_samples ? lo : hi];
        const Patch& b = patches_[lo_samples ? hi : lo];
        Rng rng(hash_pair(lo, hi, options_.seed));
        stratified(rng, g, s.data(), t.data());
        stratified(rng, g, s2.data(), t2.data());
        shuffle_cells(rng, n, s2.data(), t2.data());
        for (int k = 0; k < n; ++k) {
            Vec3 x = a.point(s[k], t[k]);
            double f = point_polygon_form_factor(x, a.normal, b.p.data(), b.nv, b.normal);
            if (f <= 0) continue;
            from.push_back(x + a.normal * lift);
            to.push_back(b.point(s2[k], t2[k]) + b.normal * lift);
            weight.push_back(f * a.area / n);
            owner.push_back(pi);
        }
    }
    std::vector<uint8_t> vis(from.size());
    visibility_.segments_visible(from.data(), to.data(), from.size(), vis.data());
    std::vector<double> g_sum(partners.size(), 0.0);
    for (size_t r = 0; r < from.size(); ++r)
        if (vis[r]) g_sum[owner[r]] += weight[r];
    for (uint32_t pi = 0; pi < partners.size(); ++pi)
        if (g_sum[pi] > 0) out.emplace_back(partners[pi], static_cast<float>(g_sum[pi]));
}

}  // namespace hirad
