#include "pipeline/engine/rounds.h"

#include <atomic>
#include <chrono>
#include <filesystem>
#include <memory>
#include <stdexcept>
#include <unistd.h>

#include "pipeline/outofcore/outofcore.h"

namespace hirad {

namespace fs = std::filesystem;

namespace {

double seconds_since(std::chrono::steady_clock::time_point t) {
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - t).count();
}

// Round `next`'s refinement of source group g: from the root's link to the group (round 1), or
// from round next - 1's links of the group in `previous`, part by part. Kept links go to `keep`
// (rounds.h: batches of exactly kChunkLinks, in an order that depends only on the input).
// Returns the most links held at once.
uint64_t refine_group(Refiner& refiner, const Hierarchy& h, const SourceGroups& groups, const LinkChunks* previous,
                      int next, uint32_t g, RefineStats& stats, const std::function<void(std::vector<Link>&)>& keep) {
    uint64_t held = 0;
    const size_t pieces = next == 1 ? 1 : previous->parts(g);
    std::vector<Link> frontier;
    for (size_t p = 0; p < pieces; ++p) {
        std::vector<uint8_t> evaluated;
        frontier.clear();
        if (next == 1) {
            Link seed;
            seed.receiver = h.root;
            seed.source = groups.roots[g];
            frontier.push_back(seed);
            evaluated.push_back(0);
        } else {
            previous->read(g, p, frontier);
            evaluated.assign(frontier.size(), 1);
        }
        held = std::max(held, refiner.run_group(std::move(frontier), std::move(evaluated), stats, kChunkLinks, keep));
        frontier = {};
    }
    return held;
}

// All links in one vector, solved by a push-pull solver.
class MemoryStages : public RoundStages {
public:
    MemoryStages(Hierarchy& h, const Visibility& vis, const RefineOptions& ropt, PushPull kind,
                 const SolverOptions& so, const RoundProgressFn& progress, RoundsRun& run)
        : h_(h), refiner_(h, vis, ropt), kind_(kind), so_(so), progress_(progress), run_(run) {}

    uint64_t refine(int next, const std::vector<RGB>& b) override {
        const uint64_t before = run_.refine.split;
        pending_ = next == 1 ? refiner_.initial_links(b, run_.refine) : refiner_.refine(run_.links, b, run_.refine);
        refiner_.release();
        return run_.refine.split - before;
    }
    void commit(int) override {
        run_.links.swap(pending_);
        pending_ = {};
        sort_links(run_.links);
        run_.links_per_round.push_back(run_.links.size());
    }
    void discard(int) override { pending_ = {}; }
    HierarchicalSolution solve(int round, std::vector<RGB> start) override {
        SolverOptions so = so_;
        const uint64_t links = run_.links.size();
        so.on_iteration = [&](const IterationReport& rep) {
            if (progress_) progress_({round, links, rep.iteration, rep.residual});
            return !so_.on_iteration || so_.on_iteration(rep);
        };
        HierarchicalSolution sol;
        switch (kind_) {
            case PushPull::Jacobi: sol = solve_push_pull(h_, run_.links, start, so); break;
            case PushPull::GaussSeidel: sol = solve_gauss_seidel_push_pull(h_, run_.links, start, so); break;
            case PushPull::Southwell: sol = solve_southwell_push_pull(h_, run_.links, start, so); break;
        }
        run_.iterations += sol.iterations;
        run_.residual_history.insert(run_.residual_history.end(), sol.residual_history.begin(),
                                     sol.residual_history.end());
        return sol;
    }

private:
    Hierarchy& h_;
    Refiner refiner_;
    PushPull kind_;
    SolverOptions so_;
    const RoundProgressFn& progress_;
    RoundsRun& run_;
    std::vector<Link> pending_;
};

// Links group by group through a RoundWriter (the store's round directory, or memory chunks),
// solved by streaming block Southwell; every step recorded in the run store.
class StreamedStages : public RoundStages {
public:
    StreamedStages(Hierarchy& h, const Visibility& vis, const RefineOptions& ropt, const SourceGroups& groups,
                   const StreamingOptions& so, RunStore& store, const RoundProgressFn& progress, RoundsRun& run)
        : h_(h), groups_(groups), ng_(groups.count()), refiner_(h, vis, ropt), so_(so), store_(store),
          progress_(progress), run_(run), info_{store.links_fingerprint(), store.settings_fingerprint(), UINT32_MAX, 0} {}

    // Starts from a stored round (resume or reuse).
    void adopt(int round, std::vector<uint8_t> is_source, std::vector<double> outgoing) {
        chunks_ = std::make_unique<StoreChunks>(store_.round_dir(round), ng_);
        is_source_ = std::move(is_source);
        outgoing_ = std::move(outgoing);
    }

    uint64_t refine(int next, const std::vector<RGB>& b) override {
        const uint64_t splits_before = run_.refine.split;
        out_ = std::make_unique<RoundWriter>(store_.round_dir(next), ng_, info_);
        src_.assign(h_.nodes.size(), 0);
        own_.assign(h_.nodes.size(), 0.0);
        // The sources' outgoing coupling, summed over the parts as they leave (sorted, in group
        // and part order), so that it is the same wherever and in whatever order they were made.
        out_->on_part = [&](const std::vector<Link>& part) {
            src_.resize(h_.nodes.size(), 0);
            own_.resize(h_.nodes.size(), 0.0);
            for (const Link& l : part) {
                src_[l.source] = 1;
                own_[l.source] += h_.sent(l) / h_.nodes[l.source].area;
            }
        };
        if (remote_) {
            refine_remote(next);
        } else {
            refiner_.set_radiosity(b, next > 1);
            uint64_t kept_links = 0;
            for (uint32_t g = 0; g < ng_; ++g) {
                // Kept links leave for the store a part at a time, as refinement makes them; what
                // refinement holds is bounded by kChunkLinks per level of depth.
                const uint64_t held = refine_group(refiner_, h_, groups_, chunks_.get(), next, g, run_.refine,
                                                   [&](std::vector<Link>& kept) {
                                                       kept_links += kept.size();
                                                       out_->add(g, kept);
                                                   });
                run_.peak_refine_links = std::max<uint64_t>(run_.peak_refine_links, held);
                out_->end_group(g);
                if (progress_) progress_({next, kept_links, shots_, 1.0, g + 1, ng_});
            }
        }
        refiner_.release();
        src_.resize(h_.nodes.size(), 0);
        own_.resize(h_.nodes.size(), 0.0);
        return run_.refine.split - splits_before;
    }
    void commit(int next) override {
        uint32_t elements = 0;
        for (const Node& node : h_.nodes) elements += !node.cluster;
        chunks_ = out_->finish(static_cast<uint32_t>(h_.nodes.size()), elements);
        out_.reset();
        is_source_ = std::move(src_);
        outgoing_ = std::move(own_);
        run_.links_per_round.push_back(chunks_->total_links());
        store_.refined(next, h_, is_source_, outgoing_);
    }
    void discard(int next) override {
        store_.discard_round(next);
        out_.reset();
    }
    HierarchicalSolution solve(int round, std::vector<RGB> start) override {
        // Solve round `round`'s links, checkpointing into the store.
        StreamingOptions so = so_;
        so.checkpoint_path = store_.checkpoint_path();
        so.checkpoint_fingerprint = store_.checkpoint_fingerprint(round);
        const uint64_t links_now = chunks_->total_links();
        so.on_round = [&](uint64_t it, double res) {
            if (progress_) progress_({round, links_now, shots_ + it, res});
            return !so_.on_round || so_.on_round(it, res);
        };
        run_.last_solve = StreamingStats{};
        HierarchicalSolution sol = solve_streaming(h_, groups_, *chunks_, is_source_, outgoing_, std::move(start), so,
                                                   run_.last_solve);
        shots_ += run_.last_solve.rounds;
        return sol;
    }
    void solved(int round, const HierarchicalSolution& solution) override { store_.solved(round, solution); }

    const LinkChunks& chunks() const { return *chunks_; }
    void set_remote(const RemoteRefineFn& remote) { remote_ = remote; }

private:
    // Round `next`'s groups refined by the workers, merged in group order (rounds.h).
    void refine_remote(int next) {
        if (!store_.on_disk()) throw std::invalid_argument("distributed refinement needs a link store on disk");
        std::error_code ec;
        fs::remove_all(store_.spill_dir(next), ec);  // a killed run's, never merged
        remote_(next, static_cast<uint32_t>(ng_));
        const auto t0 = std::chrono::steady_clock::now();
        const auto ranges = store_.spill_ranges(next, static_cast<uint32_t>(ng_));
        const uint32_t start_nodes = static_cast<uint32_t>(h_.nodes.size());
        struct Range {
            std::string dir;
            SpillLog log;
            std::unique_ptr<StoreChunks> links;
            std::vector<uint32_t> made;   // the worker's new nodes (its index - log.nodes) -> ours
            size_t at = 0;                // entries of its log merged so far
        };
        std::vector<Range> rs;
        for (const auto& [b, e] : ranges) {
            Range r;
            r.dir = store_.spill_range_dir(next, b, e);
            r.log = store_.read_spill_log(r.dir, next);
            if (r.log.begin != b || r.log.end != e || r.log.nodes != start_nodes)
                throw std::runtime_error(r.dir + "/log: the spill of groups [" + std::to_string(b) + ", " +
                                         std::to_string(e) + ") started from another hierarchy (" +
                                         std::to_string(r.log.nodes) + " nodes, not " + std::to_string(start_nodes) + ")");
            r.links = std::make_unique<StoreChunks>(r.dir, ng_);
            rs.push_back(std::move(r));
        }
        auto ours = [&](Range& r, uint32_t i, const char* what) {
            if (i < r.log.nodes) return i;
            if (i - r.log.nodes >= r.made.size())
                throw std::runtime_error(r.dir + ": " + what + " " + std::to_string(i) +
                                         " is not a node the worker had made by then");
            return r.made[i - r.log.nodes];
        };
        std::vector<Link> part;
        size_t w = 0;
        for (uint32_t g = 0; g < ng_; ++g) {
            while (g >= rs[w].log.end) ++w;
            Range& r = rs[w];
            // The group's subdivisions, in its order: those an earlier group made already exist.
            for (const uint32_t end = r.log.group_log_end[g - r.log.begin]; r.at < end; ++r.at) {
                const uint32_t node = ours(r, r.log.log[r.at], "subdivision log entry");
                if (h_.nodes[node].cluster)
                    throw std::runtime_error(r.dir + "/log: entry " + std::to_string(r.at) + " names a cluster");
                h_.subdivide(node);
                const Node& n = h_.nodes[node];
                for (uint32_t c = 0; c < n.child_count; ++c) r.made.push_back(n.first_child + c);
            }
            for (size_t p = 0; p < r.links->parts(g); ++p) {
                r.links->read(g, p, part);
                for (Link& l : part) {
                    l.receiver = ours(r, l.receiver, "link receiver");
                    l.source = ours(r, l.source, "link source");
                }
                out_->add(g, part);
            }
            out_->end_group(g);
        }
        for (const Range& r : rs) {
            run_.refine.evaluated += r.log.stats.evaluated;
            run_.refine.split += r.log.stats.split;
            run_.refine.rays += r.log.stats.rays;
            run_.peak_refine_links = std::max(run_.peak_refine_links, r.log.held);
        }
        rs.clear();
        fs::remove_all(store_.spill_dir(next));
        run_.merge_seconds.push_back(seconds_since(t0));
    }

    Hierarchy& h_;
    const SourceGroups& groups_;
    size_t ng_;
    Refiner refiner_;
    StreamingOptions so_;
    RunStore& store_;
    const RoundProgressFn& progress_;
    RoundsRun& run_;
    LinkStoreInfo info_;
    std::unique_ptr<LinkChunks> chunks_;     // the current round's links
    std::vector<uint8_t> is_source_;         // per node, of the current round's links
    std::vector<double> outgoing_;
    std::unique_ptr<RoundWriter> out_;       // refinement's pending round
    std::vector<uint8_t> src_;
    std::vector<double> own_;
    uint64_t shots_ = 0;
    RemoteRefineFn remote_;
};

}  // namespace

void run_rounds(const Hierarchy& h, RoundStages& stages, int max_rounds, RoundsState& s, RoundsLog& log,
                const PrepareFn& prepare) {
    if (max_rounds < 1) throw std::invalid_argument("max_rounds must be at least 1");
    auto now = [] { return std::chrono::steady_clock::now(); };
    for (;;) {
        if (!s.solved && s.round > 0) {
            // Every round's solve starts from the emission, not from the previous round's
            // radiosity. Iterating from E, Jacobi, Gauss-Seidel and Southwell approach the
            // solution from below (M^-1 = sum (diag(rho) F)^k is non-negative), so a stopped
            // solve misses light but never holds light the round's links do not carry: a warm
            // start kept round 1's coarse light behind walls that later rounds closed (stale
            // light within the tolerance, 2e-3 of the lit side on the thin-wall test). It also
            // makes a resumed round the same computation as one never interrupted.
            if (prepare) prepare();
            std::vector<RGB> start = node_emission(h);
            for (size_t i = start.size(); i < h.nodes.size(); ++i) start.push_back(start[h.nodes[i].parent]);
            // The previous round's solution was what refinement read; it is not held through
            // this solve (on the 10M-triangle building about 1 GB), and the start is the solve's
            // to take (out of core it becomes the solver's B, not a copy of it).
            s.solution = HierarchicalSolution{};
            const auto t0 = now();
            s.solution = stages.solve(s.round, std::move(start));
            log.solve_seconds.push_back(seconds_since(t0));
            s.solved = true;
            stages.solved(s.round, s.solution);
        }
        if (s.stop_after_solve || (s.round > 0 && s.settled) || s.round >= max_rounds) break;
        const int next = s.round + 1;
        const auto t0 = now();
        const uint64_t splits = stages.refine(next, next == 1 ? node_emission(h) : s.solution.radiosity);
        log.refine_seconds.push_back(seconds_since(t0));
        log.refine_splits.push_back(splits);
        if (next > 1 && splits == 0) {
            stages.discard(next);
            log.refine_kept.push_back(0);
            s.settled = true;
            break;
        }
        stages.commit(next);
        log.refine_kept.push_back(1);
        s.round = next;
        s.solved = false;
    }
    if (!s.solved) throw std::logic_error("hierarchical rounds ended without a solution");
}

RoundsRun run_in_memory(Hierarchy& h, const Visibility& vis, const RefineOptions& refine, int max_rounds,
                        PushPull solver, const SolverOptions& solve, const RoundProgressFn& progress,
                        const PrepareFn& prepare) {
    RoundsRun run;
    MemoryStages stages(h, vis, refine, solver, solve, progress, run);
    run_rounds(h, stages, max_rounds, run.state, run.log, prepare);
    run.solution = run.state.solution;
    run.link_count = run.links.size();
    return run;
}

RoundsRun run_streamed(Hierarchy& h, const Visibility& vis, const RefineOptions& refine, int max_rounds,
                       const SourceGroups& groups, const StreamingOptions& solve, RunStore& store, bool resume,
                       bool reuse_links, const RoundProgressFn& progress, const PrepareFn& prepare,
                       const RemoteRefineFn& remote) {
    RoundsRun run;
    run.groups = groups.count();
    if (remote && !store.on_disk()) throw std::invalid_argument("distributed refinement needs a link store on disk");
    store.open(resume || reuse_links);
    StreamedStages stages(h, vis, refine, groups, solve, store, progress, run);
    stages.set_remote(remote);
    // What an earlier bake left: final links to reuse, or the last finished step to resume from.
    ResumePoint at = store.resume_point(h, reuse_links, resume, max_rounds);
    if (at.round > 0) {
        stages.adopt(at.round, std::move(at.is_source), std::move(at.outgoing));
        run.state.round = at.round;
        run.state.solved = at.solved;
        run.state.solution = std::move(at.solution);
        run.state.settled = at.settled;
        run.state.stop_after_solve = at.reused;
        if (!at.reused) run.resumed_from_round = at.round;
    }
    run_rounds(h, stages, max_rounds, run.state, run.log, prepare);
    run.solution = run.state.solution;
    run.iterations = run.solution.iterations;
    run.residual_history = run.solution.residual_history;
    const LinkChunks& chunks = stages.chunks();
    run.link_count = chunks.total_links();
    if (store.on_disk()) {
        auto* stored = dynamic_cast<const StoreChunks*>(&chunks);
        run.store_bytes = stored ? stored->reader().total_compressed_bytes() : 0;
        run.transport_bytes = stored ? stored->reader().total_transport_bytes() : 0;
        run.store_round = store.round_dir(run.state.round);
        if (!run.state.stop_after_solve) store.finish(run.state.round, run.state.settled);
    } else {
        run.links = all_links(chunks);
    }
    return run;
}

SpillLog refine_range(Hierarchy& h, const Visibility& vis, const RefineOptions& refine, const SourceGroups& groups,
                      const RunStore& store, int round, uint32_t begin, uint32_t end) {
    if (begin >= end || end > groups.count())
        throw std::invalid_argument("refine_range: groups [" + std::to_string(begin) + ", " + std::to_string(end) +
                                    ") are not a range of the " + std::to_string(groups.count()) + " source groups");
    const std::string dir = store.spill_range_dir(round, begin, end);
    if (fs::exists(dir + "/log")) return store.read_spill_log(dir, round);  // another attempt finished it
    ResumePoint at = store.round_start(h, round);
    Refiner refiner(h, vis, refine);
    refiner.set_radiosity(round == 1 ? node_emission(h) : at.solution.radiosity, round > 1);
    std::unique_ptr<StoreChunks> previous;
    if (round > 1) previous = std::make_unique<StoreChunks>(store.round_dir(round - 1), groups.count());
    SpillLog log;
    log.begin = begin;
    log.end = end;
    log.nodes = static_cast<uint32_t>(h.nodes.size());
    const size_t own = h.subdivided.size();
    // Assembled under a name of this process's, renamed when complete.
    static std::atomic<uint64_t> attempt{0};
    const std::string tmp = dir + ".tmp-" + std::to_string(::getpid()) + "-" + std::to_string(attempt++);
    fs::create_directories(store.spill_dir(round));
    fs::remove_all(tmp);
    const uint64_t rays0 = vis.rays_cast();
    {
        RoundWriter out(tmp, groups.count(), LinkStoreInfo{store.links_fingerprint(), store.settings_fingerprint(),
                                                           UINT32_MAX, 0});
        for (uint32_t g = begin; g < end; ++g) {
            const auto t0 = std::chrono::steady_clock::now();
            uint64_t kept = 0;
            log.held = std::max(log.held, refine_group(refiner, h, groups, previous.get(), round, g, log.stats,
                                                       [&](std::vector<Link>& links) {
                                                           kept += links.size();
                                                           out.add(g, links);
                                                       }));
            out.end_group(g);
            log.group_log_end.push_back(static_cast<uint32_t>(h.subdivided.size() - own));
            log.group_seconds.push_back(seconds_since(t0));
            log.group_links.push_back(kept);
        }
        uint32_t elements = 0;
        for (const Node& node : h.nodes) elements += !node.cluster;
        out.finish(static_cast<uint32_t>(h.nodes.size()), elements);
    }
    log.stats.rays = vis.rays_cast() - rays0;
    log.log.assign(h.subdivided.begin() + long(own), h.subdivided.end());
    store.write_spill_log(tmp, round, log);
    std::error_code ec;
    fs::rename(tmp, dir, ec);
    if (ec) {
        // Another attempt at the same range got there first: its result is the same.
        fs::remove_all(tmp);
        if (!fs::exists(dir + "/log")) throw std::runtime_error(dir + ": cannot be renamed into place: " + ec.message());
    }
    return log;
}

}  // namespace hirad
