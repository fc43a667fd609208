#include "pipeline/geometry/luminaire.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <stdexcept>

#include "pipeline/geometry/patches.h"
#include "pipeline/geometry/visibility.h"

namespace hirad {

namespace {

constexpr double kDeg = kPi / 180.0;

uint64_t bits(double v) {
    uint64_t b;
    std::memcpy(&b, &v, sizeof b);
    return b;
}

[[noreturn]] void refuse(const Luminaire& l, const std::string& problem) {
    throw std::invalid_argument("luminaire '" + l.name + "': " + problem);
}

}  // namespace

void Luminaire::validate() const {
    if (points.empty()) refuse(*this, "no emitting points");
    if (weights.size() != points.size()) refuse(*this, "weights and points differ in number");
    double sum = 0;
    for (size_t k = 0; k < points.size(); ++k) {
        if (!isfinite(points[k])) refuse(*this, "point " + std::to_string(k) + " is not finite");
        if (!(weights[k] >= 0) || !std::isfinite(weights[k])) refuse(*this, "weight " + std::to_string(k) + " is negative or not finite");
        sum += weights[k];
    }
    if (std::fabs(sum - 1) > 1e-9) refuse(*this, "weights sum to " + std::to_string(sum) + ", not 1");
    if (!isfinite(colour) || colour.x < 0 || colour.y < 0 || colour.z < 0) refuse(*this, "colour is negative or not finite");
    if (distant) {
        for (size_t k = 0; k < points.size(); ++k)
            if (std::fabs(length(points[k]) - 1) > 1e-9)
                refuse(*this, "direction " + std::to_string(k) + " is not a unit vector");
        if (!(illuminance >= 0) || !std::isfinite(illuminance)) refuse(*this, "illuminance is negative or not finite");
        if (!tints.empty() && tints.size() != points.size()) refuse(*this, "tints and directions differ in number");
        for (const RGB& t : tints)
            if (!isfinite(t) || t.x < 0 || t.y < 0 || t.z < 0) refuse(*this, "a tint is negative or not finite");
        return;
    }
    for (int a = 0; a < 3; ++a)
        if (!isfinite(axis[a]) || std::fabs(length(axis[a]) - 1) > 1e-9) refuse(*this, "frame axis " + std::to_string(a) + " is not a unit vector");
    if (std::fabs(dot(axis[0], axis[1])) > 1e-9 || std::fabs(dot(axis[1], axis[2])) > 1e-9 ||
        std::fabs(dot(axis[0], axis[2])) > 1e-9)
        refuse(*this, "frame axes are not orthogonal");
    if (dot(cross(axis[0], axis[1]), axis[2]) < 0) refuse(*this, "frame is not right-handed");
    if (nc < 1 || ng < 2) refuse(*this, "the candela table needs at least 1 C plane and 2 gamma angles");
    if (candela.size() != size_t(nc) * size_t(ng)) refuse(*this, "the candela table is not nc x ng");
    for (double v : candela)
        if (!(v >= 0) || !std::isfinite(v)) refuse(*this, "a candela value is negative or not finite");
    if (!isfinite(colour) || colour.x < 0 || colour.y < 0 || colour.z < 0) refuse(*this, "colour is negative or not finite");
}

double Luminaire::intensity(const Vec3& d) const {
    const double len = length(d);
    if (!(len > 0)) return 0;
    const double lx = dot(d, axis[0]) / len, ly = dot(d, axis[1]) / len, lz = dot(d, axis[2]) / len;
    const double gamma = std::acos(std::clamp(-lz, -1.0, 1.0));  // 0 .. pi
    const double gj = gamma / kPi * (ng - 1);
    const int j0 = std::min(int(gj), ng - 2);
    const double v = gj - j0;
    if (nc == 1) return candela[j0] * (1 - v) + candela[j0 + 1] * v;
    double c = std::atan2(ly, lx);  // -pi .. pi
    if (c < 0) c += 2 * kPi;
    double ci = c / (2 * kPi) * nc;
    int i0 = int(ci);
    double u = ci - i0;
    if (i0 >= nc) { i0 = 0; u = 0; }
    const int i1 = (i0 + 1) % nc;
    const double* a = &candela[size_t(i0) * ng];
    const double* b = &candela[size_t(i1) * ng];
    const double ea = a[j0] * (1 - v) + a[j0 + 1] * v, eb = b[j0] * (1 - v) + b[j0 + 1] * v;
    return ea * (1 - u) + eb * u;
}

double Luminaire::table_flux() const {
    if (distant) return 0;
    const double h = kPi / (ng - 1);
    const double dc = 2 * kPi / nc;
    double total = 0;
    for (int j = 0; j + 1 < ng; ++j) {
        const double g0 = j * h, g1 = (j + 1) * h;
        const double S = std::cos(g0) - std::cos(g1);
        const double B = (std::sin(g1) - std::sin(g0) - h * std::cos(g1)) / h;
        for (int i = 0; i < nc; ++i) {
            const int i1 = (i + 1) % nc;
            const double m0 = 0.5 * (candela[size_t(i) * ng + j] + candela[size_t(i1) * ng + j]);
            const double m1 = 0.5 * (candela[size_t(i) * ng + j + 1] + candela[size_t(i1) * ng + j + 1]);
            total += dc * (m0 * (S - B) + m1 * B);
        }
    }
    return total;
}

uint64_t Luminaire::fingerprint() const {
    uint64_t f = 0x1A77ull;
    for (size_t k = 0; k < points.size(); ++k) {
        for (int a = 0; a < 3; ++a) f = hash_pair(f, bits(points[k][a]), 11);
        f = hash_pair(f, bits(weights[k]), 12);
    }
    for (int a = 0; a < 3; ++a)
        for (int b = 0; b < 3; ++b) f = hash_pair(f, bits(axis[a][b]), 13);
    f = hash_pair(f, (uint64_t(nc) << 32) | uint64_t(ng), 14);
    for (double v : candela) f = hash_pair(f, bits(v), 15);
    for (int a = 0; a < 3; ++a) f = hash_pair(f, bits(colour[a]), 16);
    if (distant) f = hash_pair(f, bits(illuminance), 18);
    for (const RGB& t : tints)
        for (int a = 0; a < 3; ++a) f = hash_pair(f, bits(t[a]), 20);
    if (interleave) f = hash_pair(f, 1, 21);
    return f;
}

Luminaire distant_light(std::string name, std::vector<Vec3> directions, std::vector<double> weights,
                        double illuminance, RGB colour, std::vector<RGB> tints) {
    Luminaire l;
    l.name = std::move(name);
    l.distant = true;
    for (Vec3& d : directions) {
        const double len = length(d);
        if (len > 0 && std::isfinite(len)) d = d / len;
    }
    l.points = std::move(directions);
    l.weights = std::move(weights);
    l.illuminance = illuminance;
    l.colour = colour;
    l.tints = std::move(tints);
    l.axis[0] = {1, 0, 0};
    l.axis[1] = {0, 1, 0};
    l.axis[2] = {0, 0, 1};
    l.candela = {0, 0};
    l.validate();
    return l;
}

uint64_t luminaires_fingerprint(const std::vector<Luminaire>& luminaires) {
    uint64_t f = 0x10Eull;
    for (const Luminaire& l : luminaires) f = hash_pair(f, l.fingerprint(), 17);
    return f;
}

namespace {

// The light of every luminaire point that reaches x, one shadow ray each (from `start`, x
// lifted off its surface): per arrival the unit direction towards the light, w_k I, r^2, the
// receiver's cosine (1 without a normal) and the luminaire. With a normal, points below the
// receiver's plane are skipped before any ray is traced.
struct Arrivals {
    std::vector<Vec3> from, to, dir;
    std::vector<double> wi, r2, cosr;
    std::vector<uint32_t> owner;
    std::vector<RGB> tint;    // per arrival: the light's colour (times its direction's tint)
    std::vector<float> seen;  // transmittance of the shadow ray (0 blocked, 1 open, between: glass)

    // stride > 1: of a sky (more than kSkyDirections directions) only the directions j with
    // j % stride == offset, their weights times stride (one share of an interleaved set).
    // Lights marked `interleave` share one numbering of their directions (sky_index), from
    // sky_start (the directions of such lights before this list, when a sky comes in parts).
    void collect(const std::vector<Luminaire>& luminaires, const Visibility* visibility, const Vec3& x,
                 const Vec3* n, const Vec3& start, size_t stride = 1, size_t offset = 0, size_t sky_start = 0) {
        from.clear(); to.clear(); dir.clear(); wi.clear(); r2.clear(); cosr.clear(); owner.clear(); tint.clear();
        size_t sky_index = sky_start;
        for (uint32_t li = 0; li < luminaires.size(); ++li) {
            const Luminaire& l = luminaires[li];
            if (l.distant) {
                const size_t first = sky_index;
                if (l.interleave) sky_index += l.points.size();
                if (!(l.illuminance > 0)) continue;
                const double far = visibility ? visibility->reach(start) : 1.0;
                const bool share = stride > 1 && (l.interleave || l.points.size() > kSkyDirections);
                const size_t step = share ? stride : 1;
                // this light's first direction that falls to point `offset`
                const size_t begin = !share ? 0 : l.interleave ? (offset + stride - first % stride) % stride : offset;
                for (size_t k = begin; k < l.points.size(); k += step) {
                    if (!(l.weights[k] > 0)) continue;
                    const Vec3& d = l.points[k];  // unit, towards the light
                    const double c = n ? dot(*n, d) : 1.0;
                    if (!(c > 0)) continue;
                    from.push_back(start);
                    to.push_back(start + d * far);
                    dir.push_back(d);
                    wi.push_back(l.weights[k] * l.illuminance * double(step));
                    r2.push_back(1.0);
                    cosr.push_back(c);
                    owner.push_back(li);
                    tint.push_back(l.tints.empty() ? l.colour : mul(l.colour, l.tints[k]));
                }
                continue;
            }
            for (size_t k = 0; k < l.points.size(); ++k) {
                if (!(l.weights[k] > 0)) continue;
                const Vec3 d = l.points[k] - x;  // receiver -> light
                const double dd = dot(d, d);
                if (!(dd > 0)) continue;
                const double rr = std::sqrt(dd);
                const double c = n ? dot(*n, d) / rr : 1.0;
                if (!(c > 0)) continue;
                const double i = l.intensity(-d);  // light -> receiver
                if (!(i > 0)) continue;
                from.push_back(start);
                to.push_back(l.points[k]);
                dir.push_back(d / rr);
                wi.push_back(l.weights[k] * i);
                r2.push_back(dd);
                cosr.push_back(c);
                owner.push_back(li);
                tint.push_back(l.colour);
            }
        }
        seen.assign(from.size(), 1.0f);
        if (visibility && !from.empty())
            visibility->segments_transmittance(from.data(), to.data(), from.size(), seen.data());
    }
};

RGB irradiance_of(const std::vector<Luminaire>& luminaires, const Arrivals& a) {
    RGB sum{};
    for (size_t s = 0; s < a.from.size(); ++s)
        if (a.seen[s] > 0) sum += a.tint[s] * (a.seen[s] * a.wi[s] * a.cosr[s] / a.r2[s]);
    return sum;
}

}  // namespace

RGB luminaire_irradiance_at(const std::vector<Luminaire>& luminaires, const Visibility* visibility, const Vec3& x,
                            const Vec3& n, double lift) {
    Arrivals a;
    a.collect(luminaires, visibility, x, &n, x + n * lift);
    return irradiance_of(luminaires, a);
}

void luminaire_irradiance(const std::vector<Luminaire>& luminaires, const Visibility* visibility, const Vec3* x,
                          const Vec3* n, size_t count, RGB* out, double lift) {
    if (luminaires.empty()) {
        std::fill(out, out + count, RGB{});
        return;
    }
    tbb::parallel_for(tbb::blocked_range<size_t>(0, count, 64), [&](const tbb::blocked_range<size_t>& r) {
        Arrivals a;
        for (size_t q = r.begin(); q < r.end(); ++q) {
            a.collect(luminaires, visibility, x[q], &n[q], x[q] + n[q] * lift);
            out[q] = irradiance_of(luminaires, a);
        }
    });
}

void luminaire_moments(const std::vector<Luminaire>& luminaires, const Visibility* visibility, const Vec3* x,
                       size_t count, RGB* s0, std::array<RGB, 3>* s1) {
    if (luminaires.empty()) return;
    tbb::parallel_for(tbb::blocked_range<size_t>(0, count, 64), [&](const tbb::blocked_range<size_t>& r) {
        Arrivals a;
        for (size_t q = r.begin(); q < r.end(); ++q) {
            a.collect(luminaires, visibility, x[q], nullptr, x[q]);
            for (size_t s = 0; s < a.from.size(); ++s) {
                if (!(a.seen[s] > 0)) continue;
                const RGB v = a.tint[s] * (a.seen[s] * a.wi[s] / a.r2[s]);
                s0[q] += v;
                for (int c = 0; c < 3; ++c) s1[q][c] += v * a.dir[s][c];
            }
        }
    });
}

std::vector<Vec3> unit_directions(const std::vector<Vec3>& directions) {
    std::vector<Vec3> dirs = directions;
    for (size_t k = 0; k < dirs.size(); ++k) {
        const double len = length(dirs[k]);
        if (!(len > 0) || !std::isfinite(len))
            throw std::invalid_argument("direction " + std::to_string(k) + " is zero or not finite");
        dirs[k] = dirs[k] / len;
    }
    return dirs;
}

void distant_transmittance(const Visibility& vis, const Vec3* x, const Vec3* n, size_t count,
                           const std::vector<Vec3>& dirs, double lift, float* out) {
    const size_t D = dirs.size();
    std::fill(out, out + count * D, 0.0f);
    tbb::parallel_for(tbb::blocked_range<size_t>(0, count, 4), [&](const tbb::blocked_range<size_t>& r) {
        std::vector<Vec3> from, to;
        std::vector<size_t> slot;
        std::vector<float> t;
        for (size_t p = r.begin(); p < r.end(); ++p) {
            const Vec3 np = normalize(n[p]);
            const Vec3 start = x[p] + np * lift;
            const double far = vis.reach(start);
            from.clear(); to.clear(); slot.clear();
            for (size_t d = 0; d < D; ++d) {
                if (!(dot(np, dirs[d]) > 0)) continue;
                from.push_back(start);
                to.push_back(start + dirs[d] * far);
                slot.push_back(d);
            }
            t.assign(from.size(), 0.0f);
            if (!from.empty()) vis.segments_transmittance(from.data(), to.data(), from.size(), t.data());
            for (size_t k = 0; k < slot.size(); ++k)
                out[p * D + slot[k]] = static_cast<float>(dot(np, dirs[slot[k]]) * t[k]);
        }
    });
}

namespace {

// An element's g x g stratum centres (Patch::point) and its normal at each.
void element_points(const Patch& p, int g, std::vector<Vec3>& xs, std::vector<Vec3>& ns) {
    for (int a = 0; a < g; ++a)
        for (int b = 0; b < g; ++b) {
            xs[size_t(a) * g + b] = p.point((a + 0.5) / g, (b + 0.5) / g);
            ns[size_t(a) * g + b] = p.normal;
        }
}

}  // namespace

void element_group_irradiance(const std::vector<Luminaire>& luminaires, const std::vector<uint32_t>& group,
                              size_t groups, const Visibility& visibility, const Patch* const* elements, size_t count,
                              int g, std::vector<RGB>& out, size_t sky_start) {
    if (g < 1) throw std::invalid_argument("element_group_irradiance: g must be at least 1");
    if (group.size() != luminaires.size())
        throw std::invalid_argument("element_group_irradiance: one group per luminaire");
    for (uint32_t q : group)
        if (q >= groups) throw std::invalid_argument("element_group_irradiance: a group index out of range");
    out.assign(groups * count, RGB{});
    const double lift = visibility.ray_offset();
    const size_t m = size_t(g) * size_t(g);
    tbb::parallel_for(tbb::blocked_range<size_t>(0, count, 16), [&](const tbb::blocked_range<size_t>& r) {
        std::vector<Vec3> xs(m), ns(m);
        Arrivals arrivals;
        for (size_t e = r.begin(); e < r.end(); ++e) {
            element_points(*elements[e], g, xs, ns);
            for (size_t k = 0; k < m; ++k) {
                arrivals.collect(luminaires, &visibility, xs[k], &ns[k], xs[k] + ns[k] * lift, m, k, sky_start);
                for (size_t s = 0; s < arrivals.from.size(); ++s) {
                    if (!(arrivals.seen[s] > 0)) continue;
                    const uint32_t q = group[arrivals.owner[s]];
                    out[q * count + e] += arrivals.tint[s] * (arrivals.seen[s] * arrivals.wi[s] * arrivals.cosr[s] /
                                                              arrivals.r2[s]);
                }
            }
            for (size_t q = 0; q < groups; ++q) out[q * count + e] = out[q * count + e] / double(m);
        }
    });
}

void element_luminaire_irradiance(const std::vector<Luminaire>& luminaires, const Visibility& visibility,
                                  const Patch* const* elements, size_t count, int g, std::vector<RGB>& mean,
                                  std::vector<double>& spread) {
    if (g < 1) throw std::invalid_argument("element_luminaire_irradiance: g must be at least 1");
    mean.assign(count, RGB{});
    spread.assign(count, 0.0);
    const double lift = visibility.ray_offset();
    const size_t m = size_t(g) * size_t(g);
    tbb::parallel_for(tbb::blocked_range<size_t>(0, count, 16), [&](const tbb::blocked_range<size_t>& r) {
        std::vector<Vec3> xs(m), ns(m);
        std::vector<RGB> hs(m);
        for (size_t e = r.begin(); e < r.end(); ++e) {
            element_points(*elements[e], g, xs, ns);
            Arrivals arrivals;
            for (size_t k = 0; k < m; ++k) {
                // skies: point k takes every m-th direction from the k-th (interleaved), so the
                // element's mean sees each direction once, from stratified points
                arrivals.collect(luminaires, &visibility, xs[k], &ns[k], xs[k] + ns[k] * lift, m, k);
                hs[k] = irradiance_of(luminaires, arrivals);
            }
            RGB sum{};
            double lo = 1e300, hi = -1e300;
            for (const RGB& h : hs) {
                sum += h;
                const double y = luminance(h);
                lo = std::min(lo, y);
                hi = std::max(hi, y);
            }
            mean[e] = sum / double(m);
            spread[e] = hi - lo;
        }
    });
}

}  // namespace hirad
