// Out of core: the links of one refinement round, written to the link store (or kept in
// memory) group by group as refinement makes them, and read back for the final gather.
//
// The rounds themselves (refine, solve, refine again) are driven by the one refine -> solve
// loop, pipeline/engine/rounds.h; what is kept on disk between steps is the run store,
// run_store.h; the solve is the streaming block Southwell solver, streaming_solver.h.
//
// Refinement judges the links kChunkLinks at a time, depth first, and the kept ones go to the
// writer a part (kChunkLinks) at a time, so link generation holds a bounded number of links,
// not a group's.
#pragma once
#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "pipeline/hierarchy/gather.h"
#include "pipeline/hierarchy/refine.h"
#include "pipeline/outofcore/streaming_solver.h"

namespace hirad {

// The links of one round, on disk (a link store in `dir`) or in memory (`dir` empty).
class RoundWriter {
public:
    RoundWriter(const std::string& dir, size_t groups, LinkStoreInfo info);
    // More of group `group`'s links (the groups one after the other): they leave in parts of
    // kChunkLinks, each sorted, the last of a group at end_group().
    void add(uint32_t group, const std::vector<Link>& links);
    void end_group(uint32_t group);
    // Commits the store (if any) and gives the round's links as chunks.
    std::unique_ptr<LinkChunks> finish(uint32_t nodes, uint32_t elements);
    // Called with every part as it leaves, sorted (the store's order), in group and part order:
    // what is summed over the links (the sources' outgoing coupling) is summed in this order, so
    // it does not depend on the order refinement kept them in (nor on where it ran).
    std::function<void(const std::vector<Link>& sorted_part)> on_part;

private:
    void put_part(uint32_t group);

    std::string dir_;
    std::unique_ptr<LinkStoreWriter> writer_;
    std::vector<std::vector<Link>> memory_;
    std::vector<Link> pending_;  // the current group's links not yet in a part
    uint32_t parts_ = 0;               // parts of the current group written
};

// All links of `chunks` (a store's round or an in-memory round), sorted by receiver: what the
// final gather walks.
std::vector<Link> all_links(const LinkChunks& chunks);

// The final links of a store's round directory as the final gather reads them (12 bytes a
// link, by receiver then source: the order all_links gives), over a hierarchy of `nodes`
// nodes. The store is read twice, a part at a time (counts per receiver, then each link put
// in its row), so that no 24-byte copy of all the links is ever held.
GatherLinks gather_links(const std::string& store_round_dir, size_t groups, size_t nodes);
GatherLinks gather_links(const LinkChunks& chunks, size_t nodes);

}  // namespace hirad
