// The hierarchical pipeline out of core: refinement rounds streamed through the link store,
// each followed by a streaming block-Southwell solve, with everything needed to resume a
// killed bake or to re-solve stored links for new materials.
//
// Round 1 links every source group from the root (the link from the whole scene to the
// group's subtree, refined down); round r + 1 re-judges round r's links group by group with
// the radiosity of round r's solve, a stored part at a time. Refinement judges the links
// kChunkLinks at a time, depth first, and the kept ones go to disk a part (kChunkLinks) at a
// time, so link generation holds a bounded number of links, not a group's. Rounds stop when
// nothing splits or at max_rounds.
//
// The store directory holds
//   round-<r>/        the links of round r (formats/linkstore), the last two rounds kept
//   refined-<r>       after round r's refinement: the hierarchy's subdivision log, which
//                     nodes are sources, their outgoing coupling sums
//   solved-<r>        after round r's solve: radiosity per node
//   checkpoint        the running solve's state (streaming_solver.h)
//   final             the round whose links and solution are final
// all written atomically and tagged with fingerprints of the scene's geometry and of the
// refinement settings (and of the materials, where the content depends on them).
#pragma once
#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "pipeline/hierarchy/hierarchy.h"
#include "pipeline/hierarchy/refine.h"
#include "pipeline/outofcore/streaming_solver.h"
#include "pipeline/geometry/visibility.h"

namespace hirad {

struct OutOfCoreOptions {
    RefineOptions refine;
    int max_rounds = 6;
    uint32_t group_faces = 1024;       // input faces per source group (one chunk each)
    std::string store;                 // directory of the link store; empty: links in memory
    StreamingOptions solve;            // tolerance, memory budget, checkpoint interval
    uint64_t geometry_fingerprint = 0; // of the scene's faces
    uint64_t settings_fingerprint = 0; // of the refinement settings
    uint64_t materials_fingerprint = 0;
    bool resume = false;               // continue from what a killed bake with the same inputs left
    bool reuse_links = false;          // solve on the stored final links (same geometry and
                                       // settings; materials may differ): no link estimates
    std::function<void(int round, uint64_t links, uint64_t shots, double residual)> progress;
};

struct OutOfCoreReport {
    HierarchicalSolution solution;
    int rounds = 0;
    bool settled = false;
    bool reused = false;               // links taken from the store, none estimated
    int resumed_from_round = 0;        // 0: started fresh
    std::vector<uint64_t> links_per_round, splits_per_round;
    std::vector<double> refine_seconds, solve_seconds;
    RefineStats refine_stats;
    StreamingStats last_solve;
    uint64_t links = 0;
    uint64_t store_bytes = 0;          // compressed link payload of the final round
    uint64_t transport_bytes = 0;      // of which the transport sections (what a solve reads)
    uint64_t peak_refine_links = 0;    // most links link generation held at once (waiting and kept)
    std::vector<uint8_t> is_source;    // per node of the final hierarchy
    std::string final_round_dir;       // the store's final round (store mode)
    std::vector<Link> memory_links;    // the final links (memory mode)
};

// `hierarchy` must be fresh (nothing subdivided); `visibility` is over its faces.
OutOfCoreReport run_out_of_core(Hierarchy& hierarchy, const Visibility& visibility, const OutOfCoreOptions& options);

// The final links of a store (or of an in-memory run's last round), for the final gather.
std::vector<Link> load_links(const std::string& store_round_dir, size_t groups);

}  // namespace hirad
