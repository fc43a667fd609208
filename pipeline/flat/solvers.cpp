#include "pipeline/flat/solvers.h"

#include <tbb/parallel_for.h>

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>

#include "pipeline/core/checks.h"

namespace hirad {

namespace {

// Sums f(i) over [0, n) in fixed-size blocks added in order: the same bits whatever the
// number of threads.
template <typename F>
double ordered_sum(uint32_t n, F f) {
    constexpr uint32_t kBlock = 4096;
    const uint32_t blocks = (n + kBlock - 1) / kBlock;
    std::vector<double> partial(blocks, 0.0);
    tbb::parallel_for(uint32_t(0), blocks, [&](uint32_t b) {
        double s = 0;
        const uint32_t end = std::min(n, (b + 1) * kBlock);
        for (uint32_t i = b * kBlock; i < end; ++i) s += f(i);
        partial[b] = s;
    });
    double total = 0;
    for (double p : partial) total += p;
    return total;
}

double norm2(const RGB& v) { return dot(v, v); }

// The emission norm (colour.h) with every weight 1, summed in ordered_sum's blocks.
double emission_norm(const RadiositySystem& sys) {
    return norm_or_one(ordered_sum(sys.size(), [&](uint32_t i) { return norm2(sys.emission[i]); }));
}

// Unshot power of a residual: what Southwell and progressive refinement rank patches by.
double power(const RGB& r, double area) { return (std::fabs(r.x) + std::fabs(r.y) + std::fabs(r.z)) * area; }

// Index of the largest unshot power; ties go to the lowest index so the order of shots is
// deterministic.
uint32_t argmax_power(const std::vector<RGB>& residual, const std::vector<double>& area) {
    const uint32_t n = static_cast<uint32_t>(area.size());
    constexpr uint32_t kBlock = 8192;
    const uint32_t blocks = (n + kBlock - 1) / kBlock;
    std::vector<std::pair<double, uint32_t>> best(blocks, {-1.0, 0});
    auto scan = [&](uint32_t b) {
        std::pair<double, uint32_t> m{-1.0, 0};
        const uint32_t end = std::min(n, (b + 1) * kBlock);
        for (uint32_t i = b * kBlock; i < end; ++i) {
            double p = power(residual[i], area[i]);
            if (p > m.first) m = {p, i};
        }
        best[b] = m;
    };
    if (blocks > 1) tbb::parallel_for(uint32_t(0), blocks, scan);
    else if (blocks == 1) scan(0);
    std::pair<double, uint32_t> m{-1.0, 0};
    for (const auto& b : best)
        if (b.first > m.first) m = b;
    return m.second;
}

void require_links(const RadiositySystem& sys, const char* who) {
    if (!sys.links) throw std::invalid_argument(std::string(who) + " needs the link matrix");
}

}  // namespace

std::vector<RGB> gather(const RadiositySystem& sys, const std::vector<RGB>& b) {
    require_links(sys, "gather");
    const LinkMatrix& L = *sys.links;
    std::vector<RGB> h(sys.size());
    tbb::parallel_for(tbb::blocked_range<uint32_t>(0, sys.size(), 256), [&](const tbb::blocked_range<uint32_t>& r) {
        for (uint32_t i = r.begin(); i < r.end(); ++i) {
            RGB acc;
            for (uint64_t k = L.offsets[i]; k < L.offsets[i + 1]; ++k) acc += b[L.columns[k]] * double(L.coupling[k]);
            h[i] = acc / sys.area[i];
        }
    });
    return h;
}

double relative_residual(const RadiositySystem& sys, const std::vector<RGB>& b) {
    std::vector<RGB> h = gather(sys, b);
    double r = ordered_sum(sys.size(), [&](uint32_t i) {
        return norm2(sys.emission[i] + mul(sys.reflectance[i], h[i]) - b[i]);
    });
    return std::sqrt(r) / emission_norm(sys);
}

Solution solve_direct(const RadiositySystem& sys) {
    require_links(sys, "the direct solver");
    const uint32_t n = sys.size();
    if (n > 12000) throw std::invalid_argument("the direct solver is for verification on small scenes (n <= 12000)");
    const LinkMatrix& L = *sys.links;
    Solution sol;
    sol.radiosity.assign(n, RGB{});
    for (int c = 0; c < 3; ++c) {
        Eigen::MatrixXd m = Eigen::MatrixXd::Identity(n, n);
        Eigen::VectorXd e(n);
        for (uint32_t i = 0; i < n; ++i) {
            e[i] = sys.emission[i][c];
            for (uint64_t k = L.offsets[i]; k < L.offsets[i + 1]; ++k)
                m(i, L.columns[k]) -= sys.reflectance[i][c] * L.coupling[k] / sys.area[i];
        }
        Eigen::VectorXd b = m.partialPivLu().solve(e);
        for (uint32_t i = 0; i < n; ++i) sol.radiosity[i][c] = b[i];
    }
    sol.iterations = 1;
    sol.residual = relative_residual(sys, sol.radiosity);
    require_finite_residual("the direct solver", sol.residual, 1);
    sol.residual_history.push_back(sol.residual);
    sol.converged = true;
    return sol;
}

Solution solve_jacobi(const RadiositySystem& sys, const SolverOptions& opt) {
    require_links(sys, "Jacobi");
    const uint32_t n = sys.size();
    const double enorm = emission_norm(sys);
    Solution sol;
    std::vector<RGB> b = sys.emission, next(n);
    for (uint64_t it = 1; it <= opt.max_iterations; ++it) {
        std::vector<RGB> h = gather(sys, b);
        tbb::parallel_for(uint32_t(0), n, [&](uint32_t i) { next[i] = sys.emission[i] + mul(sys.reflectance[i], h[i]); });
        // next - b is exactly the residual E - M b of the current iterate.
        double r = std::sqrt(ordered_sum(n, [&](uint32_t i) { return norm2(next[i] - b[i]); })) / enorm;
        require_finite_residual("Jacobi", r, it);
        sol.residual_history.push_back(r);
        sol.iterations = it;
        sol.residual = r;
        bool go_on = !opt.on_iteration || opt.on_iteration({it, r, UINT32_MAX});
        // Stop on b, the iterate whose residual was just measured.
        if (r <= opt.tolerance || !go_on || it == opt.max_iterations) { sol.converged = r <= opt.tolerance; break; }
        b.swap(next);
    }
    sol.radiosity = std::move(b);
    return sol;
}

Solution solve_gauss_seidel(const RadiositySystem& sys, const SolverOptions& opt) {
    require_links(sys, "Gauss-Seidel");
    const LinkMatrix& L = *sys.links;
    const uint32_t n = sys.size();
    Solution sol;
    std::vector<RGB> b = sys.emission;
    for (uint64_t it = 1; it <= opt.max_iterations; ++it) {
        for (uint32_t i = 0; i < n; ++i) {
            RGB acc;
            for (uint64_t k = L.offsets[i]; k < L.offsets[i + 1]; ++k) acc += b[L.columns[k]] * double(L.coupling[k]);
            b[i] = sys.emission[i] + mul(sys.reflectance[i], acc / sys.area[i]);
        }
        double r = relative_residual(sys, b);
        require_finite_residual("Gauss-Seidel", r, it);
        sol.residual_history.push_back(r);
        sol.iterations = it;
        sol.residual = r;
        bool go_on = !opt.on_iteration || opt.on_iteration({it, r, UINT32_MAX});
        if (r <= opt.tolerance || !go_on) { sol.converged = r <= opt.tolerance; break; }
    }
    sol.radiosity = std::move(b);
    return sol;
}

namespace {

// Southwell's iteration in shooting form. b holds the radiosity already shot, r = E - M b the
// unshot radiosity. Shooting patch s sends rho_j F_js r_s to every j it is linked with.
// The couplings of the shooter come from `row`; ambient is used only for display.
Solution shoot(const char* solver_name, const RadiositySystem& sys, const CouplingRow& row, const SolverOptions& opt,
               uint64_t snapshot_every,
               const std::function<void(uint64_t, const std::vector<RGB>&)>& snapshot) {
    const uint32_t n = sys.size();
    const double enorm = emission_norm(sys);
    Solution sol;
    std::vector<RGB> b(n), r = sys.emission;
    std::vector<double> r2(n);
    for (uint32_t i = 0; i < n; ++i) r2[i] = norm2(r[i]);
    double r2_total = ordered_sum(n, [&](uint32_t i) { return r2[i]; });
    std::vector<std::pair<uint32_t, float>> links;
    // The running sum of squares drifts as it is updated; it is recomputed exactly every n
    // shots and before the solver decides it has converged.
    uint64_t since_exact = 0;
    for (uint64_t shot = 1; shot <= opt.max_iterations; ++shot) {
        const uint32_t s = argmax_power(r, sys.area);
        const RGB rs = r[s];
        b[s] += rs;
        r[s] = RGB{};
        links.clear();
        row(s, links);
        auto update = [&](size_t k) {
            const uint32_t j = links[k].first;
            r[j] += mul(sys.reflectance[j], rs) * (double(links[k].second) / sys.area[j]);
        };
        if (links.size() > 8192) tbb::parallel_for(size_t(0), links.size(), update);
        else for (size_t k = 0; k < links.size(); ++k) update(k);
        r2_total -= r2[s];
        r2[s] = 0;
        for (const auto& [j, g] : links) {
            double v = norm2(r[j]);
            r2_total += v - r2[j];
            r2[j] = v;
        }
        if (++since_exact >= n || std::sqrt(std::max(r2_total, 0.0)) / enorm <= opt.tolerance) {
            r2_total = ordered_sum(n, [&](uint32_t i) { return r2[i]; });
            since_exact = 0;
        }
        const double res = std::sqrt(std::max(r2_total, 0.0)) / enorm;
        // A NaN unshot power is never the largest: without this a NaN would never be shot and
        // the solve would run to max_iterations.
        require_finite_residual(solver_name, res, shot, "shot");
        sol.residual_history.push_back(res);
        sol.iterations = shot;
        sol.residual = res;
        bool go_on = !opt.on_iteration || opt.on_iteration({shot, res, s});
        if (snapshot && snapshot_every > 0 && shot % snapshot_every == 0) {
            // Display estimate: what has arrived (b + r) plus an ambient term standing in for
            // the unshot energy (Cohen et al. 1988): ambient = R * sum(r A) / sum(A),
            // R = 1 / (1 - mean rho).
            RGB unshot, rho_mean;
            double total_area = 0;
            for (uint32_t i = 0; i < n; ++i) {
                unshot += r[i] * sys.area[i];
                rho_mean += sys.reflectance[i] * sys.area[i];
                total_area += sys.area[i];
            }
            rho_mean = rho_mean / total_area;
            RGB ambient{unshot.x / total_area / (1 - rho_mean.x), unshot.y / total_area / (1 - rho_mean.y),
                        unshot.z / total_area / (1 - rho_mean.z)};
            std::vector<RGB> display(n);
            for (uint32_t i = 0; i < n; ++i) display[i] = b[i] + r[i] + mul(sys.reflectance[i], ambient);
            snapshot(shot, display);
        }
        if (res <= opt.tolerance || !go_on) { sol.converged = res <= opt.tolerance; break; }
    }
    sol.radiosity = std::move(b);
    return sol;
}

}  // namespace

Solution solve_southwell(const RadiositySystem& sys, const SolverOptions& opt) {
    require_links(sys, "Southwell");
    const LinkMatrix& L = *sys.links;
    CouplingRow row = [&](uint32_t i, std::vector<std::pair<uint32_t, float>>& out) {
        for (uint64_t k = L.offsets[i]; k < L.offsets[i + 1]; ++k) out.emplace_back(L.columns[k], L.coupling[k]);
    };
    return shoot("Southwell", sys, row, opt, 0, nullptr);
}

Solution solve_progressive(const RadiositySystem& sys, const CouplingRow& couplings_of, const ProgressiveOptions& opt,
                           uint64_t* rows_computed) {
    // Form factors on the fly: a patch's couplings are computed the first time it shoots and
    // kept for its later shots.
    std::vector<std::vector<std::pair<uint32_t, float>>> cache(sys.size());
    std::vector<uint8_t> cached(sys.size(), 0);
    uint64_t computed = 0;
    CouplingRow row = [&](uint32_t i, std::vector<std::pair<uint32_t, float>>& out) {
        if (!cached[i]) {
            couplings_of(i, cache[i]);
            cached[i] = 1;
            ++computed;
        }
        out.insert(out.end(), cache[i].begin(), cache[i].end());
    };
    Solution sol = shoot("progressive refinement", sys, row, opt, opt.snapshot_every, opt.snapshot);
    if (rows_computed) *rows_computed = computed;
    return sol;
}

}  // namespace hirad
