#include "pipeline/outofcore/streaming_solver.h"

#include <tbb/parallel_pipeline.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <mutex>
#include <stdexcept>

#include "formats/statefile.h"
#include "pipeline/core/checks.h"

namespace hirad {

SourceGroups SourceGroups::cut(const Hierarchy& h, uint32_t max_faces) {
    SourceGroups g;
    g.face_rank.assign(h.face_order.size(), 0);
    for (uint32_t k = 0; k < h.face_order.size(); ++k) g.face_rank[h.face_order[k]] = k;
    if (h.nodes.empty()) return g;
    max_faces = std::max<uint32_t>(1, max_faces);
    // Depth first, children in order: the groups' face ranges follow each other.
    std::vector<uint32_t> stack{h.root};
    while (!stack.empty()) {
        const uint32_t i = stack.back();
        stack.pop_back();
        const Node& node = h.nodes[i];
        if (!node.cluster || node.face_end - node.face_begin <= max_faces) {
            g.roots.push_back(i);
            g.first_face.push_back(node.face_begin);
            continue;
        }
        for (int c = node.child_count; c-- > 0;) stack.push_back(node.first_child + c);
    }
    g.first_face.push_back(static_cast<uint32_t>(h.face_order.size()));
    return g;
}

uint32_t SourceGroups::of(const Hierarchy& h, uint32_t node) const {
    const Node& n = h.nodes[node];
    // (an element's face_begin is its face's place in face_order, as face_rank says)
    const uint32_t begin = n.face_begin;
    const uint32_t end = n.face_end;
    auto it = std::upper_bound(first_face.begin(), first_face.end(), begin);
    if (it == first_face.begin() || it == first_face.end()) return kNoGroup;
    const uint32_t g = static_cast<uint32_t>(it - first_face.begin()) - 1;
    return end <= first_face[g + 1] ? g : kNoGroup;
}

MemoryChunks::MemoryChunks(std::vector<std::vector<Link>> by_group)
    : chunks_(std::move(by_group)), transport_bytes_(chunks_.size()) {
    TransportLinks t;
    for (size_t g = 0; g < chunks_.size(); ++g)
        for (size_t p = 0; p < parts(g); ++p) {
            read_transport(g, p, t);
            transport_bytes_[g].push_back(t.bytes());
        }
}

uint64_t LinkChunks::links(size_t g) const {
    uint64_t n = 0;
    for (size_t p = 0; p < parts(g); ++p) n += links(g, p);
    return n;
}

void LinkChunks::read(size_t g, std::vector<Link>& out) const {
    out.clear();
    out.reserve(links(g));
    std::vector<Link> part;
    for (size_t p = 0; p < parts(g); ++p) {
        read(g, p, part);
        out.insert(out.end(), part.begin(), part.end());
    }
}

uint64_t LinkChunks::total_links() const {
    uint64_t n = 0;
    for (size_t g = 0; g < groups(); ++g) n += links(g);
    return n;
}

StoreChunks::StoreChunks(const std::string& dir, size_t groups) : reader_(dir), parts_(groups) {
    for (size_t k = 0; k < reader_.chunk_count(); ++k) {
        const ChunkEntry& e = reader_.chunk(k);
        const uint32_t g = e.source_begin / kPartsPerGroup, p = e.source_begin % kPartsPerGroup;
        if (e.source_end != e.source_begin + 1 || g >= groups || p != parts_[g].size())
            throw std::runtime_error(reader_.chunk_path(k) + ": chunk " + std::to_string(k) + ": key range [" +
                                     std::to_string(e.source_begin) + ", " + std::to_string(e.source_end) +
                                     ") is not the next part of one of the " + std::to_string(groups) +
                                     " source groups");
        parts_[g].push_back(k);
    }
}

void sort_part(std::vector<Link>& links) {
    std::sort(links.begin(), links.end(), [](const Link& a, const Link& b) {
        return a.source != b.source ? a.source < b.source : a.receiver < b.receiver;
    });
}

void write_part(LinkStoreWriter& writer, uint32_t group, uint32_t part, const std::vector<Link>& links) {
    if (uint64_t(group + 1) * kPartsPerGroup > UINT32_MAX)
        throw std::runtime_error("source group " + std::to_string(group) + ": too many source groups for the store's"
                                 " chunk keys; use a larger links.group_faces");
    if (part >= kPartsPerGroup)
        throw std::runtime_error("source group " + std::to_string(group) + " has more than " +
                                 std::to_string(uint64_t(kPartsPerGroup) * kChunkLinks) +
                                 " links, more than a group can store; use smaller links.group_faces");
    if (links.size() > kChunkLinks) throw std::invalid_argument("write_part: more than kChunkLinks links");
    const uint32_t key = group * kPartsPerGroup + part;
    writer.write_chunk(key, key + 1, links.data(), links.size());
}

std::vector<RGB> unflatten_rgb(const std::vector<double>& a, size_t n, const std::string& what) {
    if (a.size() != 3 * n)
        throw std::runtime_error(what + ": values of " + std::to_string(a.size() / 3) + " nodes, the hierarchy has " +
                                 std::to_string(n));
    std::vector<RGB> out(n);
    for (size_t i = 0; i < n; ++i) out[i] = {a[3 * i], a[3 * i + 1], a[3 * i + 2]};
    return out;
}

namespace {

using Chunk = std::shared_ptr<TransportLinks>;

double seconds_since(std::chrono::steady_clock::time_point t) {
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - t).count();
}

}  // namespace

HierarchicalSolution solve_streaming(const Hierarchy& h, const SourceGroups& groups, const LinkChunks& chunks,
                                     const std::vector<uint8_t>& is_source, const std::vector<double>& outgoing,
                                     std::vector<RGB> start, const StreamingOptions& opt,
                                     StreamingStats& stats) {
    const size_t n = h.nodes.size();
    const size_t ng = chunks.groups();
    if (is_source.size() != n || outgoing.size() != n)
        throw std::invalid_argument("streaming solve: per-node source flags and outgoing sums must cover the hierarchy (" + std::to_string(is_source.size()) + ", " + std::to_string(outgoing.size()) + " for " + std::to_string(n) + " nodes)");
    if (ng != groups.count()) throw std::invalid_argument("streaming solve: the links' groups are not the hierarchy's");

    std::vector<RGB> b = start.size() == n ? std::move(start) : node_emission(h);
    // received: per node, the power G (B_S - shot_S) its links brought in (divided by the
    // node's area only before push-pull, so that shooting a link is a multiply-add).
    std::vector<RGB> shot(n), received(n);
    std::vector<std::vector<uint32_t>> sources(ng);
    // Per node, compact: what validating a link and gathering read (the nodes themselves are
    // large).
    std::vector<uint32_t> source_group(n, kNoGroup);
    for (uint32_t i = 0; i < n; ++i) {
        if (!is_source[i]) continue;
        const uint32_t g = groups.of(h, i);
        if (g == kNoGroup) throw std::invalid_argument("streaming solve: a source above the groups' cut");
        sources[g].push_back(i);
        source_group[i] = g;
    }
    uint64_t largest = 0;
    std::vector<uint64_t> first_part(ng + 1, 0);   // parts numbered across groups, for the cache
    for (size_t g = 0; g < ng; ++g) {
        first_part[g + 1] = first_part[g] + chunks.parts(g);
        for (size_t p = 0; p < chunks.parts(g); ++p) {
            largest = std::max(largest, chunks.transport_bytes(g, p));
            stats.decoded_bytes += chunks.transport_bytes(g, p);
        }
    }
    // Per node: B, shot, received; its source group; the leaves' two terms (gather_terms).
    stats.state_bytes = n * (3 * sizeof(RGB) + sizeof(uint32_t) + 2 * sizeof(double));
    stats.largest_chunk_bytes = largest;
    // Chunks in flight: one being shot, the others being read and decoded, two per thread
    // (decoding is what limits streaming).
    const size_t window = std::max(2, 2 * tbb::this_task_arena::max_concurrency());
    const uint64_t in_flight = window * largest;
    size_t shot_parts = 0;
    stats.chunks_in_flight = window;
    const std::vector<uint32_t> leaves = h.leaves();
    const double enorm = leaf_emission_norm(h, leaves);
    // The gain limit (hierarchical_solver.h) from the couplings each node receives: one pass
    // over the links' transport in group and part order (the same sums whatever the threads).
    // Receiving clusters (Hierarchy::reception) gather a vector irradiance instead, G (B_S -
    // shot_S) reception(R, S) summed per cluster slot.
    LeafTerms terms;
    bool clusters_receive = false;
    {
        std::vector<double> in(n, 0.0);
        std::vector<Reception> in_clusters;
        TransportLinks t;
        for (size_t g = 0; g < ng; ++g)
            for (size_t p = 0; p < chunks.parts(g); ++p) {
                chunks.read_transport(g, p, t);
                const std::vector<uint32_t> receivers = t.receivers();
                for (size_t r = 0, k = 0; r < t.runs(); ++r)
                    for (; k < t.run_end[r]; ++k) {
                        if (receivers[k] >= n)
                            throw std::runtime_error("streaming solve: a link's receiver is not a node");
                        add_coupling(h, receivers[k], t.sources[r], double(t.coupling[k]), in, in_clusters);
                    }
            }
        clusters_receive = !in_clusters.empty();
        terms = gather_terms(h, std::move(in), std::move(in_clusters));
    }
    std::vector<VectorIrradiance> received_clusters(clusters_receive ? h.cluster_shapes.size() : 0);
    stats.state_bytes += received_clusters.size() * sizeof(VectorIrradiance);
    // The budget holds the whole state, the clusters' vectors too (known once the links are
    // read: whether any ends on a cluster), and the chunks in flight; what is left of it keeps
    // chunks decoded.
    stats.minimum_budget = stats.state_bytes + in_flight;
    uint64_t cache_capacity = UINT64_MAX;
    if (opt.memory_budget > 0) {
        if (opt.memory_budget < stats.minimum_budget)
            throw std::runtime_error("memory_budget of " + std::to_string(opt.memory_budget) +
                                     " bytes is below what the solver needs: " + std::to_string(stats.state_bytes) +
                                     " bytes of per-node state and " + std::to_string(in_flight) + " for " +
                                     std::to_string(window) + " chunks in flight");
        cache_capacity = opt.memory_budget - stats.minimum_budget;
    }

    // The irradiance gathered at each node is what it received over its area; push-pull
    // divides as it walks, and keeps no irradiance until the end.
    bool pushed = false;
    auto gather_and_push_pull = [&] {
        push_pull_power(h, received, b, terms, received_clusters);
        pushed = true;
    };

    HierarchicalSolution sol;
    uint64_t round = 0;
    const uint64_t fingerprint = opt.checkpoint_fingerprint ^ (n * 0x9E3779B97F4A7C15ull) ^ ng;
    if (!opt.checkpoint_path.empty() && std::filesystem::exists(opt.checkpoint_path)) {
        StateFile cp = StateFile::read(opt.checkpoint_path);
        if (cp.fingerprint == fingerprint) {
            received = unflatten_rgb(cp.f64("received"), n, opt.checkpoint_path);
            if (clusters_receive) {
                // Each cluster's three vectors and its uniform part, four RGB rows.
                const std::vector<RGB> v =
                    unflatten_rgb(cp.f64("received_clusters"), 4 * received_clusters.size(), opt.checkpoint_path);
                for (size_t k = 0; k < received_clusters.size(); ++k) {
                    VectorIrradiance& c = received_clusters[k];
                    c.c[0] = v[4 * k];
                    c.c[1] = v[4 * k + 1];
                    c.c[2] = v[4 * k + 2];
                    c.uniform = v[4 * k + 3];
                }
            }
            shot = unflatten_rgb(cp.f64("shot"), n, opt.checkpoint_path);
            const std::vector<uint64_t>& counters = cp.u64("counters");
            if (counters.size() != 3) throw std::runtime_error(opt.checkpoint_path + ": bad counters");
            round = counters[0];
            stats.groups_shot = counters[1];
            stats.links_shot = counters[2];
            sol.residual_history = cp.f64("history");
            gather_and_push_pull();
            stats.resumed = true;
        }
    }
    auto checkpoint = [&] {
        StateFile cp;
        cp.fingerprint = fingerprint;
        // Borrowed, not copied: RGB is three doubles, VectorIrradiance twelve (its three
        // vectors and its uniform part, the four RGB rows a reader unflattens).
        static_assert(sizeof(RGB) == 3 * sizeof(double) && sizeof(VectorIrradiance) == 12 * sizeof(double));
        cp.put_view("received", received.data(), 3 * received.size());
        if (clusters_receive) cp.put_view("received_clusters", received_clusters.data(), 12 * received_clusters.size());
        cp.put_view("shot", shot.data(), 3 * shot.size());
        cp.put("counters", std::vector<uint64_t>{round, stats.groups_shot, stats.links_shot});
        cp.put("history", sol.residual_history);
        cp.write(opt.checkpoint_path);
        ++stats.checkpoints;
    };

    // Chunks kept decoded: the first ones read, while they fit (a cyclic access pattern would
    // make any eviction policy miss every time).
    std::vector<Chunk> cache(first_part[ng]);
    uint64_t cached_bytes = 0;
    // Decoded chunks shot and not kept, for the readers to decode into again (their buffers
    // stay allocated: no allocation and no page faults per chunk). At most `window` of them.
    std::vector<Chunk> spare;
    std::mutex spare_mutex;
    struct Part { uint32_t group, part; };
    auto load = [&](Part q, bool& hit) -> Chunk {
        const uint64_t slot = first_part[q.group] + q.part;
        if (cache[slot]) { hit = true; return cache[slot]; }
        hit = false;
        Chunk links;
        {
            std::lock_guard<std::mutex> lock(spare_mutex);
            if (!spare.empty()) {
                links = std::move(spare.back());
                spare.pop_back();
            }
        }
        if (!links) links = std::make_shared<TransportLinks>();
        chunks.read_transport(q.group, q.part, *links);
        auto fail = [&](size_t k, uint32_t receiver, uint32_t source) {
            throw std::runtime_error("source group " + std::to_string(q.group) + ", part " + std::to_string(q.part) +
                                     ", link " + std::to_string(k) + " (receiver " + std::to_string(receiver) +
                                     ", source " + std::to_string(source) + "): not a link of this group's"
                                     " sources to an element of the hierarchy (a store of another hierarchy?)");
        };
        // Sources per run, and the receivers' range as a whole (the chunk has checked that
        // they increase within runs). That a receiver is an element is not checked per
        // link: a store of this hierarchy (the fingerprints say so) has no other, and another
        // receiver is a wrong answer for a store of another hierarchy, never an access out of
        // bounds.
        for (size_t r = 0, k = 0; r < links->runs(); ++r) {
            const uint32_t s = links->sources[r];
            if (s >= n || source_group[s] != q.group) fail(k, links->receivers()[k], s);
            k = links->run_end[r];
        }
        if (links->receiver_end > n) {
            const std::vector<uint32_t> rc = links->receivers();
            for (size_t r = 0, k = 0; r < links->runs(); ++r)
                for (; k < links->run_end[r]; ++k)
                    if (rc[k] >= n) fail(k, rc[k], links->sources[r]);
        }
        return links;
    };

    auto last_checkpoint = std::chrono::steady_clock::now();
    double last_write = 0;  // seconds the last checkpoint took to write
    for (;;) {
        // Unshot power per group and the residual, in a fixed order.
        std::vector<double> power(ng, 0.0);
        double r2 = 0;
        for (size_t g = 0; g < ng; ++g)
            for (uint32_t s : sources[g]) {
                const RGB d = b[s] - shot[s];
                const double a = h.nodes[s].area;
                power[g] += a * luminance_of_magnitude(d);
                r2 += a * dot(d, d);
            }
        const double residual = std::sqrt(r2) / enorm;
        require_finite_residual("the streaming solver (block Southwell)", residual, round, "round");
        sol.residual = residual;
        if (residual <= opt.tolerance) { sol.converged = true; break; }
        if (round >= opt.max_rounds) break;
        const double top = *std::max_element(power.begin(), power.end());
        std::vector<uint32_t> pick;
        for (uint32_t g = 0; g < ng; ++g)
            if (power[g] > 0 && power[g] >= 0.5 * top) pick.push_back(g);
        std::sort(pick.begin(), pick.end(), [&](uint32_t a, uint32_t c) {
            return power[a] != power[c] ? power[a] > power[c] : a < c;
        });

        // Shoot the picked groups in order, part by part, while the next part is read. A
        // group's sources shoot B - shot as it was when the group began; shot is updated
        // after its last part.
        std::vector<Part> queue;
        for (uint32_t g : pick)
            for (uint32_t p = 0; p < chunks.parts(g); ++p) queue.push_back({g, p});
        // A pipeline: parts handed out in order, read and decoded by up to `window` workers at
        // once, shot strictly in order by one at a time.
        size_t next_part = 0;
        struct Loaded { Part part; Chunk links; bool hit; };
        const auto pipe_start = std::chrono::steady_clock::now();
        const double shoot_before = stats.shoot_seconds;
        tbb::parallel_pipeline(
            window,
            tbb::make_filter<void, Part>(tbb::filter_mode::serial_in_order,
                                         [&](tbb::flow_control& fc) -> Part {
                                             if (next_part == queue.size()) { fc.stop(); return {}; }
                                             return queue[next_part++];
                                         }) &
                tbb::make_filter<Part, Loaded>(tbb::filter_mode::parallel,
                                               [&](Part q) -> Loaded {
                                                   bool hit = false;
                                                   Chunk c = load(q, hit);
                                                   return {q, std::move(c), hit};
                                               }) &
                tbb::make_filter<Loaded, void>(tbb::filter_mode::serial_in_order, [&](const Loaded& in) {
                    const Part q = in.part;
                    (in.hit ? stats.chunk_hits : stats.chunk_reads) += 1;
                    auto t0 = std::chrono::steady_clock::now();
                    const TransportLinks& t = *in.links;
                    const uint16_t* delta = t.deltas();
                    const float* coupling = t.coupling.data();
                    for (size_t r = 0, k = 0, j = 0; r < t.runs(); ++r) {
                        const RGB d = b[t.sources[r]] - shot[t.sources[r]];
                        uint32_t rc = 0;
                        if (!clusters_receive) {
                            for (const size_t end = t.run_end[r]; k < end; ++k) {
                                rc += delta[k] ? delta[k] : t.escape(j++);
                                received[rc] += d * double(coupling[k]);
                            }
                            continue;
                        }
                        for (const size_t end = t.run_end[r]; k < end; ++k) {
                            rc += delta[k] ? delta[k] : t.escape(j++);
                            const uint32_t slot = h.slot_of(rc);
                            if (slot == kNoNode) received[rc] += d * double(coupling[k]);
                            else received_clusters[slot].add(d * double(coupling[k]), h.reception(rc, t.sources[r]));
                        }
                    }
                    // A group's sources shoot B - shot as it was when the group began; shot
                    // is updated after its last part.
                    const size_t k = shot_parts++;
                    const bool group_done = k + 1 == queue.size() || queue[k + 1].group != q.group;
                    if (group_done) {
                        for (uint32_t src : sources[q.group]) shot[src] = b[src];
                        ++stats.groups_shot;
                    }
                    stats.shoot_seconds += seconds_since(t0);
                    stats.links_shot += t.size();
                    const uint64_t bytes = t.bytes();
                    if (!in.hit && cached_bytes + bytes <= cache_capacity) {
                        cache[first_part[q.group] + q.part] = in.links;
                        cached_bytes += bytes;
                    } else if (!in.hit) {
                        std::lock_guard<std::mutex> lock(spare_mutex);
                        spare.push_back(in.links);
                    }
                    stats.resident_bytes_peak = std::max<uint64_t>(stats.resident_bytes_peak, cached_bytes + in_flight);
                }));
        shot_parts = 0;
        // What the pipeline took beyond shooting: the shooter waiting for chunks.
        stats.read_wait_seconds += seconds_since(pipe_start) - (stats.shoot_seconds - shoot_before);
        gather_and_push_pull();
        ++round;
        sol.residual_history.push_back(residual);
        if (opt.on_round && !opt.on_round(round, residual)) break;
        if (opt.checkpoint_seconds > 0 && !opt.checkpoint_path.empty() &&
            seconds_since(last_checkpoint) >= std::max(opt.checkpoint_seconds, kCheckpointSpacing * last_write)) {
            const auto t0 = std::chrono::steady_clock::now();
            checkpoint();
            last_write = seconds_since(t0);
            stats.checkpoint_write_seconds += last_write;
            last_checkpoint = std::chrono::steady_clock::now();
        }
    }
    stats.rounds = round;
    sol.iterations = round;
    sol.limited_leaves = terms.limited();
    sol.normalised_leaves = terms.normalised();
    // Fraction of each node's power carried by its own and its ancestors' links.
    sol.outgoing.assign(n, 0.0);
    for (size_t i = 0; i < n; ++i)
        sol.outgoing[i] = outgoing[i] + (h.nodes[i].parent == kNoNode ? 0.0 : sol.outgoing[h.nodes[i].parent]);
    // The irradiance that goes with B: the last push-pull again (the same B, to the bit), in
    // the memory `shot` held (none before the first push-pull, as B is then the start).
    shot = std::vector<RGB>();
    std::vector<RGB> irradiance(n);
    if (pushed) push_pull_power(h, received, b, terms, received_clusters, &irradiance);
    sol.radiosity = std::move(b);
    sol.irradiance = std::move(irradiance);
    return sol;
}

}  // namespace hirad
