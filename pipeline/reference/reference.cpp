#include "pipeline/reference/reference.h"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <stdexcept>

namespace hirad {

namespace {

// Panes one bounce ray may pass before the path is ended (a ray caught between panes).
constexpr int kMaxPanes = 16;

struct Emitters {
    std::vector<uint32_t> patch;
    std::vector<double> cdf;  // by emitted power (sum of channels x area)
    double total = 0;
};

// The patch's own emission (Patch::self_emission), clamped at 0 (the path tracer draws from it).
RGB own_emission(const Patch& p) {
    RGB e = p.self_emission();
    return {std::max(e.x, 0.0), std::max(e.y, 0.0), std::max(e.z, 0.0)};
}

Emitters collect_emitters(const std::vector<Patch>& patches) {
    Emitters e;
    for (uint32_t i = 0; i < patches.size(); ++i) {
        const RGB s = own_emission(patches[i]);
        double power = (s.x + s.y + s.z) * patches[i].area;
        if (power <= 0) continue;
        e.total += power;
        e.patch.push_back(i);
        e.cdf.push_back(e.total);
    }
    return e;
}

void frame(const Vec3& n, Vec3& t, Vec3& b) {
    t = normalize(std::fabs(n.x) > 0.5 ? cross(n, Vec3{0, 1, 0}) : cross(n, Vec3{1, 0, 0}));
    b = cross(n, t);
}

// Irradiance at x (normal n) arriving directly from the emitters, one sample.
RGB direct(const std::vector<Patch>& patches, const Visibility& vis, const Emitters& em, const Vec3& x, const Vec3& n,
           double lift, Rng& rng) {
    const double u = rng.uniform() * em.total;
    const size_t k = std::min<size_t>(std::upper_bound(em.cdf.begin(), em.cdf.end(), u) - em.cdf.begin(), em.patch.size() - 1);
    const Patch& q = patches[em.patch[k]];
    const RGB qe = own_emission(q);
    const double pick = ((qe.x + qe.y + qe.z) * q.area) / em.total;
    Vec3 y = q.point(rng.uniform(), rng.uniform());
    Vec3 d = y - x;
    double r2 = dot(d, d);
    if (r2 <= 0) return {};
    double r = std::sqrt(r2);
    double cos_x = dot(n, d) / r, cos_y = -dot(q.normal, d) / r;
    if (cos_x <= 0 || cos_y <= 0) return {};
    Vec3 from = x + n * lift, to = y + q.normal * lift;
    double pass = 1;
    if (vis.has_glass()) {  // through glass with its T(theta), pane by pane
        float t = 0;
        vis.segments_transmittance(&from, &to, 1, &t);
        pass = t;
    } else {
        uint8_t visible = 0;
        vis.segments_visible(&from, &to, 1, &visible);
        pass = visible;
    }
    if (!(pass > 0)) return {};
    // L_e = E / pi; pdf of y is pick / A_q.
    return qe * (pass * cos_x * cos_y / (r2 * kPi) * q.area / pick);
}

}  // namespace

std::vector<ReferenceEstimate> reference_radiance(const std::vector<Patch>& patches, const Visibility& vis,
                                                  const std::vector<uint32_t>& patch, const std::vector<Vec2>& st,
                                                  const ReferenceOptions& opt,
                                                  const std::vector<Luminaire>& luminaires) {
    if (patch.size() != st.size()) throw std::invalid_argument("reference: one (s, t) per patch index");
    const Emitters em = collect_emitters(patches);
    const double lift = vis.ray_offset();
    std::vector<ReferenceEstimate> out(patch.size());
    tbb::parallel_for(size_t(0), patch.size(), [&](size_t q) {
        if (patch[q] >= patches.size()) throw std::invalid_argument("reference: patch index out of range");
        const Patch& p0 = patches[patch[q]];
        const Vec3 x0 = p0.point(st[q].u, st[q].v);
        Rng rng(hash_pair(q, patch[q], opt.seed ^ 0x5EEDull));
        RGB sum, sum2;
        for (int path = 0; path < opt.paths; ++path) {
            // Radiance reflected at x0: (rho/pi) H(x0); beta carries the product of the
            // reflectances along the path (cosine sampling cancels cos/pdf = pi).
            RGB l;
            RGB beta = p0.reflectance / kPi;
            Vec3 x = x0, n = p0.normal;
            const bool lit = em.total > 0 || !luminaires.empty();
            for (int bounce = 0; lit || bounce == 0; ++bounce) {
                if (em.total > 0) l += mul(beta, direct(patches, vis, em, x, n, lift, rng));
                if (!luminaires.empty()) l += mul(beta, luminaire_irradiance_at(luminaires, &vis, x, n, lift));
                Vec3 t, b;
                frame(n, t, b);
                double r1 = rng.uniform(), r2 = rng.uniform();
                double rad = std::sqrt(r1), phi = 2 * kPi * r2;
                Vec3 dir = t * (rad * std::cos(phi)) + b * (rad * std::sin(phi)) + n * std::sqrt(std::max(0.0, 1 - r1));
                // The next surface that scatters: glass on the way is passed (T) or reflects.
                Vec3 origin = x + n * lift;
                RayHit hit = vis.intersect(origin, dir);
                RGB gain;     // the path weight's factor at the scattering vertex
                Vec3 side;    // the normal of the side the path leaves from
                bool scattered = false;
                for (int pane = 0; hit.patch >= 0 && pane < kMaxPanes; ++pane) {
                    const Patch& h = patches[hit.patch];
                    const double c = dot(h.normal, dir);
                    const double t_glass = vis.glass_transmittance(hit.patch, std::fabs(c));
                    if (t_glass <= 0) {
                        if (c >= 0) break;  // back faces neither emit nor reflect
                        // L_in = (rho_h / pi) H(hit) and H = pi <L_in> under cosine sampling:
                        // the path's weight gains rho_h.
                        gain = h.reflectance;
                        side = h.normal;
                        scattered = true;
                        break;
                    }
                    const double pr = max_component(h.reflectance), total = t_glass + pr;
                    // the point on the glass, from the lifted origin the ray left (x + dir t
                    // falls short of the pane by the lift, and the next ray would meet it again)
                    const Vec3 at = origin + dir * hit.t;
                    if (rng.uniform() * total < t_glass) {  // through, weight T / (T / total)
                        beta = beta * total;
                        x = at;
                        n = c < 0 ? h.normal * -1.0 : h.normal;  // onwards: lifted past the pane
                        origin = x + n * lift;
                        hit = vis.intersect(origin, dir);
                        continue;
                    }
                    gain = h.reflectance * (total / pr);  // reflected on the side met
                    side = c < 0 ? h.normal : h.normal * -1.0;
                    scattered = true;
                    break;
                }
                if (!scattered) break;
                beta = mul(beta, gain);
                if (bounce + 1 >= opt.min_bounces) {
                    double survive = std::min(0.95, max_component(gain));
                    if (survive <= 0 || rng.uniform() >= survive) break;
                    beta = beta / survive;
                }
                x = origin + dir * hit.t;
                n = side;
            }
            RGB value = own_emission(p0) / kPi + l;
            sum += value;
            sum2 += mul(value, value);
        }
        const double m = opt.paths;
        RGB mean = sum / m;
        RGB var = sum2 / m - mul(mean, mean);
        out[q].radiance = mean;
        out[q].standard_error = {std::sqrt(std::max(var.x, 0.0) / std::max(m - 1, 1.0)),
                                 std::sqrt(std::max(var.y, 0.0) / std::max(m - 1, 1.0)),
                                 std::sqrt(std::max(var.z, 0.0) / std::max(m - 1, 1.0))};
    });
    return out;
}

}  // namespace hirad
