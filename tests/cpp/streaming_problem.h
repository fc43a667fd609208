// The inputs of a streaming solve made by refinement, shared by the C++ tests of the
// out-of-core solver. Header-only: the build compiles tests/cpp/*_test.cpp and nothing else.
#pragma once
#include <gtest/gtest.h>

#include <algorithm>
#include <memory>
#include <string>
#include <vector>

#include "formats/linkstore.h"
#include "pipeline/geometry/visibility.h"
#include "pipeline/hierarchy/hierarchical_solver.h"
#include "pipeline/hierarchy/refine.h"
#include "pipeline/outofcore/streaming_solver.h"

namespace hirad::test {

// Everything a streaming solve takes, from links made by refinement.
struct Problem {
    Scene scene;
    Hierarchy h;
    std::unique_ptr<Visibility> vis;
    std::vector<Link> links;        // sorted by receiver (for the in-memory solvers)
    SourceGroups groups;
    std::vector<std::vector<Link>> by_group;  // per group, sorted by sort_part
    std::vector<uint8_t> is_source;
    std::vector<double> outgoing;

    // The furnace's refinement of the in-memory test (hierarchy_test.cpp): its couplings sum
    // to the areas within about 2 %.
    Problem(Scene s, uint32_t group_faces, RefineOptions ro = {1e-5 * 6, 0.02, 256, 1}) : scene(std::move(s)), h(scene) {
        vis = std::make_unique<Visibility>(h.faces);
        Refiner refiner(h, *vis, ro);
        RefineStats stats;
        groups = SourceGroups::cut(h, group_faces);
        by_group.assign(groups.count(), {});
        // As the out-of-core rounds link: each group from the root's link to the group's root,
        // so that every source lies in its group.
        refiner.set_radiosity(node_emission(h));
        for (uint32_t g = 0; g < groups.count(); ++g) {
            Link seed;
            seed.receiver = h.root;
            seed.source = groups.roots[g];
            by_group[g] = refiner.run_group({seed}, {0}, stats);
        }
        is_source.assign(h.nodes.size(), 0);
        outgoing.assign(h.nodes.size(), 0.0);
        for (uint32_t g = 0; g < groups.count(); ++g) {
            for (const Link& l : by_group[g]) {
                EXPECT_EQ(groups.of(h, l.source), g);
                links.push_back(l);
                is_source[l.source] = 1;
                outgoing[l.source] += double(l.coupling) / h.nodes[l.source].area;
            }
            sort_part(by_group[g]);
        }
        sort_links(links);
    }
    // The streaming solve of the links kept in memory, to `tolerance`.
    HierarchicalSolution stream(double tolerance) const {
        StreamingOptions opt;
        opt.tolerance = tolerance;
        StreamingStats stats;
        return solve_streaming(h, groups, MemoryChunks(by_group), is_source, outgoing, {}, opt, stats);
    }
    // The store holding the same links: one chunk per part of kChunkLinks.
    void write_store(const std::string& dir) const {
        LinkStoreWriter writer(dir, {1, 2, uint32_t(h.nodes.size()), uint32_t(h.nodes.size())});
        for (uint32_t g = 0; g < by_group.size(); ++g)
            for (uint32_t p = 0; p * kChunkLinks < by_group[g].size(); ++p) {
                const auto begin = by_group[g].begin() + p * kChunkLinks;
                const auto end = by_group[g].begin() + std::min<size_t>(by_group[g].size(), (p + 1) * kChunkLinks);
                write_part(writer, g, p, std::vector<Link>(begin, end));
            }
        writer.commit();
    }
};

}  // namespace hirad::test
