// The element hierarchy (clusters over faces, element quadtrees, 2:1 balance), refinement
// from the root's self-link, and the three solvers with push-pull on the furnace.
#include "pipeline/hierarchy/hierarchy.h"

#include <gtest/gtest.h>

#include <cmath>
#include <set>
#include <utility>
#include <vector>

#include "pipeline/core/checks.h"
#include "pipeline/hierarchy/hierarchical_solver.h"
#include "pipeline/hierarchy/refine.h"
#include "pipeline/geometry/visibility.h"
#include "tests/cpp/test_scenes.h"

namespace hirad {
namespace {

TEST(Hierarchy, ClustersAboveFacesParentsFirst) {
    Scene scene = test::unit_cube(test::grey(0.5), test::grey(1.0));
    Hierarchy h(scene);
    size_t clusters = 0;
    for (size_t i = 0; i < h.nodes.size(); ++i) {
        const Node& n = h.nodes[i];
        clusters += n.cluster;
        if (i != h.root) EXPECT_LT(n.parent, i);
        if (!n.cluster) continue;
        // 2 to kClusterChildren children, whose faces follow each other and make up the cluster's
        EXPECT_GE(n.child_count, 2);
        EXPECT_LE(n.child_count, kClusterChildren);
        uint32_t at = n.face_begin;
        for (uint32_t c = n.first_child; c < n.first_child + n.child_count; ++c) {
            EXPECT_EQ(h.nodes[c].face_begin, at);
            at = h.nodes[c].face_end;
        }
        EXPECT_EQ(at, n.face_end);
    }
    // 6 faces, two buckets: the root cut into a bucket of 4 and one of 2, each holding its
    // faces as children
    EXPECT_EQ(clusters, 3u);
    EXPECT_EQ(h.nodes.size(), 9u);
    EXPECT_EQ(h.nodes[h.root].child_count, 2);
    EXPECT_NEAR(h.nodes[h.root].area, 6.0, 1e-12);
    for (uint32_t f = 0; f < 6; ++f) EXPECT_FALSE(h.nodes[h.face_node[f]].cluster);
}

TEST(Hierarchy, SubdivisionTilesTheParent) {
    Scene scene = test::unit_cube(test::grey(0.5), test::grey(1.0));
    Hierarchy h(scene);
    const uint32_t e = h.face_node[0];
    ASSERT_TRUE(h.can_subdivide(e, 0.25));
    EXPECT_FALSE(h.can_subdivide(e, 0.26));
    h.subdivide(e);
    ASSERT_EQ(h.nodes[e].child_count, 4);
    double sum = 0;
    for (int c = 0; c < 4; ++c) {
        const Node& child = h.nodes[h.nodes[e].first_child + c];
        sum += child.area;
        EXPECT_EQ(child.parent, e);
        EXPECT_NEAR(dot(h.normal(h.nodes[e].first_child + c), h.normal(e)), 1.0, 1e-12);
    }
    EXPECT_NEAR(sum, h.nodes[e].area, 1e-12);
}

TEST(Hierarchy, ClusterSamplesLieOnItsFaces) {
    Scene scene = test::unit_cube(test::grey(0.5), test::grey(1.0));
    Hierarchy h(scene);
    Rng rng(3);
    for (int k = 0; k < 200; ++k) {
        Vec3 p, n;
        h.sample(h.root, rng.uniform(), rng.uniform(), rng.uniform(), p, n);
        // On the unit cube's surface, with the inward normal of the face it lies on.
        const double dist = std::min({p.x, 1 - p.x, p.y, 1 - p.y, p.z, 1 - p.z});
        EXPECT_NEAR(dist, 0.0, 1e-12);
        EXPECT_NEAR(length(n), 1.0, 1e-12);
    }
}

TEST(Hierarchy, BalanceLeavesAtMostOneLevelBetweenNeighbours) {
    // Two unit quads side by side in one mesh; the right one is split three levels deep at
    // the shared edge, so the left one must split until its edge carries one midpoint only.
    Scene scene;
    for (int q = 0; q < 2; ++q) {
        Face f;
        f.nv = 4;
        f.p = {Vec3{double(q), 0, 0}, Vec3{double(q) + 1, 0, 0}, Vec3{double(q) + 1, 1, 0}, Vec3{double(q), 1, 0}};
        scene.faces.push_back(f);
    }
    Hierarchy h(scene);
    uint32_t right = h.face_node[1];
    for (int level = 0; level < 3; ++level) {
        h.subdivide(right);
        right = h.nodes[right].first_child;  // the child at corner 0, on the shared edge x = 1
    }
    const uint64_t split = h.balance();
    EXPECT_GT(split, 0u);
    // Leaves of the left face touching x = 1 next to the deep corner (y < 0.5) are at least
    // two levels deep; next to the unrefined upper half they may stay at one.
    int deep = 0;
    auto depth = [&](uint32_t i) {  // below its element root (the face)
        int d = 0;
        for (; h.nodes[i].parent != kNoNode && !h.nodes[h.nodes[i].parent].cluster; i = h.nodes[i].parent) ++d;
        return d;
    };
    for (uint32_t i : h.leaves()) {
        const Patch& s = h.shape(i);
        if (s.face != 0) continue;
        double xmax = 0, ymax = 0;
        for (int k = 0; k < 4; ++k) { xmax = std::max(xmax, s.p[k].x); ymax = std::max(ymax, s.p[k].y); }
        if (xmax == 1.0 && ymax <= 0.5) { EXPECT_GE(depth(i), 2); ++deep; }
    }
    EXPECT_GT(deep, 0);
    EXPECT_EQ(h.balance(), 0u);  // balanced already: nothing more to split
}

TEST(Refine, LinksStartAtTheRootAndNeverJoinRelatives) {
    Scene scene = test::unit_cube(test::grey(0.5), test::grey(1.0));
    Hierarchy h(scene);
    Visibility vis(h.faces);
    Refiner refiner(h, vis, {1e-3, 0.01, 16, 1});
    RefineStats stats;
    std::vector<Link> links = refiner.initial_links(node_emission(h), stats);
    ASSERT_FALSE(links.empty());
    std::set<std::pair<uint32_t, uint32_t>> seen;
    auto ancestor = [&](uint32_t a, uint32_t d) {
        for (uint32_t p = d; p != kNoNode; p = h.nodes[p].parent)
            if (p == a) return true;
        return false;
    };
    for (const Link& l : links) {
        EXPECT_FALSE(h.nodes[l.receiver].cluster);
        EXPECT_FALSE(ancestor(l.receiver, l.source) || ancestor(l.source, l.receiver));
        EXPECT_TRUE(seen.insert({l.receiver, l.source}).second);
        EXPECT_GT(l.coupling, 0.0f);
    }
}

class HierarchicalFurnace : public ::testing::TestWithParam<int> {};

TEST_P(HierarchicalFurnace, RadiosityIsEmissionOverOneMinusRho) {
    // Closed cube, rho = 0.5, E = 1: B = 2 everywhere, for all three solvers.
    Scene scene = test::unit_cube(test::grey(0.5), test::grey(1.0));
    Hierarchy h(scene);
    Visibility vis(h.faces);
    Refiner refiner(h, vis, {1e-5 * 6, 0.02, 256, 1});
    RefineStats stats;
    std::vector<Link> links = refiner.initial_links(node_emission(h), stats);
    sort_links(links);
    SolverOptions opt;
    opt.tolerance = 1e-8;
    opt.max_iterations = 100000;
    HierarchicalSolution sol;
    if (GetParam() == 0) sol = solve_push_pull(h, links, {}, opt);
    if (GetParam() == 1) sol = solve_gauss_seidel_push_pull(h, links, {}, opt);
    if (GetParam() == 2) sol = solve_southwell_push_pull(h, links, {}, opt);
    EXPECT_TRUE(sol.converged);
    for (uint32_t i : h.leaves())
        for (int c = 0; c < 3; ++c) EXPECT_NEAR(sol.radiosity[i][c], 2.0, 0.02) << "leaf " << i;
}


// A NaN emission on one face: all three stop with an error at the first residual.
TEST_P(HierarchicalFurnace, NonFiniteResidualStopsAtOnce) {
    Scene scene = test::unit_cube(test::grey(0.5), test::grey(1.0));
    scene.faces[2].emission.x = std::nan("");
    Hierarchy h(scene);
    Visibility vis(h.faces);
    Refiner refiner(h, vis, {1e-3, 0.2, 16, 1});
    RefineStats stats;
    std::vector<RGB> judge = node_emission(h);
    for (RGB& b : judge) b.x = std::isfinite(b.x) ? b.x : 1.0;  // refine as if it were lit
    std::vector<Link> links = refiner.initial_links(judge, stats);
    sort_links(links);
    SolverOptions opt;
    opt.tolerance = 1e-12;
    opt.max_iterations = 1000000;
    uint64_t calls = 0;
    opt.on_iteration = [&](const IterationReport&) { return ++calls, true; };
    const char* names[3] = {"hierarchical Jacobi", "hierarchical Gauss-Seidel", "hierarchical Southwell"};
    try {
        if (GetParam() == 0) solve_push_pull(h, links, {}, opt);
        if (GetParam() == 1) solve_gauss_seidel_push_pull(h, links, {}, opt);
        if (GetParam() == 2) solve_southwell_push_pull(h, links, {}, opt);
        ADD_FAILURE() << "no error";
    } catch (const NonFiniteError& e) {
        EXPECT_EQ(std::string(e.what()).rfind(std::string(names[GetParam()]) + ": the residual is nan", 0), 0u)
            << e.what();
    }
    EXPECT_EQ(calls, 0u);
}

INSTANTIATE_TEST_SUITE_P(Solvers, HierarchicalFurnace, ::testing::Values(0, 1, 2));

}  // namespace
}  // namespace hirad
