// Hierarchical radiosity as rounds: refine the links, solve, refine again with the new
// radiosity, until no link splits or `max_rounds` rounds were solved. One loop for both ways
// of holding the links:
//   in memory   all links in one vector, solved by push-pull Jacobi, Gauss-Seidel or
//               Southwell (hierarchical_solver.h);
//   streamed    links written group by group to a link store (or to memory chunks) and
//               solved by streaming block Southwell within a memory budget
//               (streaming_solver.h), every step kept in the run store (run_store.h) so that a
//               killed bake resumes and a finished one lends its links to new materials.
//
// The loop (run_rounds) is
//   round 0 -> refine from the root's links (judged by emission alone) -> round 1
//   solve round r (starting from round r - 1's radiosity, new nodes taking their parent's)
//   stop if r = max_rounds; else refine round r's links with that radiosity
//   nothing split: round r is final (settled); else it becomes round r + 1, solve again.
// Each way supplies the three stages (RoundStages): refine, keep or discard what refinement
// made, solve.
#pragma once
#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "pipeline/geometry/visibility.h"
#include "pipeline/hierarchy/hierarchical_solver.h"
#include "pipeline/hierarchy/hierarchy.h"
#include "pipeline/hierarchy/refine.h"
#include "pipeline/outofcore/run_store.h"
#include "pipeline/outofcore/streaming_solver.h"

namespace hirad {

// What a running hierarchical solve reports (from its worker thread).
struct RoundProgress {
    int round = 0;
    uint64_t links = 0;       // links of the round being solved
    uint64_t iteration = 0;   // iterations (or shooting rounds) so far, all rounds
    double residual = 1;      // of the running solve
    // While a round's links are made out of core: the source groups linked so far and in all
    // (groups 0: solving, or linking in memory), `links` then the links kept so far.
    uint64_t groups_linked = 0, groups = 0;
};
using RoundProgressFn = std::function<void(const RoundProgress&)>;

// The steps a way of holding links supplies to the loop.
class RoundStages {
public:
    virtual ~RoundStages() = default;
    // Refines into round `next` (1: from the root), judged with per-node radiosity `b`.
    // Returns the number of links split. The result is pending until commit or discard.
    virtual uint64_t refine(int next, const std::vector<RGB>& b) = 0;
    // The pending links become round `next`'s.
    virtual void commit(int next) = 0;
    // Nothing split: the pending links are dropped, the current round stays final.
    virtual void discard(int next) = 0;
    // Solves round `round`'s links from `start` (per node; the stage may take it over).
    virtual HierarchicalSolution solve(int round, std::vector<RGB> start) = 0;
    // Round `round` was solved (persistence hook).
    virtual void solved(int round, const HierarchicalSolution& solution) {}
};

// Where the loop stands; a resumed run starts from a stored round.
struct RoundsState {
    int round = 0;               // the round whose links the stages hold (0: none yet)
    bool solved = false;         // `solution` is that round's
    bool settled = false;        // refinement split nothing: the round is final
    bool stop_after_solve = false;  // reused links: solve them once, refine nothing
    HierarchicalSolution solution;
};

// What every pass of the loop recorded.
struct RoundsLog {
    std::vector<uint64_t> refine_splits;   // per refinement pass, the first (from the root) included
    std::vector<uint8_t> refine_kept;      // per pass: 1 when its links became a round (0: nothing split)
    std::vector<double> refine_seconds;    // per refinement pass
    std::vector<double> solve_seconds;     // per solve
};

// Called before every solve, when refinement may have made new elements: gives them their
// source terms (the luminaires' light, luminaire.h). Empty: nothing to do.
using PrepareFn = std::function<void()>;

// The loop. On return `state.solved` holds (a logic error otherwise).
void run_rounds(const Hierarchy& h, RoundStages& stages, int max_rounds, RoundsState& state, RoundsLog& log,
                const PrepareFn& prepare = {});

// A finished hierarchical solve, before it is published (engine.h).
struct RoundsRun {
    HierarchicalSolution solution;    // per node of the hierarchy
    RoundsState state;
    RoundsLog log;
    RefineStats refine;
    std::vector<uint64_t> links_per_round;
    uint64_t iterations = 0;          // all rounds
    std::vector<double> residual_history;  // all rounds (in memory) or the last (streamed)
    // in memory: the final links; streamed: read from `store_round` on demand (or in memory
    // when the store has no root)
    std::vector<Link> links;
    uint64_t link_count = 0;
    // streamed only
    std::string store_round;          // the final round's links in the store
    size_t groups = 0;                // source groups
    int resumed_from_round = 0;
    uint64_t store_bytes = 0, transport_bytes = 0, peak_refine_links = 0;
    StreamingStats last_solve;
    // distributed only: per round refined remotely, the workers' ranges and the driver's merge
    std::vector<double> merge_seconds;
};

enum class PushPull { Jacobi, GaussSeidel, Southwell };

// In memory: push-pull solves of `solver` kind.
RoundsRun run_in_memory(Hierarchy& h, const Visibility& vis, const RefineOptions& refine, int max_rounds,
                        PushPull solver, const SolverOptions& solve, const RoundProgressFn& progress,
                        const PrepareFn& prepare = {});

// Distributed link generation. Refinement visits the source groups one after the other, and a
// group's links all leave nodes of its own subtree. What it decides depends on the hierarchy the
// round started from, the radiosity it judges by, and the nodes a link joins through their keys
// (Node::key seeds the estimates), never through their indices. So any range of groups can be
// refined on another machine, on its own copy of the hierarchy rebuilt from the run store, which
// numbers the nodes it makes its own way (refine_range). The driver then merges the ranges in
// group order: it replays each group's subdivisions into the one hierarchy, skipping those an
// earlier group made, which numbers the new nodes exactly as one machine refining every group
// would; it maps each worker's numbering onto that, and writes the round's chunks (sorted parts,
// so the order refinement kept them in does not matter) and manifest. Store, checksums and
// solution are the single-machine bake's, bit for bit, whatever the ranges and the workers.
//
// A RemoteRefineFn has round `round`'s groups [0, groups) refined by workers (each range by
// refine_range, into store.spill_range_dir) and returns when every range is complete (throws
// otherwise). The ranges it picks are its own; together they must cover every group once.
using RemoteRefineFn = std::function<void(int round, uint32_t groups)>;

// A worker's share: round `round`'s refinement of groups [begin, end), from the run store's
// state (round - 1 refined and solved; nothing for round 1), written to the store's spill
// directory for the range (assembled under a temporary name, renamed when complete; a range
// already complete is left as it is, and its log returned). `h` must be fresh.
SpillLog refine_range(Hierarchy& h, const Visibility& vis, const RefineOptions& refine, const SourceGroups& groups,
                      const RunStore& store, int round, uint32_t begin, uint32_t end);

// Streamed through the run store (in memory when the store has no root): `h` must be fresh
// (or only split for its luminaires, before any links), `groups` cut from it (SourceGroups::cut),
// `store` made for that many groups. With `remote`, each refinement is distributed (the store
// must be on disk).
RoundsRun run_streamed(Hierarchy& h, const Visibility& vis, const RefineOptions& refine, int max_rounds,
                       const SourceGroups& groups, const StreamingOptions& solve, RunStore& store, bool resume,
                       bool reuse_links, const RoundProgressFn& progress, const PrepareFn& prepare = {},
                       const RemoteRefineFn& remote = {});

}  // namespace hirad
