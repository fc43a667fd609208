#include "pipeline/outofcore/run_store.h"

#include <algorithm>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <stdexcept>

#include "formats/linkstore.h"
#include "formats/statefile.h"
#include "pipeline/core/atomic_file.h"
#include "pipeline/outofcore/streaming_solver.h"

namespace fs = std::filesystem;

namespace hirad {

namespace {

uint64_t mix(uint64_t a, uint64_t b) { return hash_pair(a, b, 0x5EEDull); }

uint64_t bits(double x) {
    uint64_t u;
    std::memcpy(&u, &x, 8);
    return u;
}

// What a state file is: its kind and round, written into it, so a file renamed or copied from
// elsewhere in the store is refused rather than taken for another step.
enum class StateKind : uint64_t { Refined = 1, Solved = 2, Final = 3, Spill = 4 };
const char* const kBelongsTo = "belongs_to";

const char* kind_name(uint64_t k) {
    switch (k) {
        case uint64_t(StateKind::Refined): return "refined";
        case uint64_t(StateKind::Solved): return "solved";
        case uint64_t(StateKind::Final): return "final";
        case uint64_t(StateKind::Spill): return "spill";
        default: return "unknown";
    }
}

void label(StateFile& f, StateKind kind, int round) {
    f.put(kBelongsTo, std::vector<uint64_t>{uint64_t(kind), uint64_t(round)});
}

void save_solution(const std::string& path, uint64_t fingerprint, int round, const HierarchicalSolution& sol) {
    StateFile f;
    f.fingerprint = fingerprint;
    label(f, StateKind::Solved, round);
    static_assert(sizeof(RGB) == 3 * sizeof(double));
    f.put_view("radiosity", sol.radiosity.data(), 3 * sol.radiosity.size());  // borrowed, not copied
    f.put_view("irradiance", sol.irradiance.data(), 3 * sol.irradiance.size());
    f.put_view("outgoing", sol.outgoing.data(), sol.outgoing.size());
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

// Whether a state file of this run is there: false when there is none; an error naming the
// file when there is one that is not this step's (another kind or round: renamed or copied) or,
// unless `other_run_ok`, not this run's (another scene, settings or materials). A resume that
// quietly skipped a foreign file would start over in a store that still holds it.
bool load_state(const std::string& path, uint64_t fingerprint, StateKind kind, int round, StateFile& out,
                bool other_run_ok = false) {
    if (!fs::exists(path)) return false;
    StateFile f = StateFile::read(path);
    if (!f.has(kBelongsTo) || f.u64(kBelongsTo).size() != 2)
        throw std::runtime_error(path + ": a state file that does not say what it belongs to (written by another "
                                 "version of hirad?); bake without --resume to start over");
    const std::vector<uint64_t>& what = f.u64(kBelongsTo);
    if (what[0] != uint64_t(kind) || what[1] != uint64_t(round))
        throw std::runtime_error(path + ": holds the " + kind_name(what[0]) + " state of round " +
                                 std::to_string(what[1]) + ", not the " + kind_name(uint64_t(kind)) + " state of round " +
                                 std::to_string(round) + " (renamed or replaced); bake without --resume to start over");
    if (f.fingerprint != fingerprint) {
        if (other_run_ok) return false;
        throw std::runtime_error(path + ": belongs to another run (another scene, settings or materials); bake "
                                 "without --resume to start over");
    }
    out = std::move(f);
    return true;
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

StoreFingerprints StoreFingerprints::of(const Scene& scene, double epsilon, double min_area, int samples,
                                        uint64_t seed, int max_rounds, uint32_t group_faces, uint64_t luminaires,
                                        double relative, double spread) {
    // Geometry (what the links depend on) and the materials (what the oracle's radiosity,
    // hence the refinement, also depends on).
    StoreFingerprints fp;
    uint64_t geo = 0x6E0ull, mat = 0x3A7ull;
    for (const Face& f : scene.faces) {
        geo = hash_pair(geo, (uint64_t(f.nv) << 32) | f.mesh, 1);
        for (int k = 0; k < f.nv; ++k)
            for (int a = 0; a < 3; ++a) geo = hash_pair(geo, bits(f.p[k][a]), 2);
        for (int a = 0; a < 3; ++a) mat = hash_pair(hash_pair(mat, bits(f.reflectance[a]), 3), bits(f.emission[a]), 4);
        if (f.transmittance > 0) mat = hash_pair(mat, bits(f.transmittance), 8);  // glazing (opaque: as before)
    }
    uint64_t settings = 0x5E7ull;
    for (uint64_t v : {bits(epsilon), bits(min_area), uint64_t(samples), seed, uint64_t(max_rounds), uint64_t(group_faces)})
        settings = hash_pair(settings, v, 5);
    if (relative > 0) settings = hash_pair(settings, bits(relative), 9);  // off: as before
    if (spread > 0) settings = hash_pair(settings, bits(spread), 10);
    if (luminaires) {
        geo = hash_pair(geo, luminaires, 6);
        mat = hash_pair(mat, luminaires, 7);
    }
    fp.geometry = geo;
    fp.settings = settings;
    fp.materials = mat;
    return fp;
}

RunStore::RunStore(std::string root, const StoreFingerprints& fingerprints, size_t groups)
    : root_(std::move(root)), fp_(fingerprints) {
    links_fp_ = mix(mix(fp_.geometry, fp_.settings), groups);
    run_fp_ = mix(links_fp_, fp_.materials);
}

std::string RunStore::round_dir(int r) const { return on_disk() ? root_ + "/round-" + std::to_string(r) : std::string(); }
std::string RunStore::refined_path(int r) const { return root_ + "/refined-" + std::to_string(r); }
std::string RunStore::solved_path(int r) const { return root_ + "/solved-" + std::to_string(r); }
std::string RunStore::final_path() const { return root_ + "/final"; }
std::string RunStore::checkpoint_path() const { return on_disk() ? root_ + "/checkpoint" : std::string(); }
uint64_t RunStore::checkpoint_fingerprint(int round) const { return on_disk() ? mix(run_fp_, round) : 0; }

void RunStore::open(bool keep_earlier) {
    if (!on_disk()) return;
    fs::create_directories(root_);
    if (keep_earlier) return;
    // Only the names this component writes, the final marker first, so that an interrupted
    // new run never passes for the old one; and their temporaries: "<name>.<pid>-<n>.tmp" of a
    // writer killed mid-write (pipeline/core/atomic_file.h), "<name>.tmp" of older writers.
    // Other files in the directory are left alone.
    fs::remove(final_path());
    auto ours = [](const std::string& name) {
        return name.rfind("round-", 0) == 0 || name.rfind("refined-", 0) == 0 || name.rfind("solved-", 0) == 0 ||
               name.rfind("spill-", 0) == 0 || name == "final" || name == "checkpoint";
    };
    std::vector<fs::path> doomed;
    for (const auto& entry : fs::directory_iterator(root_)) {
        const std::string name = entry.path().filename().string();
        std::string base = name;
        if (!is_atomic_temporary(name, &base) && name.size() > 4 && name.compare(name.size() - 4, 4, ".tmp") == 0)
            base = name.substr(0, name.size() - 4);
        if (ours(base)) doomed.push_back(entry.path());
    }
    for (const fs::path& p : doomed) fs::remove_all(p);  // not while iterating the directory
}

ResumePoint RunStore::resume_point(Hierarchy& h, bool reuse_links, bool resume, int max_rounds) const {
    ResumePoint at;
    if (!on_disk() || !(reuse_links || resume)) return at;
    auto adopt_refined = [&](const StateFile& f, int r) {
        h.replay(f.u32("log"));
        const std::vector<uint32_t>& src = f.u32("is_source");
        if (src.size() != h.nodes.size() || f.f64("outgoing").size() != h.nodes.size())
            throw std::runtime_error(refined_path(r) + ": per-node arrays do not match the hierarchy");
        at.is_source.assign(src.begin(), src.end());
        at.outgoing = f.f64("outgoing");
        at.round = r;
    };
    auto adopt_solution = [&](const StateFile& f, int r) {
        at.solution = load_solution(f, h.nodes.size(), solved_path(r));
        at.solved = true;
    };
    StateFile fin;
    // A final state of other geometry or settings is refused on resume; for --reuse-links it
    // means there is nothing to reuse (said just below).
    const bool have_final = load_state(final_path(), links_fp_, StateKind::Final, 0, fin, reuse_links);
    if (reuse_links && !have_final)
        throw std::runtime_error(root_ + ": no final links of this geometry and these refinement settings to "
                                 "reuse (bake once without --reuse-links)");
    if (have_final) {
        const int r = static_cast<int>(fin.u64("round").at(0));
        StateFile ref;
        if (!load_state(refined_path(r), links_fp_, StateKind::Refined, r, ref))
            throw std::runtime_error(refined_path(r) + ": missing or of another scene, though " + final_path() +
                                     " names round " + std::to_string(r));
        adopt_refined(ref, r);
        at.reused = true;
        at.settled = fin.u64("round").at(1) != 0;
        // Reuse always solves again from the links; a resumed bake that had finished takes
        // its solution as it was.
        StateFile sol;
        // (the solution of other materials on the same links is not this run's: solved again)
        if (!reuse_links && load_state(solved_path(r), run_fp_, StateKind::Solved, r, sol, true)) adopt_solution(sol, r);
        return at;
    }
    for (int r = max_rounds; r >= 1 && at.round == 0; --r) {
        StateFile ref;
        // (finish() re-stamps the last refinement with the links' fingerprint before it writes
        // `final`: a kill between the two leaves it so, and it is still this run's)
        const bool ours = load_state(refined_path(r), run_fp_, StateKind::Refined, r, ref, true) ||
                          load_state(refined_path(r), links_fp_, StateKind::Refined, r, ref);
        if (!ours || !store_committed(round_dir(r))) continue;
        adopt_refined(ref, r);
        // Without round r's solution (killed during its solve, or the file removed) the round is
        // solved again, from the emission as every round is: the same bits as a run never killed.
        StateFile sol;
        if (load_state(solved_path(r), run_fp_, StateKind::Solved, r, sol)) adopt_solution(sol, r);
    }
    return at;
}

void RunStore::refined(int round, const Hierarchy& h, const std::vector<uint8_t>& is_source,
                       const std::vector<double>& outgoing) const {
    if (!on_disk()) return;
    StateFile f;
    f.fingerprint = run_fp_;
    label(f, StateKind::Refined, round);
    f.put("log", h.subdivided);
    f.put("is_source", std::vector<uint32_t>(is_source.begin(), is_source.end()));
    f.put("outgoing", outgoing);
    f.write(refined_path(round));
}

void RunStore::discard_round(int round) const {
    if (on_disk()) fs::remove_all(round_dir(round));
}

void RunStore::solved(int round, const HierarchicalSolution& solution) const {
    if (!on_disk()) return;
    save_solution(solved_path(round), run_fp_, round, solution);
    fs::remove(checkpoint_path());
    if (round > 1) {
        fs::remove_all(round_dir(round - 1));
        fs::remove(refined_path(round - 1));
        fs::remove(solved_path(round - 1));
    }
}

void RunStore::finish(int round, bool settled) const {
    if (!on_disk()) return;
    // Refinement depended on the materials; its result stays usable for others.
    StateFile ref = StateFile::read(refined_path(round));
    ref.fingerprint = links_fp_;
    ref.write(refined_path(round));
    StateFile fin;
    fin.fingerprint = links_fp_;
    label(fin, StateKind::Final, 0);
    fin.put("round", std::vector<uint64_t>{uint64_t(round), uint64_t(settled)});
    fin.write(final_path());
}

ResumePoint RunStore::round_start(Hierarchy& h, int round) const {
    ResumePoint at;
    if (!on_disk()) throw std::invalid_argument("distributed refinement needs a link store on disk");
    if (round < 1) throw std::invalid_argument("refinement rounds start at 1");
    if (round == 1) return at;
    const int r = round - 1;
    StateFile ref, sol;
    if (!load_state(refined_path(r), run_fp_, StateKind::Refined, r, ref))
        throw std::runtime_error(refined_path(r) + ": missing: round " + std::to_string(round) +
                                 " cannot be refined before round " + std::to_string(r) + " is refined and solved");
    if (!load_state(solved_path(r), run_fp_, StateKind::Solved, r, sol))
        throw std::runtime_error(solved_path(r) + ": missing: round " + std::to_string(round) +
                                 " cannot be refined before round " + std::to_string(r) + " is solved");
    h.replay(ref.u32("log"));
    at.round = r;
    at.solution = load_solution(sol, h.nodes.size(), solved_path(r));
    at.solved = true;
    return at;
}

std::string RunStore::spill_dir(int round) const { return root_ + "/spill-" + std::to_string(round); }

std::string RunStore::spill_range_dir(int round, uint32_t begin, uint32_t end) const {
    char name[32];
    std::snprintf(name, sizeof name, "/%08x-%08x", begin, end);
    return spill_dir(round) + name;
}

void RunStore::write_spill_log(const std::string& dir, int round, const SpillLog& log) const {
    StateFile f;
    f.fingerprint = mix(run_fp_, uint64_t(round));
    label(f, StateKind::Spill, round);
    f.put("range", std::vector<uint32_t>{log.begin, log.end, log.nodes});
    f.put("log", log.log);
    f.put("group_log_end", log.group_log_end);
    f.put("counts", std::vector<uint64_t>{log.stats.evaluated, log.stats.split, log.stats.rays, log.held});
    f.put("group_seconds", log.group_seconds);
    f.put("group_links", log.group_links);
    f.write(dir + "/log");
}

SpillLog RunStore::read_spill_log(const std::string& dir, int round) const {
    const std::string path = dir + "/log";
    StateFile f;
    if (!load_state(path, mix(run_fp_, uint64_t(round)), StateKind::Spill, round, f, true))
        throw std::runtime_error(path + ": missing, or made from another scene or config (do the workers see the same "
                                 "config, scene and link store as this machine?)");
    SpillLog log;
    const std::vector<uint32_t>& range = f.u32("range");
    const std::vector<uint64_t>& counts = f.u64("counts");
    if (range.size() != 3 || counts.size() != 4) throw std::runtime_error(path + ": malformed spill log");
    log.begin = range[0];
    log.end = range[1];
    log.nodes = range[2];
    log.log = f.u32("log");
    log.group_log_end = f.u32("group_log_end");
    log.stats.evaluated = counts[0];
    log.stats.split = counts[1];
    log.stats.rays = counts[2];
    log.held = counts[3];
    log.group_seconds = f.f64("group_seconds");
    log.group_links = f.u64("group_links");
    const size_t n = log.end > log.begin ? log.end - log.begin : 0;
    bool ok = n > 0 && log.group_log_end.size() == n && log.group_seconds.size() == n && log.group_links.size() == n;
    for (size_t k = 0; ok && k < n; ++k)
        ok = log.group_log_end[k] <= log.log.size() && (k == 0 || log.group_log_end[k] >= log.group_log_end[k - 1]);
    if (!ok || (n > 0 && log.group_log_end.back() != log.log.size()))
        throw std::runtime_error(path + ": inconsistent spill log (group ranges and subdivision log do not agree)");
    return log;
}

std::vector<std::pair<uint32_t, uint32_t>> RunStore::spill_ranges(int round, uint32_t groups) const {
    std::vector<std::pair<uint32_t, uint32_t>> ranges;
    const std::string dir = spill_dir(round);
    if (fs::is_directory(dir))
        for (const auto& entry : fs::directory_iterator(dir)) {
            const std::string name = entry.path().filename().string();
            unsigned b = 0, e = 0;
            char tail = 0;
            if (name.size() != 17 || std::sscanf(name.c_str(), "%8x-%8x%c", &b, &e, &tail) != 2 ||
                name != spill_range_dir(round, b, e).substr(dir.size() + 1))
                continue;
            ranges.emplace_back(b, e);
        }
    std::sort(ranges.begin(), ranges.end());
    uint32_t next = 0;
    for (const auto& [b, e] : ranges) {
        if (b != next || e <= b)
            throw std::runtime_error(dir + ": the workers' ranges of source groups do not tile [0, " +
                                     std::to_string(groups) + "): " +
                                     (b > next ? "groups [" + std::to_string(next) + ", " + std::to_string(b) + ") missing"
                                               : "range [" + std::to_string(b) + ", " + std::to_string(e) + ") overlaps"));
        next = e;
    }
    if (next != groups)
        throw std::runtime_error(dir + ": groups [" + std::to_string(next) + ", " + std::to_string(groups) +
                                 ") were not refined by any worker");
    return ranges;
}

}  // namespace hirad
