// Radiosity solvers over the flat link matrix: the furnace, agreement with the direct solve,
// residual bookkeeping, and LinkMatrix assembly.
#include "pipeline/flat/solvers.h"

#include <gtest/gtest.h>

#include <atomic>
#include <cmath>
#include <functional>
#include <map>
#include <string>
#include <memory>
#include <stdexcept>
#include <vector>

#include "pipeline/core/checks.h"
#include "pipeline/geometry/formfactors.h"
#include "pipeline/geometry/patches.h"
#include "pipeline/geometry/visibility.h"

namespace hirad {
namespace {

// The unit cube's six faces facing inward, each an n x n grid of patches, with per-face
// reflectance.
std::vector<Patch> inward_cube(int per_side, const std::array<RGB, 6>& reflectance) {
    const std::vector<std::vector<Vec3>> quads = {
        {{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0}},  // floor
        {{0, 0, 1}, {0, 1, 1}, {1, 1, 1}, {1, 0, 1}},  // ceiling
        {{0, 0, 0}, {0, 1, 0}, {0, 1, 1}, {0, 0, 1}},  // x = 0
        {{1, 0, 0}, {1, 0, 1}, {1, 1, 1}, {1, 1, 0}},  // x = 1
        {{0, 0, 0}, {0, 0, 1}, {1, 0, 1}, {1, 0, 0}},  // y = 0
        {{0, 1, 0}, {1, 1, 0}, {1, 1, 1}, {0, 1, 1}},  // y = 1
    };
    Scene scene;
    for (size_t q = 0; q < quads.size(); ++q) {
        Face f;
        f.nv = 4;
        for (int k = 0; k < 4; ++k) f.p[k] = quads[q][k];
        f.reflectance = reflectance[q];
        scene.faces.push_back(f);
    }
    return mesh_patches(scene, {1.0, 1.0 / per_side + 1e-12}).patches;
}

// Everything a solve needs, kept alive together.
struct Box {
    std::vector<Patch> patches;
    std::unique_ptr<Visibility> vis;
    std::unique_ptr<RayCastFormFactors> rc;
    LinkMatrix links;
    RadiositySystem sys;

    Box(const Box&) = delete;  // the system and the estimator point into the box itself
    Box& operator=(const Box&) = delete;
    Box(std::vector<Patch> p, int samples) : patches(std::move(p)) {
        vis = std::make_unique<Visibility>(patches);
        rc = std::make_unique<RayCastFormFactors>(patches, *vis, RayCastOptions{samples, 11});
        links = LinkMatrix::build(static_cast<uint32_t>(patches.size()),
                                  [&](uint32_t i, std::vector<std::pair<uint32_t, float>>& out) {
                                      rc->upper_couplings_of(i, out);
                                  });
        sys.links = &links;
        for (const Patch& q : patches) {
            sys.area.push_back(q.area);
            sys.reflectance.push_back(q.reflectance);
            sys.emission.push_back(q.emission);
        }
    }
    CouplingRow row() const {
        return [this](uint32_t i, std::vector<std::pair<uint32_t, float>>& out) { rc->couplings_of(i, out); };
    }
};

using SolveFn = std::function<Solution(const RadiositySystem&, const SolverOptions&)>;

// Every solver behind one signature; progressive computes its rows with the same estimator.
std::vector<std::pair<const char*, SolveFn>> solvers(const Box& box) {
    return {
        {"direct", [](const RadiositySystem& s, const SolverOptions&) { return solve_direct(s); }},
        {"jacobi", solve_jacobi},
        {"gauss_seidel", solve_gauss_seidel},
        {"southwell", solve_southwell},
        {"progressive",
         [&box](const RadiositySystem& s, const SolverOptions& o) {
             ProgressiveOptions po;
             po.tolerance = o.tolerance;
             po.max_iterations = o.max_iterations;
             return solve_progressive(s, box.row(), po);
         }},
    };
}

// The furnace: a closed enclosure where every patch emits E and reflects rho. Each patch
// sees only the enclosure (row sums of F are 1), so B = E + rho B everywhere: B = E/(1-rho).
// Channels: rho = 0.5, 0.9 and 0 (B = E exactly).
TEST(Solvers, FurnaceGivesEOverOneMinusRho) {
    const RGB rho{0.5, 0.9, 0.0};
    std::array<RGB, 6> refl;
    refl.fill(rho);
    std::vector<Patch> patches = inward_cube(3, refl);
    const RGB e{1.0, 2.0, 3.0};
    for (Patch& p : patches) p.emission = e;
    Box box(std::move(patches), 256);
    const RGB want{e.x / (1 - rho.x), e.y / (1 - rho.y), e.z};
    SolverOptions opt;
    opt.tolerance = 1e-7;
    for (const auto& [name, solve] : solvers(box)) {
        SCOPED_TRACE(name);
        Solution sol = solve(box.sys, opt);
        EXPECT_TRUE(sol.converged);
        ASSERT_EQ(sol.radiosity.size(), box.patches.size());
        for (const RGB& b : sol.radiosity) {
            EXPECT_NEAR(b.x, want.x, 0.01 * want.x);
            EXPECT_NEAR(b.y, want.y, 0.01 * want.y);
            EXPECT_NEAR(b.z, want.z, 1e-6 * want.z);  // no reflection: B = E to the tolerance
        }
    }
}

// A NaN emission (a bad input that got through) or a reflectance above 1 (the solve
// diverges): every solver stops at once with an error naming it, instead of handing on NaN
// (or, for the shooting methods, never shooting the NaN and running to max_iterations).
TEST(Solvers, NonFiniteResidualStopsEverySolverAtOnce) {
    std::array<RGB, 6> refl;
    refl.fill(RGB{0.5, 0.5, 0.5});
    std::vector<Patch> patches = inward_cube(2, refl);
    for (Patch& p : patches) p.emission = {1, 1, 1};
    patches[3].emission.y = std::nan("");
    Box box(std::move(patches), 16);
    SolverOptions opt;
    opt.tolerance = 1e-12;
    opt.max_iterations = 1000000;
    const std::map<std::string, std::string> names = {{"direct", "the direct solver"}, {"jacobi", "Jacobi"},
                                                      {"gauss_seidel", "Gauss-Seidel"}, {"southwell", "Southwell"},
                                                      {"progressive", "progressive refinement"}};
    for (const auto& [name, solve] : solvers(box)) {
        SCOPED_TRACE(name);
        uint64_t calls = 0;
        SolverOptions counted = opt;
        counted.on_iteration = [&](const IterationReport&) { return ++calls, true; };
        try {
            solve(box.sys, counted);
            ADD_FAILURE() << "no error";
        } catch (const NonFiniteError& e) {
            const std::string msg = e.what();
            EXPECT_EQ(msg.rfind(names.at(name) + ": the residual is nan at ", 0), 0u) << msg;
            EXPECT_NE(msg.find("no longer finite"), std::string::npos) << msg;
        }
        EXPECT_EQ(calls, 0u);  // stopped before reporting a single non-finite iteration
    }

    // Reflectance 1.5 in a closed box: B grows by half every sweep until it overflows.
    std::array<RGB, 6> over;
    over.fill(RGB{1.5, 1.5, 1.5});
    std::vector<Patch> diverging = inward_cube(1, over);
    for (Patch& p : diverging) p.emission = {1, 1, 1};
    Box box2(std::move(diverging), 16);
    uint64_t sweeps = 0;
    SolverOptions counted = opt;
    counted.on_iteration = [&](const IterationReport&) { return ++sweeps, true; };
    EXPECT_THROW(solve_jacobi(box2.sys, counted), NonFiniteError);
    EXPECT_LT(sweeps, 3000u);  // 1.5^k overflows a double near k = 1750, far below the limit
}

TEST(Solvers, ProgressiveComputesEveryRowOnceInTheFurnace) {
    // Every patch starts with unshot E and only ever gains more until it shoots, so reaching
    // ||r|| <= tol ||E|| needs every patch to shoot: n rows, each computed once.
    std::array<RGB, 6> refl;
    refl.fill(RGB{0.5, 0.5, 0.5});
    std::vector<Patch> patches = inward_cube(2, refl);
    for (Patch& p : patches) p.emission = {1, 1, 1};
    Box box(std::move(patches), 64);
    ProgressiveOptions po;
    po.tolerance = 1e-6;
    uint64_t rows = 0;
    Solution sol = solve_progressive(box.sys, box.row(), po, &rows);
    EXPECT_TRUE(sol.converged);
    EXPECT_EQ(rows, box.patches.size());
    EXPECT_GT(sol.iterations, box.patches.size());  // several rounds of shots
}

// A box with coloured walls and one emitting patch in the middle of the ceiling.
Box coloured_box() {
    std::array<RGB, 6> refl = {RGB{0.7, 0.7, 0.7}, RGB{0.5, 0.5, 0.5}, RGB{0.8, 0.1, 0.1},
                               RGB{0.1, 0.8, 0.1}, RGB{0.6, 0.6, 0.6}, RGB{0.2, 0.3, 0.8}};
    std::vector<Patch> patches = inward_cube(3, refl);
    int emitters = 0;
    for (Patch& p : patches)
        if (p.face == 1 && std::fabs(p.centroid.x - 0.5) < 1e-9 && std::fabs(p.centroid.y - 0.5) < 1e-9) {
            p.emission = {10, 8, 6};
            ++emitters;
        }
    EXPECT_EQ(emitters, 1);
    return Box(std::move(patches), 64);
}

TEST(Solvers, IterativeSolversAgreeWithDirect) {
    Box box = coloured_box();
    Solution direct = solve_direct(box.sys);
    EXPECT_LT(direct.residual, 1e-10);
    SolverOptions opt;
    opt.tolerance = 1e-7;
    for (const auto& [name, solve] : solvers(box)) {
        SCOPED_TRACE(name);
        Solution sol = solve(box.sys, opt);
        ASSERT_EQ(sol.radiosity.size(), direct.radiosity.size());
        for (size_t i = 0; i < sol.radiosity.size(); ++i)
            for (int c = 0; c < 3; ++c) {
                const double d = direct.radiosity[i][c];
                ASSERT_GT(d, 0);  // every patch of a closed box is lit
                EXPECT_NEAR(sol.radiosity[i][c], d, 1e-4 * d) << "patch " << i << " channel " << c;
            }
    }
}

TEST(Solvers, ResidualHistoryMatchesTheReturnedSolution) {
    Box box = coloured_box();
    SolverOptions opt;
    opt.tolerance = 1e-7;
    const std::pair<const char*, SolveFn> checked[] = {
        {"jacobi", solve_jacobi}, {"gauss_seidel", solve_gauss_seidel}, {"southwell", solve_southwell}};
    for (const auto& [name, solve] : checked) {
        SCOPED_TRACE(name);
        uint64_t calls = 0;
        double last = -1;
        opt.on_iteration = [&](const IterationReport& r) {
            ++calls;
            EXPECT_EQ(r.iteration, calls);
            last = r.residual;
            return true;
        };
        Solution sol = solve(box.sys, opt);
        EXPECT_TRUE(sol.converged);
        ASSERT_FALSE(sol.residual_history.empty());
        EXPECT_EQ(sol.residual_history.size(), sol.iterations);
        EXPECT_EQ(calls, sol.iterations);
        EXPECT_EQ(sol.residual_history.back(), sol.residual);
        EXPECT_EQ(last, sol.residual);
        EXPECT_LE(sol.residual, opt.tolerance);
        // Only the last entry may be at or below the tolerance: the solver stops there.
        for (size_t k = 0; k + 1 < sol.residual_history.size(); ++k) EXPECT_GT(sol.residual_history[k], opt.tolerance);
        const double actual = relative_residual(box.sys, sol.radiosity);
        EXPECT_NEAR(actual, sol.residual, 1e-6);
        EXPECT_LE(actual, opt.tolerance * 1.01);  // the reported residual is the returned B's
    }
}

TEST(Solvers, CallbackCanStopEarly) {
    Box box = coloured_box();
    SolverOptions opt;
    opt.tolerance = 1e-12;
    opt.on_iteration = [](const IterationReport& r) { return r.iteration < 3; };
    SolverOptions limited;  // the iteration limit stops a solve the same way
    limited.tolerance = 1e-12;
    limited.max_iterations = 4;
    const std::pair<const char*, SolveFn> checked[] = {
        {"jacobi", solve_jacobi}, {"gauss_seidel", solve_gauss_seidel}, {"southwell", solve_southwell}};
    for (const auto& [name, solve] : checked) {
        SCOPED_TRACE(name);
        Solution sol = solve(box.sys, opt);
        EXPECT_EQ(sol.iterations, 3u);
        EXPECT_FALSE(sol.converged);
        EXPECT_GT(sol.residual, opt.tolerance);
        // Stopped early, the solution returned is still the one whose residual is reported.
        EXPECT_NEAR(relative_residual(box.sys, sol.radiosity), sol.residual, 1e-9 * sol.residual);
        Solution lim = solve(box.sys, limited);
        EXPECT_EQ(lim.iterations, 4u);
        EXPECT_FALSE(lim.converged);
        EXPECT_NEAR(relative_residual(box.sys, lim.radiosity), lim.residual, 1e-9 * lim.residual);
    }
}

TEST(Solvers, ShootingReportsItsShooter) {
    // The first shot goes to the only patch with unshot power: the emitter.
    Box box = coloured_box();
    uint32_t emitter = UINT32_MAX;
    for (uint32_t i = 0; i < box.sys.size(); ++i)
        if (box.sys.emission[i].x > 0) emitter = i;
    std::vector<uint32_t> shooters;
    SolverOptions opt;
    opt.on_iteration = [&](const IterationReport& r) {
        shooters.push_back(r.shooter);
        return shooters.size() < 2;
    };
    solve_southwell(box.sys, opt);
    ASSERT_EQ(shooters.size(), 2u);
    EXPECT_EQ(shooters[0], emitter);
    EXPECT_NE(shooters[1], emitter);  // its unshot radiosity is zero after shooting
    EXPECT_LT(shooters[1], box.sys.size());
}

TEST(Solvers, GatherIsFTimesB) {
    // With B = 1 everywhere, H_i = sum_j F_ij = (sum_j G_ij) / A_i: the row sum of the links.
    Box box = coloured_box();
    std::vector<RGB> ones(box.sys.size(), RGB{1, 1, 1});
    std::vector<RGB> h = gather(box.sys, ones);
    for (uint32_t i = 0; i < box.sys.size(); ++i) {
        double row = 0;
        for (uint64_t k = box.links.offsets[i]; k < box.links.offsets[i + 1]; ++k) row += box.links.coupling[k];
        EXPECT_NEAR(h[i].x, row / box.sys.area[i], 1e-12);
        EXPECT_NEAR(h[i].x, 1.0, 0.02);  // a closed box: every patch sees only the box
    }
}

TEST(Solvers, LinkSolversNeedTheLinkMatrix) {
    RadiositySystem sys;
    sys.area = {1.0};
    sys.reflectance = {RGB{0.5, 0.5, 0.5}};
    sys.emission = {RGB{1, 1, 1}};
    SolverOptions opt;
    EXPECT_THROW(solve_direct(sys), std::invalid_argument);
    EXPECT_THROW(solve_jacobi(sys, opt), std::invalid_argument);
    EXPECT_THROW(solve_gauss_seidel(sys, opt), std::invalid_argument);
    EXPECT_THROW(solve_southwell(sys, opt), std::invalid_argument);
    EXPECT_THROW(relative_residual(sys, sys.emission), std::invalid_argument);
}

TEST(LinkMatrix, FromUpperBuildsSortedSymmetricRows) {
    // G (symmetric, zero diagonal):
    //      0  1  2  3
    //  0 [ .  1  .  3 ]
    //  1 [ 1  .  2  5 ]
    //  2 [ .  2  .  4 ]
    //  3 [ 3  5  4  . ]
    std::vector<std::vector<std::pair<uint32_t, float>>> upper = {
        {{1, 1.0f}, {3, 3.0f}}, {{2, 2.0f}, {3, 5.0f}}, {{3, 4.0f}}, {}};
    LinkMatrix m = LinkMatrix::from_upper(4, upper);
    EXPECT_EQ(m.n, 4u);
    EXPECT_EQ(m.offsets, (std::vector<uint64_t>{0, 2, 5, 7, 10}));
    EXPECT_EQ(m.columns, (std::vector<uint32_t>{1, 3, 0, 2, 3, 1, 3, 0, 1, 2}));
    EXPECT_EQ(m.coupling, (std::vector<float>{1, 3, 1, 2, 5, 2, 4, 3, 5, 4}));
    EXPECT_EQ(m.link_count(), 10u);
    EXPECT_EQ(m.bytes(), 5 * sizeof(uint64_t) + 10 * (sizeof(uint32_t) + sizeof(float)));
}

TEST(LinkMatrix, BuildMatchesFromUpperAndIsSymmetric) {
    // A pseudo-random sparse upper triangle, rows evaluated in parallel by build().
    const uint32_t n = 300;
    auto row = [](uint32_t i, std::vector<std::pair<uint32_t, float>>& out) {
        for (uint32_t j = i + 1; j < n; ++j)
            if ((i * 7 + j * 13) % 5 == 0) out.emplace_back(j, float(i) + float(j) / 1000.0f);
    };
    std::vector<std::vector<std::pair<uint32_t, float>>> upper(n);
    for (uint32_t i = 0; i < n; ++i) row(i, upper[i]);
    LinkMatrix a = LinkMatrix::from_upper(n, upper);
    std::atomic<uint32_t> progress_calls{0}, largest_done{0};
    LinkMatrix b = LinkMatrix::build(n, row, [&](uint32_t done) {
        ++progress_calls;
        uint32_t seen = largest_done.load();
        while (done > seen && !largest_done.compare_exchange_weak(seen, done)) {
        }
    });
    EXPECT_EQ(progress_calls.load(), n);
    EXPECT_EQ(largest_done.load(), n);
    EXPECT_EQ(a.offsets, b.offsets);
    EXPECT_EQ(a.columns, b.columns);
    EXPECT_EQ(a.coupling, b.coupling);
    for (uint32_t i = 0; i < n; ++i)
        for (uint64_t k = b.offsets[i]; k < b.offsets[i + 1]; ++k) {
            if (k > b.offsets[i]) EXPECT_LT(b.columns[k - 1], b.columns[k]);
            const uint32_t j = b.columns[k];
            EXPECT_NE(i, j);
            // The mirrored entry holds the same coupling.
            bool found = false;
            for (uint64_t l = b.offsets[j]; l < b.offsets[j + 1]; ++l)
                if (b.columns[l] == i) found = b.coupling[l] == b.coupling[k];
            EXPECT_TRUE(found) << i << " " << j;
        }
}

}  // namespace
}  // namespace hirad
