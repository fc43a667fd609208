// Clusters that receive (Hierarchy::facing, Hierarchy::reception, RefineOptions::
// cluster_receivers): the furnace of many small faces, faces of mixed orientations under one
// source against Lambert's closed form, the solution approaching the one with element
// receivers only as epsilon falls, every sharing giving the faces exactly the link's power,
// links that carry little staying coarse, and the gain limit counting glazing.
#include <gtest/gtest.h>

#include <tbb/task_arena.h>

#include <cmath>
#include <cstring>
#include <random>
#include <vector>

#include "pipeline/hierarchy/hierarchical_solver.h"
#include "pipeline/hierarchy/hierarchy.h"
#include "pipeline/hierarchy/refine.h"
#include "pipeline/geometry/visibility.h"
#include "pipeline/outofcore/streaming_solver.h"
#include "tests/cpp/streaming_problem.h"
#include "tests/cpp/test_scenes.h"

namespace hirad {
namespace {

RefineOptions receiving(double epsilon, int samples, bool on = true) {
    RefineOptions o;
    o.epsilon = epsilon;
    o.min_area = 1.0;  // the input faces are the elements: what is tested is the clusters above them
    o.samples = samples;
    o.seed = 7;
    o.cluster_receivers = on;
    return o;
}

size_t cluster_receivers(const Hierarchy& h, const std::vector<Link>& links) {
    size_t n = 0;
    for (const Link& l : links) n += h.nodes[l.receiver].cluster;
    return n;
}

SolverOptions tight() {
    SolverOptions o;
    o.tolerance = 1e-9;
    o.max_iterations = 100000;
    return o;
}

// Lambert's contour integral: the form factor from a point x with unit normal n to a polygon
// (all of it above x's plane): F = 1 / (2 pi) sum_k gamma_k n . (a_k x b_k) / |a_k x b_k|,
// a_k, b_k the edge's ends seen from x, gamma_k the angle between them.
double lambert(const Vec3& x, const Vec3& n, const std::vector<Vec3>& poly) {
    double f = 0;
    for (size_t k = 0; k < poly.size(); ++k) {
        const Vec3 a = poly[k] - x, b = poly[(k + 1) % poly.size()] - x;
        const Vec3 c = cross(a, b);
        f += std::atan2(length(c), dot(a, b)) * dot(n, c) / length(c);
    }
    return std::abs(f) / (2 * kPi);
}

// A furnace of many small faces: a closed 10 m room (6 x 2 x 2 faces, inwards) around a
// 0.3 m box of 6 x 8 x 8 faces (outwards), everything emitting E and reflecting rho.
Scene furnace(double rho, double E) {
    Scene scene = test::tiled_cube(2, test::grey(rho), test::grey(E));
    for (Face& f : scene.faces)
        for (Vec3& p : f.p) p = p * 10.0;
    for (Face f : test::tiled_cube(8, test::grey(rho), test::grey(E)).faces) {
        std::swap(f.p[1], f.p[3]);  // turned outwards
        for (Vec3& p : f.p) p = p * 0.3 + Vec3{4.85, 4.85, 1.0};
        scene.faces.push_back(f);
    }
    return scene;
}

TEST(ClusterReceivers, FurnaceOfManySmallFacesGivesEOverOneMinusRho) {
    // Every face must come to B = E / (1 - rho) = 2, with the box's faces lit through links
    // that end on clusters, solved in memory (Jacobi) and streamed (block Southwell).
    const double rho = 0.5, E = 1.0;
    const Scene scene = furnace(rho, E);
    Hierarchy h(scene);
    Visibility vis(h.faces);
    double emitted = 0;
    for (const Face& f : scene.faces) emitted += E * f.area();
    Refiner refiner(h, vis, receiving(1e-5 * emitted, 64));
    RefineStats stats;
    std::vector<Link> links = refiner.initial_links(node_emission(h), stats);
    sort_links(links);
    EXPECT_GT(cluster_receivers(h, links), 0u) << "no link ends on a cluster";
    const HierarchicalSolution sol = solve_push_pull(h, links, {}, tight());
    ASSERT_TRUE(sol.converged);
    for (uint32_t i : h.leaves())
        for (int c = 0; c < 3; ++c) EXPECT_NEAR(sol.radiosity[i][c], E / (1 - rho), 0.01 * E / (1 - rho)) << i;

    // Streamed: groups of 64 faces, each linked from the root's link to its root.
    const test::Problem pb(scene, 64, receiving(1e-5 * emitted, 64));
    EXPECT_GT(cluster_receivers(pb.h, pb.links), 0u);
    const HierarchicalSolution streamed = pb.stream(1e-9);
    ASSERT_TRUE(streamed.converged);
    for (uint32_t i : pb.h.leaves())
        for (int c = 0; c < 3; ++c) EXPECT_NEAR(streamed.radiosity[i][c], E / (1 - rho), 0.01 * E / (1 - rho)) << i;
}

// 25 small squares (1.5 cm) tilted 0 to 56 degrees every way, 6 cm apart, 30 m under a 3 m
// square lamp (`lamp`, exitance M), with their centres and normals.
Scene tilted_squares(double M, const std::vector<Vec3>& lamp, std::vector<Vec3>& centre, std::vector<Vec3>& normal) {
    Scene scene;
    Face emitter;
    emitter.nv = 4;
    for (int k = 0; k < 4; ++k) emitter.p[k] = lamp[size_t(k)];
    emitter.emission = test::grey(M);
    scene.faces.push_back(emitter);
    for (int i = 0; i < 5; ++i)
        for (int j = 0; j < 5; ++j) {
            const double tilt = (i * 5 + j) * 0.04, azimuth = (i * 5 + j) * 2.4;
            const Vec3 n{std::sin(tilt) * std::cos(azimuth), std::sin(tilt) * std::sin(azimuth), std::cos(tilt)};
            const Vec3 c{(i - 2) * 0.06, (j - 2) * 0.06, 0};
            const Vec3 u = normalize(cross(n, std::abs(n.x) < 0.9 ? Vec3{1, 0, 0} : Vec3{0, 1, 0}));
            const Vec3 v = cross(n, u);
            const double a = 0.0075;
            Face f;
            f.nv = 4;
            f.p = {c - u * a - v * a, c + u * a - v * a, c + u * a + v * a, c - u * a + v * a};
            f.reflectance = test::grey(0.1);
            scene.faces.push_back(f);
            centre.push_back(c);
            normal.push_back(n);
        }
    return scene;
}

const std::vector<Vec3> kLamp = {{-1.5, -1.5, 30}, {-1.5, 1.5, 30}, {1.5, 1.5, 30}, {1.5, -1.5, 30}};

TEST(ClusterReceivers, FacesOfMixedOrientationsTakeTheirOwnIrradiance) {
    // The tilted squares: each must receive M F(its centre -> lamp), Lambert's closed form for
    // its own orientation, within 2 %, through links that end on clusters.
    const double M = 100.0;
    const std::vector<Vec3>& lamp = kLamp;
    std::vector<Vec3> centre, normal;
    const Scene scene = tilted_squares(M, lamp, centre, normal);
    Hierarchy h(scene);
    Visibility vis(h.faces);
    Refiner refiner(h, vis, receiving(1e-3 * M * 9, 1024));
    RefineStats stats;
    std::vector<Link> links = refiner.initial_links(node_emission(h), stats);
    sort_links(links);
    // Most squares take the lamp's light through a cluster (one whose cone is too wide for the
    // 1 % direction tolerance at 30 m is lit on its own).
    size_t own = 0;
    for (const Link& l : links) own += l.source == h.face_node[0] && !h.nodes[l.receiver].cluster;
    EXPECT_LE(own, 5u) << "squares lit on their own";
    EXPECT_GT(cluster_receivers(h, links), 0u);
    const HierarchicalSolution sol = solve_push_pull(h, links, {}, tight());
    ASSERT_TRUE(sol.converged);
    for (size_t k = 0; k < centre.size(); ++k) {
        const double expected = M * lambert(centre[k], normal[k], lamp);
        const double got = sol.irradiance[h.face_node[k + 1]].x;
        EXPECT_NEAR(got, expected, 0.02 * expected) << "square " << k << ", tilted " << (k * 0.04) << " rad";
    }
}

TEST(ClusterReceivers, ApproachTheElementReceiversSolutionAsEpsilonFalls) {
    // A cube of 6 x 6 x 6 faces, one of them a lamp, rho = 0.6: the solution with receiving
    // clusters at falling epsilon (three rounds) against the one with element receivers at
    // epsilon 0 (every pair of faces linked: the flat solution over the faces).
    Scene scene = test::tiled_cube(6, test::grey(0.6));
    scene.faces[3].emission = test::grey(36.0);
    const double emitted = 36.0 / 36;
    const Hierarchy faces(scene);
    Visibility vis(faces.faces);
    auto solve = [&](double epsilon, bool on, size_t& link_count) {
        Hierarchy h(scene);
        Refiner refiner(h, vis, receiving(epsilon * emitted, 64, on));
        RefineStats stats;
        // Three refine-solve rounds, as a bake does: links from dark sources are judged again
        // once the sources are lit.
        std::vector<Link> links = refiner.initial_links(node_emission(h), stats);
        sort_links(links);
        HierarchicalSolution sol = solve_push_pull(h, links, {}, tight());
        for (int round = 2; round <= 3; ++round) {
            links = refiner.refine(links, sol.radiosity, stats);
            sort_links(links);
            sol = solve_push_pull(h, links, {}, tight());
        }
        link_count = links.size();
        std::vector<double> face(scene.faces.size());
        for (size_t f = 0; f < face.size(); ++f) face[f] = sol.radiosity[h.face_node[f]].x;
        return face;
    };
    size_t flat_links = 0;
    const std::vector<double> flat = solve(0.0, false, flat_links);
    double previous = 1e300;
    for (double epsilon : {1e-2, 1e-3, 1e-4, 1e-5}) {
        size_t n = 0;
        const std::vector<double> b = solve(epsilon, true, n);
        double diff = 0, norm = 0;
        for (size_t f = 0; f < b.size(); ++f) {
            diff += std::abs(b[f] - flat[f]);
            norm += flat[f];
        }
        const double error = diff / norm;
        EXPECT_LE(error, previous * 1.05 + 1e-4) << "epsilon " << epsilon << ": " << n << " links";
        previous = error;
        if (epsilon == 1e-5) EXPECT_LT(error, 0.01) << n << " links against " << flat_links;
    }
}

TEST(ClusterReceivers, EverySharingGivesTheFacesExactlyTheLinksPower) {
    // Sum over the faces f below R of A_f reception(R, S).along(n_f) = 1 for every way of
    // sharing (faces of one orientation, by the direction, evenly): the faces take exactly the
    // link's G B_S, which sent() and the energy balance count.
    size_t checked[3] = {0, 0, 0};
    std::vector<Vec3> centre, normal;
    for (const Scene& scene : {furnace(0.5, 1.0), tilted_squares(1.0, kLamp, centre, normal)}) {
    const Hierarchy h(scene);
    for (uint32_t r = 0; r < h.nodes.size(); ++r) {
        if (!h.nodes[r].cluster) continue;
        std::vector<uint32_t> sources = {h.face_node[0]};
        for (uint32_t s = 0; s < h.nodes.size(); s += 7) sources.push_back(s);
        for (uint32_t s : sources) {
            if (s == r || h.facing(r, s) == Hierarchy::Facing::Back) continue;
            const Reception rec = h.reception(r, s);
            double power = 0;
            for (uint32_t j = h.nodes[r].face_begin; j < h.nodes[r].face_end; ++j) {
                const Patch& f = h.faces[h.face_order[j]];
                power += f.area * rec.along(f.normal);
            }
            EXPECT_NEAR(power, 1.0, 1e-9) << "cluster " << r << ", source " << s;
            ++checked[rec.uniform > 0 ? 2 : (h.cluster_shapes[h.slot_of(r)].cos_spread > Hierarchy::kPlanarCosine ? 0 : 1)];
        }
    }
    }
    EXPECT_GT(checked[0], 0u) << "no cluster of one orientation";
    EXPECT_GT(checked[1], 0u) << "no sharing by the direction";
    EXPECT_GT(checked[2], 0u) << "no even sharing";
}

// test::cluttered_room: a 6 m room lit by one ceiling tile, holding 16 boxes cut t x t a side.
TEST(ClusterReceivers, LinksThatCarryLittleStayCoarse) {
    // Round 1 judges every source by its emission: all but the lamp's links carry nothing
    // yet. With the geometric rules giving way for them (kSlight), round 1's links follow
    // the lamp, not the boxes' faces: 16 times the faces (t = 2 -> 8) may not double them.
    auto round_one = [](int t, size_t& faces) {
        const Scene scene = test::cluttered_room(t);
        faces = scene.faces.size();
        Hierarchy h(scene);
        Visibility vis(h.faces);
        double emitted = 0;
        for (const Face& f : scene.faces) emitted += f.emission.x * f.area();
        RefineOptions o = receiving(1e-4 * emitted, 16);
        o.min_area = 0.05;
        Refiner refiner(h, vis, o);
        RefineStats stats;
        return refiner.initial_links(node_emission(h), stats).size();
    };
    size_t faces2 = 0, faces8 = 0;
    const size_t coarse = round_one(2, faces2), fine = round_one(8, faces8);
    EXPECT_EQ(faces8 - 96, 16 * (faces2 - 96));
    EXPECT_LT(fine, 2 * coarse) << coarse << " links for " << faces2 << " faces, " << fine << " for " << faces8;
}

TEST(ClusterReceivers, ClearGlassScattersNothingItLetsThrough) {
    // A wall (rho 0.9, E 1) facing a clear pane (tau0 1, rho 0) with a lamp (E 2) behind it. The
    // lamp lights the pane's back (F 0.6) and, through the pane, the wall (F 0.3: the link the
    // estimate made through the glass); the wall sees the pane's front (F 0.5). Clear glass
    // sends on nothing it receives: both sides keep B = rho H = 0, and the wall gets the lamp's
    // light only by its own link: B_wall = E + rho F E_lamp = 1 + 0.9 x 0.3 x 2 = 1.54.
    Scene scene;
    Face wall;
    wall.nv = 4;
    wall.p = {Vec3{0, 0, 0}, Vec3{1, 0, 0}, Vec3{1, 1, 0}, Vec3{0, 1, 0}};
    wall.reflectance = test::grey(0.9);
    wall.emission = test::grey(1.0);
    Face pane = wall;
    pane.p = {Vec3{0, 0, 1}, Vec3{0, 1, 1}, Vec3{1, 1, 1}, Vec3{1, 0, 1}};
    pane.reflectance = test::grey(0.0);
    pane.emission = test::grey(0.0);
    pane.transmittance = 1.0;
    Face lamp = pane;
    for (Vec3& c : lamp.p) c.z = 2;
    lamp.emission = test::grey(2.0);
    lamp.transmittance = 0;
    scene.faces = {wall, pane, lamp};
    const Hierarchy h(scene);
    ASSERT_EQ(h.glass.size(), 1u);
    const uint32_t w = h.face_node[0], l = h.face_node[2], front = h.glass[0].front, back = h.glass[0].back;
    std::vector<Link> links(3);
    auto set = [&](Link& k, uint32_t r, uint32_t src, double f) {
        k.receiver = r;
        k.source = src;
        k.coupling = k.unoccluded = static_cast<float>(f * h.nodes[r].area);
        k.visibility = 1;
    };
    set(links[0], w, front, 0.5);
    set(links[1], w, l, 0.3);
    set(links[2], back, l, 0.6);
    sort_links(links);
    const HierarchicalSolution sol = solve_push_pull(h, links, {}, tight());
    ASSERT_TRUE(sol.converged) << "residual " << sol.residual;
    EXPECT_EQ(sol.limited_leaves, 0u);
    EXPECT_NEAR(sol.irradiance[back].x, 0.6 * 2, 1e-6);  // the back does receive the lamp (float G)
    EXPECT_EQ(sol.radiosity[back].x, 0.0);
    EXPECT_EQ(sol.radiosity[front].x, 0.0);
    EXPECT_NEAR(sol.radiosity[w].x, 1.54, 1e-6);
}

// push_pull walks the tree depth first, in parallel over subtrees of more than 4,096 faces,
// with the pushed vectors on its stack. What it must compute is the definition, written here
// in index order (parents first, then children before parents for the pull): a node's
// irradiance is its own plus its parent's, plus n . E of the pushed vector when its parent is a
// receiving cluster, the leaves' terms applied; a cluster's pushed vector is its own plus its
// parent's; B = E + rho H at element leaves, area-weighted means above. Every value must be
// that to the bit, with 1, 2 and 4 threads; and push_pull_power, from power, the same as
// push_pull from power over area.
TEST(ClusterReceivers, PushPullInParallelIsTheDefinitionToTheBit) {
    const Scene scene = test::tiled_cube(40, test::grey(0.6), test::grey(0.1));  // 9,600 faces
    Hierarchy h(scene);
    for (uint32_t f = 0; f < 9600; f += 37) h.subdivide(h.face_node[f]);   // element trees too
    for (uint32_t f = 0; f < 9600; f += 111) h.subdivide(h.nodes[h.face_node[f]].first_child + 2);
    const size_t n = h.nodes.size();
    std::mt19937_64 rng(11);
    std::uniform_real_distribution<double> u(-1.0, 1.0);
    auto rgb = [&] { return RGB{u(rng) + 1, u(rng) + 1, u(rng) + 1}; };
    std::vector<RGB> gathered(n);
    for (RGB& g : gathered) g = rgb();
    std::vector<VectorIrradiance> clusters(h.cluster_shapes.size());
    for (VectorIrradiance& v : clusters) {
        for (Vec3& c : v.c) c = rgb() - RGB{1, 1, 1};
        v.uniform = rgb();
    }
    LeafTerms terms;
    terms.scale.resize(n);
    terms.inherited.resize(n);
    for (size_t i = 0; i < n; ++i) {
        terms.scale[i] = 0.5 + 0.25 * (u(rng) + 1);
        terms.inherited[i] = 0.9 + 0.05 * (u(rng) + 1);
    }

    // The definition, in index order.
    std::vector<RGB> want_h(n), want_b(n);
    std::vector<VectorIrradiance> pushed = clusters;
    for (size_t i = 0; i < n; ++i) {
        const Node& node = h.nodes[i];
        ASSERT_TRUE(node.parent == kNoNode || node.parent < i);
        RGB above = node.parent == kNoNode ? RGB{} : want_h[node.parent];
        if (node.parent != kNoNode && h.nodes[node.parent].cluster) {
            const VectorIrradiance& v = pushed[h.cluster_slot[node.parent]];
            if (node.cluster) pushed[h.cluster_slot[i]].add(v);
            else above += v.along(h.normal(uint32_t(i)));
        }
        want_h[i] = terms.leaf_irradiance(uint32_t(i), node.leaf(), gathered[i], above);
    }
    for (size_t i = n; i-- > 0;) {
        const Node& node = h.nodes[i];
        if (node.leaf()) {
            want_b[i] = node.cluster ? RGB{} : h.emission(uint32_t(i)) +
                                                   mul(h.reflectance(uint32_t(i)), want_h[i]);
            continue;
        }
        RGB acc;
        for (uint32_t c = 0; c < node.child_count; ++c)
            acc += want_b[node.first_child + c] * h.nodes[node.first_child + c].area;
        want_b[i] = acc / node.area;
    }

    for (int threads : {1, 2, 4}) {
        std::vector<RGB> got_h(n), got_b(n);
        tbb::task_arena arena(threads);
        arena.execute([&] { push_pull(h, gathered, got_h, got_b, terms, clusters); });
        EXPECT_EQ(std::memcmp(got_h.data(), want_h.data(), n * sizeof(RGB)), 0) << threads << " threads: irradiance";
        EXPECT_EQ(std::memcmp(got_b.data(), want_b.data(), n * sizeof(RGB)), 0) << threads << " threads: radiosity";
        // In place, as the streaming solver calls it (gathered is the irradiance it overwrites).
        std::vector<RGB> in_place = gathered;
        arena.execute([&] { push_pull(h, in_place, in_place, got_b, terms, clusters); });
        EXPECT_EQ(std::memcmp(in_place.data(), want_h.data(), n * sizeof(RGB)), 0) << threads << " threads: in place";
        // From power, as the streaming solver calls it: received = gathered x area, divided
        // back by the area as the walk goes (the same quotient the definition starts from).
        std::vector<RGB> received(n), power_h(n), power_b(n), quotient = gathered;
        for (size_t i = 0; i < n; ++i) {
            received[i] = gathered[i] * h.nodes[i].area;
            quotient[i] = received[i] / h.nodes[i].area;
        }
        std::vector<RGB> want_qh(n), want_qb(n);
        push_pull(h, quotient, want_qh, want_qb, terms, clusters);  // checked above to be the definition
        arena.execute([&] { push_pull_power(h, received, power_b, terms, clusters, &power_h); });
        EXPECT_EQ(std::memcmp(power_h.data(), want_qh.data(), n * sizeof(RGB)), 0) << threads << " threads: power";
        EXPECT_EQ(std::memcmp(power_b.data(), want_qb.data(), n * sizeof(RGB)), 0) << threads << " threads: power";
        std::vector<RGB> only_b(n);
        arena.execute([&] { push_pull_power(h, received, only_b, terms, clusters); });
        EXPECT_EQ(std::memcmp(only_b.data(), want_qb.data(), n * sizeof(RGB)), 0) << threads << " threads: B only";
    }
}

}  // namespace
}  // namespace hirad
