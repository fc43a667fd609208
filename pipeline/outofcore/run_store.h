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
//   spill-<r>/        distributed refinement of round r (rounds.h, RemoteRefineFn): one
//                     directory per range of source groups a worker refined,
//                     <begin:08x>-<end:08x>/, holding its links as a link store in the worker's
//                     own numbering of new nodes and `log` (SpillLog); removed once merged
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
#include <utility>
#include <vector>

#include "pipeline/geometry/scene.h"
#include "pipeline/hierarchy/hierarchical_solver.h"
#include "pipeline/hierarchy/hierarchy.h"
#include "pipeline/hierarchy/refine.h"

namespace hirad {

// What the stored links and solutions depend on, each as a 64-bit hash.
struct StoreFingerprints {
    uint64_t geometry = 0;   // every face's corners and mesh
    uint64_t settings = 0;   // refinement settings: epsilon, min_area, samples, seed, rounds, groups, relative, spread
    uint64_t materials = 0;  // every face's reflectance and emission

    // `epsilon` is the relative threshold as configured (not yet scaled by the emitted power).
    // `luminaires` (luminaires_fingerprint, 0 for none) enters the geometry too: the
    // hierarchy is split for the luminaires' light before any link is made.
    static StoreFingerprints of(const Scene& scene, double epsilon, double min_area, int samples, uint64_t seed,
                                int max_rounds, uint32_t group_faces, uint64_t luminaires = 0, double relative = 0,
                                double spread = 0);
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

// What a worker of a distributed refinement made of its groups [begin, end), besides their links
// (which use its own numbering for the nodes it made: `nodes` and above).
struct SpillLog {
    uint32_t begin = 0, end = 0;           // the source groups
    uint32_t nodes = 0;                    // nodes of the hierarchy the worker started from
    std::vector<uint32_t> log;             // the elements it subdivided, in its numbering, in order
    std::vector<uint32_t> group_log_end;   // per group: one past its last entry in `log`
    RefineStats stats;                     // its estimates, splits and rays
    uint64_t held = 0;                     // the most links it held at once
    std::vector<double> group_seconds;     // per group: wall time of its refinement
    std::vector<uint64_t> group_links;     // per group: links kept
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

    // Distributed refinement. The state a worker starts round r's refinement from: round
    // r - 1's refinement replayed into `h` (fresh) and its solution; nothing for r = 1. Errors
    // name the file when the state is missing or another run's.
    ResumePoint round_start(Hierarchy& h, int round) const;
    std::string spill_dir(int round) const;                                   // <root>/spill-<r>
    std::string spill_range_dir(int round, uint32_t begin, uint32_t end) const;
    // The spill log in a range's directory, tied to this run and round.
    void write_spill_log(const std::string& range_dir, int round, const SpillLog& log) const;
    SpillLog read_spill_log(const std::string& range_dir, int round) const;
    // The ranges of round r's spill: they must tile [0, groups) (an error naming what is
    // missing or overlapping otherwise). Directories of other names (a worker's temporaries)
    // are ignored.
    std::vector<std::pair<uint32_t, uint32_t>> spill_ranges(int round, uint32_t groups) const;

private:
    std::string refined_path(int r) const;
    std::string solved_path(int r) const;
    std::string final_path() const;

    std::string root_;
    StoreFingerprints fp_;
    uint64_t links_fp_ = 0, run_fp_ = 0;
};

}  // namespace hirad
