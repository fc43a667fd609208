// The run store: everything a hierarchical bake keeps on disk between its steps, so that a
// killed bake can resume and a finished one can hand its links to a bake with new materials.
// The refine -> solve loop (pipeline/engine/rounds.h) and the streaming solver call it; it
// decides nothing about the physics, only what is kept, what is trusted and what is removed.
//
// The store directory holds
//   round-<r>/        the links of round r (formats/linkstore), the last two rounds kept
//   refined-<r>       after round r's refinement: the hierarchy's subdivision log, which
//                     nodes are sources, their outgoing coupling sums
//   solved-<r>        after round r's solve: radiosity per node
//   checkpoint        the running solve's state (streaming_solver.h)
//   final             the round whose links and solution are final
// all written atomically (StateFile::write) and tagged with a fingerprint:
//   links fingerprint = geometry x refinement settings x number of source groups
//                       (what the links depend on);
//   run fingerprint   = links fingerprint x materials (what refinement's oracle, hence every
//                       intermediate round, and every solution also depend on).
// A state file whose fingerprint differs belongs to another scene or config and is ignored
// (or refused, where the caller asked for it explicitly).
//
// A store with an empty root keeps nothing: every call is a no-op and nothing is resumed,
// which is how the same loop runs in memory.
#pragma once
#include <cstdint>
#include <string>
#include <vector>

#include "pipeline/geometry/scene.h"
#include "pipeline/hierarchy/hierarchical_solver.h"
#include "pipeline/hierarchy/hierarchy.h"

namespace hirad {

// What the stored links and solutions depend on, each as a 64-bit hash.
struct StoreFingerprints {
    uint64_t geometry = 0;   // every face's corners and mesh
    uint64_t settings = 0;   // refinement settings: epsilon, min_area, samples, seed, rounds, groups
    uint64_t materials = 0;  // every face's reflectance and emission

    // `epsilon` is the relative threshold as configured (not yet scaled by the emitted power).
    // `luminaires` (luminaires_fingerprint, 0 for none) enters the geometry too: the
    // hierarchy is split for the luminaires' light before any link is made.
    static StoreFingerprints of(const Scene& scene, double epsilon, double min_area, int samples, uint64_t seed,
                                int max_rounds, uint32_t group_faces, uint64_t luminaires = 0);
};

// Where a run starts: round 0 (fresh) or a stored round whose refinement was replayed into
// the hierarchy.
struct ResumePoint {
    int round = 0;                    // the round whose links are stored (0: start fresh)
    std::vector<uint8_t> is_source;   // per node, of that round's links
    std::vector<double> outgoing;     // per node, of that round's links
    bool solved = false;              // `solution` is that round's solution
    HierarchicalSolution solution;
    bool settled = false;             // the stored final round had settled
    bool reused = false;              // the links are a finished run's final links
};

class RunStore {
public:
    // `root` empty: a store in memory that keeps nothing. `groups`: the number of source groups
    // (part of the links fingerprint).
    RunStore(std::string root, const StoreFingerprints& fingerprints, size_t groups);

    bool on_disk() const { return !root_.empty(); }
    const std::string& root() const { return root_; }
    uint64_t links_fingerprint() const { return links_fp_; }
    uint64_t settings_fingerprint() const { return fp_.settings; }

    // Creates the directory; unless the run resumes or reuses links, removes what earlier runs
    // left in it (only the names listed above, the final marker first).
    void open(bool keep_earlier);

    // The stored state to start from. `reuse_links`: the final links of a finished run with the
    // same geometry and settings (an error if there are none); `resume`: the last step a
    // killed run with the same inputs finished (or a finished run's final state). The stored
    // refinement is replayed into `h` (which must be fresh).
    ResumePoint resume_point(Hierarchy& h, bool reuse_links, bool resume, int max_rounds) const;

    // The directory of round r's links ("" in memory).
    std::string round_dir(int r) const;
    // Where the running solve of round r checkpoints ("" in memory), and the fingerprint that
    // ties the checkpoint to the run and the round.
    std::string checkpoint_path() const;
    uint64_t checkpoint_fingerprint(int round) const;

    // After round r's refinement was committed: its subdivision log and per-node arrays.
    void refined(int round, const Hierarchy& h, const std::vector<uint8_t>& is_source,
                 const std::vector<double>& outgoing) const;
    // Refinement of round r made nothing new: its (uncommitted) links are removed.
    void discard_round(int round) const;
    // After round r's solve: its solution is kept, the checkpoint and round r - 1 removed.
    void solved(int round, const HierarchicalSolution& solution) const;
    // The run is over: round r is final (its refinement becomes usable for other materials).
    void finish(int round, bool settled) const;

private:
    std::string refined_path(int r) const;
    std::string solved_path(int r) const;
    std::string final_path() const;

    std::string root_;
    StoreFingerprints fp_;
    uint64_t links_fp_ = 0, run_fp_ = 0;
};

}  // namespace hirad
