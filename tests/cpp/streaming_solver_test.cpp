// The out-of-core solve (pipeline/outofcore/streaming_solver.h): block Southwell streaming
// the links from memory or from the on-disk store, against the furnace's closed form
// B = E / (1 - rho) and against the in-memory hierarchical Jacobi solve of the same links;
// the same bits from memory and from disk, whatever the budget, and after a resume.
#include "pipeline/outofcore/streaming_solver.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <cstring>
#include <filesystem>
#include <memory>
#include <type_traits>
#include <string>
#include <vector>

#include "pipeline/core/checks.h"
#include "pipeline/hierarchy/hierarchical_solver.h"
#include "pipeline/hierarchy/refine.h"
#include "tests/cpp/streaming_problem.h"
#include "tests/cpp/test_scenes.h"

namespace hirad {
namespace {

namespace fs = std::filesystem;

using test::Problem;

std::string temp_dir(const char* name) {
    const fs::path d = fs::temp_directory_path() / ("hirad_streaming_" + std::to_string(::getpid()) + "_" + name);
    fs::remove_all(d);
    return d.string();
}

bool same_bits(const std::vector<RGB>& a, const std::vector<RGB>& b) {
    return a.size() == b.size() && std::memcmp(a.data(), b.data(), a.size() * sizeof(RGB)) == 0;
}

// At the least budget the solver reports (`minimum`), the same bits as `reference`, with its
// state and the chunks it held within the budget; one byte less is refused.
void expect_the_least_budget_holds(const Problem& pb, const LinkChunks& store, const StreamingOptions& opt,
                                   uint64_t minimum, const std::vector<RGB>& reference) {
    StreamingOptions tight = opt;
    tight.memory_budget = minimum;
    StreamingStats stats;
    const HierarchicalSolution small =
        solve_streaming(pb.h, pb.groups, store, pb.is_source, pb.outgoing, {}, tight, stats);
    EXPECT_TRUE(same_bits(reference, small.radiosity));
    EXPECT_LE(stats.state_bytes + stats.resident_bytes_peak, tight.memory_budget);
    tight.memory_budget = minimum - 1;
    EXPECT_THROW(solve_streaming(pb.h, pb.groups, store, pb.is_source, pb.outgoing, {}, tight, stats),
                 std::runtime_error);
}

TEST(StreamingSolver, FurnaceFromMemoryAndFromTheStoreGivesEOverOneMinusRho) {
    const double rho = 0.5, E = 1.0;
    Problem pb(test::unit_cube(test::grey(rho), test::grey(E)), 2);
    ASSERT_GT(pb.groups.count(), 1u);  // several groups: the blocks are really blocks
    StreamingOptions opt;
    opt.tolerance = 1e-10;
    StreamingStats mem_stats, disk_stats;
    const MemoryChunks memory(pb.by_group);
    const HierarchicalSolution mem =
        solve_streaming(pb.h, pb.groups, memory, pb.is_source, pb.outgoing, {}, opt, mem_stats);
    ASSERT_TRUE(mem.converged);
    for (uint32_t i : pb.h.leaves())
        for (int c = 0; c < 3; ++c) EXPECT_NEAR(mem.radiosity[i][c], E / (1 - rho), 0.02 * E / (1 - rho)) << i;

    const std::string dir = temp_dir("furnace");
    pb.write_store(dir);
    const StoreChunks store(dir, pb.groups.count());
    EXPECT_EQ(store.total_links(), pb.links.size());
    const HierarchicalSolution disk =
        solve_streaming(pb.h, pb.groups, store, pb.is_source, pb.outgoing, {}, opt, disk_stats);
    EXPECT_TRUE(same_bits(mem.radiosity, disk.radiosity));  // the store changes nothing
    EXPECT_EQ(mem.iterations, disk.iterations);
    EXPECT_GT(disk_stats.chunk_reads, 0u);

    // The budget decides only what stays decoded: the least the solver takes, the same bits.
    expect_the_least_budget_holds(pb, store, opt, disk_stats.minimum_budget, disk.radiosity);
    fs::remove_all(dir);
}

TEST(StreamingSolver, AgreesWithTheInMemoryJacobiSolveOfTheSameLinks) {
    // Uneven: one emitting face, the others grey: not a furnace, so the solution has shape.
    Scene scene = test::unit_cube(test::grey(0.6), test::grey(0.0));
    scene.faces[1].emission = {5.0, 2.5, 1.0};
    scene.faces[3].reflectance = {0.2, 0.7, 0.4};
    Problem pb(std::move(scene), 1);
    SolverOptions jopt;
    jopt.tolerance = 1e-11;
    jopt.max_iterations = 100000;
    const HierarchicalSolution jacobi = solve_push_pull(pb.h, pb.links, {}, jopt);
    ASSERT_TRUE(jacobi.converged);
    const HierarchicalSolution streamed = pb.stream(1e-11);
    ASSERT_TRUE(streamed.converged);
    double largest = 0;
    for (uint32_t i : pb.h.leaves()) largest = std::max(largest, jacobi.radiosity[i].x);
    for (uint32_t i : pb.h.leaves())
        for (int c = 0; c < 3; ++c)
            EXPECT_NEAR(streamed.radiosity[i][c], jacobi.radiosity[i][c], 1e-8 * largest) << "leaf " << i;
    // The irradiance handed out goes with the radiosity: B = E + rho H at every leaf.
    for (uint32_t i : pb.h.leaves()) {
        const Patch& n = pb.h.shape(i);
        const RGB b = n.emission + mul(n.reflectance, streamed.irradiance[i]);
        for (int c = 0; c < 3; ++c) EXPECT_NEAR(streamed.radiosity[i][c], b[c], 1e-9 * largest);
    }
}

// Solves whole, then "killed" after round 3 with a checkpoint every round and resumed: the same
// bits and iterations; a checkpoint of another fingerprint is not resumed from.
void expect_resume_reaches_the_same_bits(const Problem& pb, const char* name) {
    const MemoryChunks chunks(pb.by_group);
    StreamingOptions opt;
    opt.tolerance = 1e-10;
    StreamingStats whole_stats;
    const HierarchicalSolution whole =
        solve_streaming(pb.h, pb.groups, chunks, pb.is_source, pb.outgoing, {}, opt, whole_stats);
    ASSERT_GT(whole.iterations, 3u);

    const std::string dir = temp_dir(name);
    fs::create_directories(dir);
    StreamingOptions killed = opt;
    killed.checkpoint_path = dir + "/checkpoint";
    killed.checkpoint_seconds = 1e-9;  // every round
    killed.checkpoint_fingerprint = 42;
    killed.on_round = [](uint64_t round, double) { return round < 3; };  // "killed" after round 3
    StreamingStats killed_stats;
    solve_streaming(pb.h, pb.groups, chunks, pb.is_source, pb.outgoing, {}, killed, killed_stats);
    ASSERT_TRUE(fs::exists(killed.checkpoint_path));
    StreamingOptions resumed = killed;
    resumed.on_round = nullptr;
    StreamingStats resumed_stats;
    const HierarchicalSolution again =
        solve_streaming(pb.h, pb.groups, chunks, pb.is_source, pb.outgoing, {}, resumed, resumed_stats);
    EXPECT_TRUE(resumed_stats.resumed);
    EXPECT_TRUE(same_bits(whole.radiosity, again.radiosity));
    EXPECT_EQ(whole.iterations, again.iterations);
    StreamingOptions other = resumed;
    other.checkpoint_fingerprint = 43;
    StreamingStats other_stats;
    const HierarchicalSolution fresh =
        solve_streaming(pb.h, pb.groups, chunks, pb.is_source, pb.outgoing, {}, other, other_stats);
    EXPECT_FALSE(other_stats.resumed);
    EXPECT_TRUE(same_bits(whole.radiosity, fresh.radiosity));
    fs::remove_all(dir);
}

TEST(StreamingSolver, ResumingFromACheckpointReachesTheSameBits) {
    Scene scene = test::unit_cube(test::grey(0.7), test::grey(0.0));
    scene.faces[0].emission = {3, 3, 3};
    expect_resume_reaches_the_same_bits(Problem(std::move(scene), 2), "resume");
}

// A tiled cube lit by one tile, refined with clusters that receive (returned in place: the
// Problem's visibility refers to its hierarchy).
Problem clusters_problem() {
    Scene scene = test::tiled_cube(6, test::grey(0.7), test::grey(0.0));
    scene.faces[3].emission = {36, 36, 36};
    RefineOptions ro{1e-4, 1.0, 16, 1};
    ro.cluster_receivers = true;
    return Problem(std::move(scene), 16, ro);
}

TEST(StreamingSolver, ResumingWithClustersThatReceiveReachesTheSameBits) {
    // Links that end on clusters keep their vector irradiance in the checkpoint too.
    const Problem pb = clusters_problem();
    size_t on_clusters = 0;
    for (const Link& l : pb.links) on_clusters += pb.h.nodes[l.receiver].cluster;
    ASSERT_GT(on_clusters, 0u);
    expect_resume_reaches_the_same_bits(pb, "resume_clusters");
}

TEST(StreamingSolver, TheBudgetHoldsTheClustersVectorsToo) {
    // With links that end on clusters, each cluster gathers a vector irradiance (96 bytes):
    // part of the solver's state, so part of the least budget it takes; at that budget the
    // state and the chunks held stay within it, and one byte less is refused.
    const Problem pb = clusters_problem();
    const std::string dir = temp_dir("budget_clusters");
    pb.write_store(dir);
    const StoreChunks store(dir, pb.groups.count());
    StreamingOptions opt;
    opt.tolerance = 1e-8;
    StreamingStats free_stats;
    const HierarchicalSolution unlimited =
        solve_streaming(pb.h, pb.groups, store, pb.is_source, pb.outgoing, {}, opt, free_stats);
    const uint64_t n = pb.h.nodes.size();
    const uint64_t per_node = n * (3 * sizeof(RGB) + sizeof(uint32_t) + 2 * sizeof(double));
    const uint64_t vectors = pb.h.cluster_shapes.size() * sizeof(VectorIrradiance);
    ASSERT_GT(vectors, 0u);
    EXPECT_EQ(free_stats.state_bytes, per_node + vectors);
    EXPECT_EQ(free_stats.minimum_budget,
              per_node + vectors + free_stats.chunks_in_flight * free_stats.largest_chunk_bytes);
    expect_the_least_budget_holds(pb, store, opt, free_stats.minimum_budget, unlimited.radiosity);
    fs::remove_all(dir);
}

TEST(StreamingSolver, NonFiniteEmissionStopsAtOnce) {
    Scene scene = test::unit_cube(test::grey(0.5), test::grey(1.0));
    Problem pb(std::move(scene), 2);
    // A NaN that got past the scene's checks (they refuse it in Scene::build).
    for (uint32_t i = 0; i < pb.h.nodes.size(); ++i)
        if (!pb.h.nodes[i].cluster && pb.h.shape(i).face == 4) {
            RGB e = pb.h.emission(i);
            e.z = std::nan("");
            pb.h.set_light(i, pb.h.direct(i), e);
        }
    StreamingOptions opt;
    opt.tolerance = 1e-12;
    uint64_t rounds = 0;
    opt.on_round = [&](uint64_t, double) { return ++rounds, true; };
    StreamingStats stats;
    try {
        solve_streaming(pb.h, pb.groups, MemoryChunks(pb.by_group), pb.is_source, pb.outgoing, {}, opt, stats);
        ADD_FAILURE() << "no error";
    } catch (const NonFiniteError& e) {
        EXPECT_NE(std::string(e.what()).find("streaming solver (block Southwell): the residual is nan at round 0"),
                  std::string::npos) << e.what();
    }
    EXPECT_EQ(rounds, 0u);
}

// The one link record: the links refinement makes go into the store and come back as the
// same records, bit for bit, without a copy field by field.
TEST(StreamingSolver, RefinementsLinksAreTheStoresRecords) {
    static_assert(std::is_same_v<LinkRecord, Link>, "one record");
    Problem pb(test::unit_cube(test::grey(0.5), test::grey(1.0)), 3);
    const std::string dir = temp_dir("records");
    pb.write_store(dir);
    const StoreChunks store(dir, pb.groups.count());
    for (size_t g = 0; g < pb.by_group.size(); ++g) {
        std::vector<Link> back;
        store.read(g, back);
        ASSERT_EQ(back.size(), pb.by_group[g].size());
        EXPECT_EQ(std::memcmp(back.data(), pb.by_group[g].data(), back.size() * sizeof(Link)), 0) << "group " << g;
    }
    fs::remove_all(dir);
}

}  // namespace
}  // namespace hirad
