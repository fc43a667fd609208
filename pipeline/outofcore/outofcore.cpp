#include "pipeline/outofcore/outofcore.h"

#include <chrono>
#include <filesystem>
#include <memory>
#include <stdexcept>

#include "pipeline/hierarchy/hierarchical_solver.h"
#include "formats/statefile.h"

namespace fs = std::filesystem;

namespace hirad {

namespace {

double seconds_since(std::chrono::steady_clock::time_point t) {
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - t).count();
}

Link to_link(const LinkRecord& r) { return {r.receiver, r.source, r.coupling, r.unoccluded, r.visibility, r.error}; }
LinkRecord to_record(const Link& l) { return {l.receiver, l.source, l.coupling, l.unoccluded, l.visibility, l.error}; }

// The links of one round, on disk or in memory.
class Round {
public:
    Round(const std::string& dir, size_t groups, LinkStoreInfo info) : dir_(dir), memory_(groups) {
        if (!dir_.empty()) writer_ = std::make_unique<LinkStoreWriter>(dir_, info);
    }
    // More of group `group`'s links (the groups one after the other): they leave in parts of
    // kChunkLinks, each sorted, the last of a group at end_group().
    void add(uint32_t group, const std::vector<LinkRecord>& links) {
        for (const LinkRecord& l : links) {
            pending_.push_back(l);
            if (pending_.size() == kChunkLinks) put_part(group);
        }
    }
    void end_group(uint32_t group) {
        if (!pending_.empty()) put_part(group);
        parts_ = 0;
    }
    // Commits the store (if any) and gives the round's links as chunks.
    std::unique_ptr<LinkChunks> finish(uint32_t nodes, uint32_t elements) {
        if (!writer_) return std::make_unique<MemoryChunks>(std::move(memory_));
        writer_->set_counts(nodes, elements);
        writer_->commit();
        writer_.reset();
        return std::make_unique<StoreChunks>(dir_, memory_.size());
    }

private:
    void put_part(uint32_t group) {
        sort_part(pending_);
        if (writer_) write_part(*writer_, group, parts_++, pending_);
        else memory_[group].insert(memory_[group].end(), pending_.begin(), pending_.end());
        pending_.clear();
    }

    std::string dir_;
    std::unique_ptr<LinkStoreWriter> writer_;
    std::vector<std::vector<LinkRecord>> memory_;
    std::vector<LinkRecord> pending_;  // the current group's links not yet in a part
    uint32_t parts_ = 0;               // parts of the current group written
};

struct Paths {
    std::string root;
    bool on_disk() const { return !root.empty(); }
    std::string round(int r) const { return on_disk() ? root + "/round-" + std::to_string(r) : std::string(); }
    std::string refined(int r) const { return root + "/refined-" + std::to_string(r); }
    std::string solved(int r) const { return root + "/solved-" + std::to_string(r); }
    std::string checkpoint() const { return root + "/checkpoint"; }
    std::string final_state() const { return root + "/final"; }
};

uint64_t mix(uint64_t a, uint64_t b) { return hash_pair(a, b, 0x5EEDull); }

void save_solution(const std::string& path, uint64_t fingerprint, const HierarchicalSolution& sol) {
    StateFile f;
    f.fingerprint = fingerprint;
    f.put("radiosity", flatten_rgb(sol.radiosity));
    f.put("irradiance", flatten_rgb(sol.irradiance));
    f.put("outgoing", sol.outgoing);
    f.put("residual", std::vector<double>{sol.residual, sol.converged ? 1.0 : 0.0, double(sol.iterations)});
    f.write(path);
}

HierarchicalSolution load_solution(const StateFile& f, size_t n, const std::string& path) {
    HierarchicalSolution sol;
    sol.radiosity = unflatten_rgb(f.f64("radiosity"), n, path);
    sol.irradiance = unflatten_rgb(f.f64("irradiance"), n, path);
    sol.outgoing = f.f64("outgoing");
    const std::vector<double>& r = f.f64("residual");
    if (sol.outgoing.size() != n || r.size() != 3) throw std::runtime_error(path + ": inconsistent solution arrays");
    sol.residual = r[0];
    sol.converged = r[1] != 0;
    sol.iterations = static_cast<uint64_t>(r[2]);
    return sol;
}

// A state file if it exists and carries the fingerprint, else nothing.
bool load_state(const std::string& path, uint64_t fingerprint, StateFile& out) {
    if (!fs::exists(path)) return false;
    StateFile f = StateFile::read(path);
    if (f.fingerprint != fingerprint) return false;
    out = std::move(f);
    return true;
}

// Removes what a store directory holds of earlier runs (only the names this stage writes),
// the final marker first, so that an interrupted new run never passes for the old one.
void clear_store(const std::string& root) {
    fs::remove(root + "/final");
    for (const auto& entry : fs::directory_iterator(root)) {
        const std::string name = entry.path().filename().string();
        if (name.rfind("round-", 0) == 0 || name.rfind("refined-", 0) == 0 || name.rfind("solved-", 0) == 0 ||
            name == "checkpoint" || (name.size() > 4 && name.compare(name.size() - 4, 4, ".tmp") == 0))
            fs::remove_all(entry.path());
    }
}

bool store_committed(const std::string& dir) {
    try {
        LinkStoreReader r(dir);
        return true;
    } catch (const std::runtime_error&) {
        return false;
    }
}

}  // namespace

std::vector<Link> load_links(const std::string& dir, size_t groups) {
    StoreChunks chunks(dir, groups);
    std::vector<Link> out;
    out.reserve(chunks.total_links());
    std::vector<LinkRecord> buf;
    for (size_t g = 0; g < groups; ++g) {
        chunks.read(g, buf);
        for (const LinkRecord& r : buf) out.push_back(to_link(r));
    }
    sort_links(out);
    return out;
}

OutOfCoreReport run_out_of_core(Hierarchy& h, const Visibility& vis, const OutOfCoreOptions& opt) {
    if (!h.subdivided.empty()) throw std::invalid_argument("out-of-core run: the hierarchy must be fresh");
    OutOfCoreReport rep;
    const SourceGroups groups = SourceGroups::cut(h, opt.group_faces);
    const size_t ng = groups.count();
    const Paths paths{opt.store};
    const uint64_t links_fp = mix(mix(opt.geometry_fingerprint, opt.settings_fingerprint), ng);
    const uint64_t run_fp = mix(links_fp, opt.materials_fingerprint);
    if (paths.on_disk()) {
        fs::create_directories(paths.root);
        if (!opt.reuse_links && !opt.resume) clear_store(paths.root);
    }
    Refiner refiner(h, vis, opt.refine);

    std::unique_ptr<LinkChunks> chunks;
    std::vector<uint8_t> is_source;
    std::vector<double> outgoing;
    std::vector<RGB> b;          // radiosity of the last solve
    int round = 0;               // the round whose links `chunks` holds
    bool solved = false;         // whether `b` is round `round`'s solution

    auto adopt_refined = [&](const StateFile& f, int r) {
        h.replay(f.u32("log"));
        const std::vector<uint32_t>& src = f.u32("is_source");
        if (src.size() != h.nodes.size() || f.f64("outgoing").size() != h.nodes.size())
            throw std::runtime_error(paths.refined(r) + ": per-node arrays do not match the hierarchy");
        is_source.assign(src.begin(), src.end());
        outgoing = f.f64("outgoing");
        chunks = std::make_unique<StoreChunks>(paths.round(r), ng);
        round = r;
    };

    // What an earlier bake left: final links to reuse, or the last finished step to resume from.
    if (paths.on_disk() && (opt.reuse_links || opt.resume)) {
        StateFile fin;
        const bool have_final = load_state(paths.final_state(), links_fp, fin);
        if (opt.reuse_links && !have_final)
            throw std::runtime_error(paths.root + ": no final links of this geometry and these refinement settings to "
                                     "reuse (bake once without --reuse-links)");
        if (have_final) {
            const int r = static_cast<int>(fin.u64("round").at(0));
            StateFile ref;
            if (!load_state(paths.refined(r), links_fp, ref))
                throw std::runtime_error(paths.refined(r) + ": missing or of another scene, though " + paths.final_state() +
                                         " names round " + std::to_string(r));
            adopt_refined(ref, r);
            rep.reused = true;
            rep.settled = fin.u64("round").at(1) != 0;
            // Reuse always solves again from the links; a resumed bake that had finished
            // takes its solution as it was.
            StateFile sol;
            if (!opt.reuse_links && load_state(paths.solved(r), run_fp, sol)) {
                rep.solution = load_solution(sol, h.nodes.size(), paths.solved(r));
                b = rep.solution.radiosity;
                solved = true;
            }
        } else {
            for (int r = opt.max_rounds; r >= 1 && round == 0; --r) {
                StateFile ref;
                if (!load_state(paths.refined(r), run_fp, ref) || !store_committed(paths.round(r))) continue;
                adopt_refined(ref, r);
                StateFile sol;
                if (load_state(paths.solved(r), run_fp, sol)) {
                    rep.solution = load_solution(sol, h.nodes.size(), paths.solved(r));
                    b = rep.solution.radiosity;
                    solved = true;
                }
            }
            rep.resumed_from_round = round;
        }
    }

    auto now = [] { return std::chrono::steady_clock::now(); };
    LinkStoreInfo info{links_fp, opt.settings_fingerprint, UINT32_MAX, 0};
    uint64_t shots = 0;
    for (;;) {
        if (!solved && round > 0) {
            // Solve round `round`'s links, from the previous solution where there is one.
            StreamingOptions so = opt.solve;
            if (paths.on_disk()) {
                so.checkpoint_path = paths.checkpoint();
                so.checkpoint_fingerprint = mix(run_fp, round);
            }
            const uint64_t links_now = chunks->total_links();
            so.on_round = [&](uint64_t it, double res) {
                if (opt.progress) opt.progress(round, links_now, shots + it, res);
                return !opt.solve.on_round || opt.solve.on_round(it, res);
            };
            std::vector<RGB> start = b;
            if (start.empty()) start = node_emission(h);
            for (size_t i = start.size(); i < h.nodes.size(); ++i) start.push_back(start[h.nodes[i].parent]);
            auto t0 = now();
            rep.last_solve = StreamingStats{};
            rep.solution = solve_streaming(h, groups, *chunks, is_source, outgoing, start, so, rep.last_solve);
            rep.solve_seconds.push_back(seconds_since(t0));
            shots += rep.last_solve.rounds;
            b = rep.solution.radiosity;
            solved = true;
            if (paths.on_disk()) {
                save_solution(paths.solved(round), run_fp, rep.solution);
                fs::remove(paths.checkpoint());
                if (round > 1) {
                    fs::remove_all(paths.round(round - 1));
                    fs::remove(paths.refined(round - 1));
                    fs::remove(paths.solved(round - 1));
                }
            }
        }
        if (rep.reused || (round > 0 && rep.settled) || round >= opt.max_rounds) break;

        // Refine into round + 1: from the root for round 1, else round `round`'s links.
        const int next = round + 1;
        auto t0 = now();
        const uint64_t splits_before = rep.refine_stats.split;
        Round out(paths.round(next), ng, info);
        std::vector<uint8_t> src;
        std::vector<double> own;
        std::vector<Link> frontier;
        std::vector<LinkRecord> records;
        refiner.set_radiosity(next == 1 ? node_emission(h) : b);
        // Kept links leave for the store a part at a time, as refinement makes them; what
        // refinement holds is bounded by kChunkLinks per level of depth.
        std::vector<LinkRecord> kept_records;
        auto keep = [&](uint32_t g, std::vector<Link>& kept) {
            src.resize(h.nodes.size(), 0);
            own.resize(h.nodes.size(), 0.0);
            kept_records.clear();
            for (const Link& l : kept) {
                src[l.source] = 1;
                own[l.source] += double(l.coupling) / h.nodes[l.source].area;
                kept_records.push_back(to_record(l));
            }
            out.add(g, kept_records);
        };
        for (uint32_t g = 0; g < ng; ++g) {
            // Round 1 starts from the link of the root to the group; later rounds re-judge the
            // previous round's links of the group, part by part.
            const size_t pieces = next == 1 ? 1 : chunks->parts(g);
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
                    chunks->read(g, p, records);
                    for (const LinkRecord& r : records) frontier.push_back(to_link(r));
                    evaluated.assign(frontier.size(), 1);
                }
                const uint64_t held =
                    refiner.run_group(std::move(frontier), std::move(evaluated), rep.refine_stats, kChunkLinks,
                                      [&](std::vector<Link>& kept) { keep(g, kept); });
                frontier = {};
                rep.peak_refine_links = std::max<uint64_t>(rep.peak_refine_links, held);
            }
            out.end_group(g);
        }
        src.resize(h.nodes.size(), 0);
        own.resize(h.nodes.size(), 0.0);
        const uint64_t splits = rep.refine_stats.split - splits_before;
        rep.refine_seconds.push_back(seconds_since(t0));
        if (next > 1 && splits == 0) {
            // Nothing split: round `round`'s links and solution are final.
            if (paths.on_disk()) fs::remove_all(paths.round(next));
            rep.settled = true;
            break;
        }
        uint32_t elements = 0;
        for (const Node& node : h.nodes) elements += !node.cluster;
        chunks = out.finish(static_cast<uint32_t>(h.nodes.size()), elements);
        is_source = std::move(src);
        outgoing = std::move(own);
        round = next;
        solved = false;
        rep.splits_per_round.push_back(splits);
        rep.links_per_round.push_back(chunks->total_links());
        if (paths.on_disk()) {
            StateFile f;
            f.fingerprint = run_fp;
            f.put("log", h.subdivided);
            f.put("is_source", std::vector<uint32_t>(is_source.begin(), is_source.end()));
            f.put("outgoing", outgoing);
            f.write(paths.refined(round));
        }
    }
    if (!solved) throw std::logic_error("out-of-core run ended without a solution");
    rep.rounds = round;
    rep.links = chunks->total_links();
    rep.is_source = is_source;
    if (paths.on_disk()) {
        auto* store = dynamic_cast<StoreChunks*>(chunks.get());
        rep.store_bytes = store ? store->reader().total_compressed_bytes() : 0;
        rep.transport_bytes = store ? store->reader().total_transport_bytes() : 0;
        rep.final_round_dir = paths.round(round);
        if (!rep.reused) {
            // Refinement depended on the materials; its result stays usable for others.
            StateFile ref = StateFile::read(paths.refined(round));
            ref.fingerprint = links_fp;
            ref.write(paths.refined(round));
            StateFile fin;
            fin.fingerprint = links_fp;
            fin.put("round", std::vector<uint64_t>{uint64_t(round), uint64_t(rep.settled)});
            fin.write(paths.final_state());
        }
    } else {
        auto* mem = dynamic_cast<MemoryChunks*>(chunks.get());
        std::vector<LinkRecord> buf;
        for (size_t g = 0; g < ng; ++g) {
            mem->read(g, buf);
            for (const LinkRecord& r : buf) rep.memory_links.push_back(to_link(r));
        }
        sort_links(rep.memory_links);
    }
    return rep;
}

}  // namespace hirad
