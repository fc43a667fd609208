// The final gather (pipeline/hierarchy/gather.h) against the closed form of a point under a
// parallel emitting rectangle: with one source of uniform radiosity and nothing reflecting,
// the irradiance at x is B F(dx -> source) exactly, wherever x is on the receiver and however
// refinement split the source.
#include "pipeline/hierarchy/gather.h"

#include <gtest/gtest.h>
#include <tbb/task_arena.h>
#include <unistd.h>

#include <cmath>
#include <cstring>
#include <filesystem>
#include <string>
#include <vector>

#include "pipeline/geometry/formfactors.h"
#include "pipeline/hierarchy/hierarchical_solver.h"
#include "pipeline/hierarchy/refine.h"
#include "pipeline/outofcore/outofcore.h"

namespace hirad {
namespace {

// Form factor from a differential area to a parallel rectangle a x b at distance c, the
// area's normal through one corner of the rectangle (Howell's catalogue, B-4).
double corner_rectangle(double a, double b, double c) {
    const double A = a / c, B = b / c;
    return (A / std::sqrt(1 + A * A) * std::atan(B / std::sqrt(1 + A * A)) +
            B / std::sqrt(1 + B * B) * std::atan(A / std::sqrt(1 + B * B))) /
           (2 * kPi);
}

// The same for a point (x, y) under the rectangle [0, w] x [0, d]: the four rectangles that
// meet above it (x, y inside).
double under_rectangle(double x, double y, double w, double d, double c) {
    return corner_rectangle(x, y, c) + corner_rectangle(w - x, y, c) + corner_rectangle(x, d - y, c) +
           corner_rectangle(w - x, d - y, c);
}

Face quad(const std::vector<Vec3>& c, double rho, double emission) {
    Face f;
    f.nv = 4;
    for (int k = 0; k < 4; ++k) f.p[k] = c[k];
    f.reflectance = {rho, rho, rho};
    f.emission = {emission, emission, emission};
    return f;
}

// A scene linked from its root (Refiner::initial_links) and solved to 1e-12.
struct Linked {
    Hierarchy h;
    Visibility vis;
    std::vector<Link> links;
    HierarchicalSolution sol;
    Linked(const Scene& scene, const RefineOptions& options) : h(scene), vis(h.faces) {
        Refiner refiner(h, vis, options);
        RefineStats stats;
        links = refiner.initial_links(node_emission(h), stats);
        sort_links(links);
        SolverOptions opt;
        opt.tolerance = 1e-12;
        sol = solve_push_pull(h, links, {}, opt);
    }
};

TEST(Gather, PointUnderAnEmittingRectangleIsBTimesTheClosedForm) {
    // Floor [0, 2] x [0, 1] at z = 0 facing up, light of the same size at z = 0.8 facing
    // down; neither reflects, so B = E on the light and H = E F on the floor.
    const double E = 3.0, c = 0.8;
    Scene scene;
    scene.faces.push_back(quad({{0, 0, 0}, {2, 0, 0}, {2, 1, 0}, {0, 1, 0}}, 0.0, 0.0));
    scene.faces.push_back(quad({{0, 0, c}, {0, 1, c}, {2, 1, c}, {2, 0, c}}, 0.0, E));
    for (const double epsilon : {1e-2, 1e-4}) {  // coarse and fine links
        SCOPED_TRACE(epsilon);
        const Linked linked(scene, {epsilon * 2 * E, 1e-3, 16, 1});
        const Hierarchy& h = linked.h;
        ASSERT_TRUE(linked.sol.converged);
        Gatherer gatherer(h, linked.links, linked.sol.radiosity, linked.vis, GatherOptions{});
        const uint32_t floor = h.face_node[0];
        std::vector<uint32_t> leaf;
        std::vector<Vec3> x;
        std::vector<uint64_t> key;
        for (const auto& st : std::vector<std::pair<double, double>>{{0.5, 0.5}, {0.05, 0.1}, {0.9, 0.85}, {0.3, 0.77}}) {
            leaf.push_back(h.leaf_at(floor, st.first, st.second));
            x.push_back(h.faces[0].point(st.first, st.second));
            key.push_back(leaf.size());
        }
        std::vector<RGB> got(x.size());
        gatherer.irradiance(leaf.data(), x.data(), key.data(), x.size(), got.data());
        for (size_t k = 0; k < x.size(); ++k) {
            const double want = E * under_rectangle(x[k].x, x[k].y, 2.0, 1.0, c);
            for (int ch = 0; ch < 3; ++ch) EXPECT_NEAR(got[k][ch], want, 1e-9 * want) << "point " << k;
        }
        // radiance(): the floor reflects nothing and emits nothing.
        std::vector<RGB> radiance(x.size());
        gatherer.radiance(leaf.data(), x.data(), key.data(), x.size(), radiance.data());
        for (const RGB& l : radiance) EXPECT_EQ(l.x, 0.0);
    }
}

TEST(Gather, RadianceIsEmissionPlusReflectedOverPi) {
    // The same with a reflecting floor: L = (E_floor + rho H) / pi at the point, H the
    // light's direct irradiance plus nothing else (the light reflects nothing, and the floor
    // cannot see itself).
    const double E = 2.0, c = 0.5, rho = 0.4, Ef = 0.25;
    Scene scene;
    scene.faces.push_back(quad({{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0}}, rho, Ef));
    scene.faces.push_back(quad({{0, 0, c}, {0, 1, c}, {1, 1, c}, {1, 0, c}}, 0.0, E));
    const Linked linked(scene, {1e-4, 1e-3, 16, 1});
    const Hierarchy& h = linked.h;
    Gatherer gatherer(h, linked.links, linked.sol.radiosity, linked.vis, GatherOptions{});
    const uint32_t leaf = h.leaf_at(h.face_node[0], 0.25, 0.6);
    const Vec3 x = h.faces[0].point(0.25, 0.6);
    const uint64_t key = 7;
    RGB l;
    gatherer.radiance(&leaf, &x, &key, 1, &l);
    const double want = (Ef + rho * E * under_rectangle(x.x, x.y, 1.0, 1.0, c)) / kPi;
    EXPECT_NEAR(l.y, want, 1e-9 * want);
}

TEST(Gather, SecondBounceTakesACloseSourcesRadiosityWhereTheKernelIs) {
    // A floor [0, 1]^2 that emits E and reflects nothing, and a wall on x = 0 (y, z in [0, 1])
    // facing it with reflectance rho, each one element. The wall's radiosity is
    // B(y) = rho E F(dy -> floor): about rho E / 2 at its foot, far less at its top. At a floor
    // point d from the wall the light from it is the integral of B(y) dF(x -> dy), weighted
    // towards the foot, while the element holds the mean of B over the wall: without the
    // second bounce the gather takes that mean (far too dark here); with it each kernel-drawn
    // y's B is gathered at y, which is exact here (the floor's light at y is its exact form
    // factor). The reference is the same integral by quadrature, with F(dy -> floor) by its
    // contour integral (Lambert).
    const double E = 2.0, rho = 0.5, d = 0.05;
    Scene scene;
    scene.faces.push_back(quad({{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0}}, 0.0, E));
    scene.faces.push_back(quad({{0, 0, 0}, {0, 1, 0}, {0, 1, 1}, {0, 0, 1}}, rho, 0.0));
    const Linked linked(scene, {1e-9, 10.0, 16, 1});  // nothing is split (min_area 10 m^2)
    const Hierarchy& h = linked.h;
    const Visibility& vis = linked.vis;
    const std::vector<Link>& links = linked.links;
    const HierarchicalSolution& sol = linked.sol;
    ASSERT_TRUE(sol.converged);
    const Vec3 x{d, 0.5, 0};
    const std::array<Vec3, 4> floor{Vec3{0, 0, 0}, Vec3{1, 0, 0}, Vec3{1, 1, 0}, Vec3{0, 1, 0}};
    // Quadrature over the wall: z = t^2 (dense at the foot), v uniform; midpoints.
    const int nz = 400, nv = 400;
    double want = 0;
    for (int i = 0; i < nz; ++i) {
        const double t = (i + 0.5) / nz, z = t * t, dz = 2 * t / nz;
        for (int j = 0; j < nv; ++j) {
            const double v = (j + 0.5) / nv, dv = 1.0 / nv;
            const Vec3 y{0, v, z};
            const double b = rho * E * point_polygon_form_factor(y, {1, 0, 0}, floor.data(), 4, {0, 0, 1});
            const Vec3 r = y - x;
            const double r2 = dot(r, r);
            want += b * (z * d) / (kPi * r2 * r2) * dz * dv;  // cos_x cos_y / (pi r^2) dA
        }
    }
    const uint32_t leaf = h.leaf_at(h.face_node[0], d, 0.5);
    auto gathered = [&](double second_bounce) {
        GatherOptions o;
        o.rays = 16;
        o.second_bounce = second_bounce;
        Gatherer g(h, links, sol.radiosity, vis, o);
        const int n = 64;  // the same point with other samples, averaged
        std::vector<uint32_t> leaves(n, leaf);
        std::vector<Vec3> xs(n, x);
        std::vector<uint64_t> keys(n);
        for (int k = 0; k < n; ++k) keys[k] = uint64_t(k + 1);
        std::vector<RGB> got(n);
        g.irradiance(leaves.data(), xs.data(), keys.data(), n, got.data());
        double sum = 0;
        for (const RGB& e : got) sum += e.y;
        return sum / n;
    };
    const double with = gathered(0.5), without = gathered(0);
    EXPECT_NEAR(with, want, 0.02 * want) << "without: " << without;
    EXPECT_LT(without, 0.8 * want);  // the element's mean: the case the second bounce is for
    // Far from the wall (beyond half its diagonal) nothing changes, bit for bit.
    const Vec3 far{0.9, 0.5, 0};
    const uint32_t far_leaf = h.leaf_at(h.face_node[0], 0.9, 0.5);
    const uint64_t key = 3;
    RGB a, b;
    GatherOptions on;
    on.second_bounce = 0.5;
    Gatherer(h, links, sol.radiosity, vis, on).irradiance(&far_leaf, &far, &key, 1, &a);
    Gatherer(h, links, sol.radiosity, vis, GatherOptions{}).irradiance(&far_leaf, &far, &key, 1, &b);
    EXPECT_EQ(a.y, b.y);
}

// n random points on face 0 (the floor [0, 1]^2 at z = 0) with x < width, by a wall at x = 0:
// their leaves, and keys k * 7 + 1.
struct FloorPoints {
    std::vector<uint32_t> leaves;
    std::vector<Vec3> xs;
    std::vector<uint64_t> keys;
    FloorPoints(const Hierarchy& h, int n, double width, uint64_t seed) : leaves(n), xs(n), keys(n) {
        Rng rng(seed);
        for (int k = 0; k < n; ++k) {
            const double u = width * rng.uniform(), v = rng.uniform();
            xs[k] = {u, v, 0};
            leaves[k] = h.leaf_at(h.face_node[0], u, v);
            keys[k] = uint64_t(k) * 7 + 1;
        }
    }
};

TEST(Gather, AValueDoesNotDependOnTheOtherPointsOfItsCall) {
    // Gatherer::irradiance takes its points in leaf order, a block of leaves at a time, and
    // empties its cell cache between blocks once it is large: a point's value must depend only
    // on its leaf, its key and the solution. Points gathered together in one call, and each
    // alone in a fresh Gatherer (an empty cache) in the reverse order, give the same bits, with
    // the importance split and without, the second bounce's cells in use (points by a wall).
    Scene scene;
    scene.faces.push_back(quad({{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0}}, 0.3, 2.0));
    scene.faces.push_back(quad({{0, 0, 0}, {0, 1, 0}, {0, 1, 1}, {0, 0, 1}}, 0.5, 0.0));
    const Linked linked(scene, {1e-4, 0.01, 16, 1});
    const Hierarchy& h = linked.h;
    const int n = 300;
    const FloorPoints p(h, n, 0.3, 11);
    const std::vector<uint32_t>& leaves = p.leaves;
    const std::vector<Vec3>& xs = p.xs;
    const std::vector<uint64_t>& keys = p.keys;
    for (double importance : {0.0, 0.02}) {
        GatherOptions o;
        o.importance = importance;
        o.second_bounce = 1.0;
        std::vector<RGB> together(n);
        Gatherer(h, linked.links, linked.sol.radiosity, linked.vis, o)
            .irradiance(leaves.data(), xs.data(), keys.data(), n, together.data());
        for (int k = n; k-- > 0;) {
            RGB alone;
            Gatherer(h, linked.links, linked.sol.radiosity, linked.vis, o)
                .irradiance(&leaves[k], &xs[k], &keys[k], 1, &alone);
            ASSERT_EQ(alone.x, together[k].x) << "point " << k << ", importance " << importance;
            ASSERT_EQ(alone.y, together[k].y);
            ASSERT_EQ(alone.z, together[k].z);
        }
    }
}

TEST(Gather, TheRaysCountedDoNotDependOnTheThreads) {
    // The second bounce's cells are cached: every floor point near the wall asks for the same
    // cells of the wall's leaves, from whichever thread holds it. Each cell must be gathered
    // once, so that the rays counted (the report's counts.rays) are the same with one thread
    // and with eight on two cores, run after run; the values are the same bits as well. (Two
    // threads that missed a cell together both gathered it, and the count moved under load.)
    Scene scene;
    scene.faces.push_back(quad({{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0}}, 0.3, 2.0));
    scene.faces.push_back(quad({{0, 0, 0}, {0, 1, 0}, {0, 1, 1}, {0, 0, 1}}, 0.5, 0.0));
    const Linked linked(scene, {1e-4, 0.01, 16, 1});
    const FloorPoints p(linked.h, 2000, 0.3, 5);
    GatherOptions o;
    o.second_bounce = 1.0;
    auto gather = [&](int threads, std::vector<RGB>& out) {
        out.assign(p.xs.size(), RGB{});
        const uint64_t before = linked.vis.rays_cast();
        tbb::task_arena arena(threads);
        arena.execute([&] {
            Gatherer(linked.h, linked.links, linked.sol.radiosity, linked.vis, o)
                .irradiance(p.leaves.data(), p.xs.data(), p.keys.data(), p.xs.size(), out.data());
        });
        return linked.vis.rays_cast() - before;
    };
    std::vector<RGB> one, many;
    const uint64_t want = gather(1, one);
    ASSERT_GT(want, 0u);
    for (int run = 0; run < 12; ++run) {
        ASSERT_EQ(gather(8, many), want) << "run " << run;
        ASSERT_EQ(std::memcmp(many.data(), one.data(), one.size() * sizeof(RGB)), 0) << "run " << run;
    }
}

TEST(Gather, TheStoresTableIsTheSortedLinksAndGathersTheSameBits) {
    // An out-of-core bake's gather reads its link store straight into the 12-byte table
    // (gather_links: counted, then placed, a part at a time). The links spread over three
    // groups in the store's part order (by source, then receiver) and parts of kChunkLinks
    // must give the table that the links sorted by receiver give, and the same irradiance
    // bits at points by a wall.
    Scene scene;
    scene.faces.push_back(quad({{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0}}, 0.3, 2.0));
    scene.faces.push_back(quad({{0, 0, 0}, {0, 1, 0}, {0, 1, 1}, {0, 0, 1}}, 0.5, 0.0));
    scene.faces.push_back(quad({{1, 0, 0}, {1, 0, 1}, {1, 1, 1}, {1, 1, 0}}, 0.7, 0.5));
    const Linked linked(scene, {1e-6, 1e-3, 16, 1});
    const Hierarchy& h = linked.h;
    ASSERT_GT(linked.links.size(), 2 * kChunkLinks) << "several parts a group";
    std::vector<std::vector<Link>> by_group(3);
    for (const Link& l : linked.links) by_group[l.source % 3].push_back(l);
    for (auto& g : by_group) sort_part(g);
    const MemoryChunks chunks(by_group);
    const GatherLinks stored = gather_links(chunks, h.nodes.size());
    const GatherLinks sorted(linked.links, h.nodes.size());
    ASSERT_EQ(stored.first, sorted.first);
    ASSERT_EQ(stored.size(), linked.links.size());
    for (size_t k = 0; k < sorted.size(); ++k) {
        ASSERT_EQ(stored.links[k].source, sorted.links[k].source) << k;
        ASSERT_EQ(stored.links[k].coupling, sorted.links[k].coupling) << k;
        ASSERT_EQ(stored.links[k].visibility, sorted.links[k].visibility) << k;
    }
    // a receiver's row holds exactly its links
    for (size_t k = 0; k < linked.links.size(); ++k) {
        const uint32_t r = linked.links[k].receiver;
        ASSERT_GE(k, sorted.first[r]);
        ASSERT_LT(k, sorted.first[r + 1]);
    }
    const int n = 200;
    const FloorPoints p(h, n, 0.2, 3);
    const std::vector<uint32_t>& leaves = p.leaves;
    const std::vector<Vec3>& xs = p.xs;
    const std::vector<uint64_t>& keys = p.keys;
    GatherOptions o;
    o.importance = 0.02;
    o.second_bounce = 1.0;
    std::vector<RGB> a(n), b(n);
    Gatherer(h, stored, linked.sol.radiosity, linked.vis, o).irradiance(leaves.data(), xs.data(), keys.data(), n, a.data());
    Gatherer(h, linked.links, linked.sol.radiosity, linked.vis, o).irradiance(leaves.data(), xs.data(), keys.data(), n,
                                                                              b.data());
    for (int k = 0; k < n; ++k) {
        ASSERT_GT(a[k].x, 0);
        ASSERT_EQ(a[k].x, b[k].x) << k;
        ASSERT_EQ(a[k].y, b[k].y) << k;
        ASSERT_EQ(a[k].z, b[k].z) << k;
    }
    // a table of another hierarchy is refused
    GatherLinks other;
    other.first.assign(3, 0);
    EXPECT_THROW(Gatherer(h, other, linked.sol.radiosity, linked.vis, o), std::invalid_argument);
}

// A store that is not this bake's (its links reach nodes the hierarchy does not have) is
// refused by the gather with the file the bad link is in, the link's nodes and the count.
TEST(Gather, AStoreOfAnotherHierarchyIsRefusedNamingItsChunk) {
    std::vector<Link> part;
    for (uint32_t k = 0; k < 5; ++k) {
        Link l;
        l.receiver = k;
        l.source = 9 - k;
        l.coupling = l.unoccluded = 0.1f;
        l.visibility = 1.0f;
        part.push_back(l);
    }
    sort_part(part);  // by source: the first out of range is 8 -> 1
    // in memory
    const MemoryChunks chunks({part});
    EXPECT_NO_THROW(gather_links(chunks, 10));
    try {
        gather_links(chunks, 8);
        ADD_FAILURE() << "no error";
    } catch (const std::invalid_argument& e) {
        EXPECT_EQ(std::string(e.what()).rfind("links in memory, group 0 part 0: a link from node 8 to node 1 is out of "
                                              "the hierarchy's 8 nodes", 0), 0u) << e.what();
    }
    // on disk: the chunk file's path
    const std::filesystem::path dir = std::filesystem::temp_directory_path() /
                                      ("hirad_gather_store_" + std::to_string(::getpid()));
    std::filesystem::remove_all(dir);
    {
        LinkStoreWriter w(dir.string(), LinkStoreInfo{1, 2, 10, 10});
        w.write_chunk(0, 1, part.data(), part.size());
        w.commit();
    }
    EXPECT_EQ(gather_links(dir.string(), 1, 10).size(), part.size());
    try {
        gather_links(dir.string(), 1, 8);
        ADD_FAILURE() << "no error";
    } catch (const std::invalid_argument& e) {
        const std::string what = e.what();
        EXPECT_EQ(what.rfind((dir / "chunk-").string(), 0), 0u) << what;
        EXPECT_NE(what.find(".hlc: a link from node 8 to node 1 is out of the hierarchy's 8 nodes"), std::string::npos)
            << what;
    }
    std::filesystem::remove_all(dir);
}

// The solid angle of a rectangle a x b seen from a point at distance c below one corner.
double corner_solid_angle(double a, double b, double c) {
    return std::atan(a * b / (c * std::sqrt(a * a + b * b + c * c)));
}

TEST(Gather, PolygonSolidAngleMomentsAreTheClosedForms) {
    // A rectangle [0, 2] x [0, 1] at height c facing down, seen from points of the plane z = 0
    // facing up: omega by the corner formula, n . w1 = pi F (Lambert), and w1's tangential part
    // by symmetry (zero along y from y = 0.5, along x from x = 1).
    const double c = 0.8;
    const std::vector<Vec3> poly{{0, 0, c}, {0, 1, c}, {2, 1, c}, {2, 0, c}};
    const Vec3 down{0, 0, -1}, up{0, 0, 1};
    for (const Vec3& x : {Vec3{1, 0.5, 0}, Vec3{0.3, 0.2, 0}, Vec3{1, 0.9, 0}}) {
        const SolidAngleMoments m = polygon_solid_angle_moments(x, up, poly.data(), 4, down);
        const double omega = corner_solid_angle(x.x, x.y, c) + corner_solid_angle(2 - x.x, x.y, c) +
                             corner_solid_angle(x.x, 1 - x.y, c) + corner_solid_angle(2 - x.x, 1 - x.y, c);
        EXPECT_NEAR(m.omega, omega, 1e-12);
        EXPECT_NEAR(m.w1.z, kPi * under_rectangle(x.x, x.y, 2.0, 1.0, c), 1e-12);
        if (x.y == 0.5) EXPECT_NEAR(m.w1.y, 0.0, 1e-12);
        if (x.x == 1.0) EXPECT_NEAR(m.w1.x, 0.0, 1e-12);
        EXPECT_LE(length(m.w1), m.omega);  // |integral of w| <= integral of 1
    }
    // Behind the emitting side: nothing.
    EXPECT_EQ(polygon_solid_angle_moments({1, 0.5, 2 * c}, down, poly.data(), 4, down).omega, 0.0);
    // A square so large it fills the hemisphere: omega -> 2 pi, w1 -> pi n.
    const double big = 1e4;
    const std::vector<Vec3> sky{{-big, -big, 1}, {-big, big, 1}, {big, big, 1}, {big, -big, 1}};
    const SolidAngleMoments h = polygon_solid_angle_moments({0, 0, 0}, up, sky.data(), 4, down);
    EXPECT_NEAR(h.omega, 2 * kPi, 1e-3);
    EXPECT_NEAR(h.w1.z, kPi, 1e-3);
    // Clipped by a tilted receiver's horizon: n . w1 = pi F on the clipped part, as the form factor.
    const Vec3 tilted = normalize(Vec3{0.6, 0.0, 0.8});
    const Vec3 x{1.9, 0.5, 0.5};  // the plane through x with this normal cuts the rectangle
    const SolidAngleMoments t = polygon_solid_angle_moments(x, tilted, poly.data(), 4, down);
    EXPECT_GT(t.omega, 0.0);
    EXPECT_NEAR(dot(t.w1, tilted), kPi * point_polygon_form_factor(x, tilted, poly.data(), 4, down), 1e-12);
}

}  // namespace
}  // namespace hirad
