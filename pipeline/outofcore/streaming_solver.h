// Block Southwell on the hierarchy, streaming its links from chunks within a memory budget.
//
// The links are grouped by their source: the cluster tree is cut into subtrees of at most a
// given number of input faces (the source groups), and a group's links are its parts (chunks
// of at most kChunkLinks links, each sorted by source, then receiver).
// Every source node S keeps what it has already shot, shot_S; its unshot radiosity is
// B_S - shot_S. A round picks the groups whose unshot power (sum of A_S |B_S - shot_S| over
// their sources) is at least half the largest, in order of that power, and shoots them:
// each link R <- S adds G (B_S - shot_S) to what R received, then shot_S = B_S. Push-pull
// after the round turns what each node received over its area (the irradiance gathered at
// it, G / A_R (B_S - shot_S) summed) into new leaf radiosity. At the fixed point (nothing unshot) the gathered irradiance is exactly the
// hierarchical gather sum of G / A_R B_S, the same solution as Jacobi with push-pull.
//
// Deterministic whatever the thread count or the budget: which groups are shot and in what
// order depends only on the state; a group's links are added in their stored order, by one
// thread; the budget only decides which chunks stay decoded in memory. Other threads read and
// decode the next chunks (a TBB pipeline, two chunks in flight per thread) while one is shot.
#pragma once
#include <algorithm>
#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "pipeline/hierarchy/hierarchical_solver.h"
#include "pipeline/hierarchy/hierarchy.h"
#include "formats/linkstore.h"
#include "pipeline/hierarchy/refine.h"

namespace hirad {

constexpr uint32_t kNoGroup = UINT32_MAX;

// The partition of the sources: subtrees of the cluster tree with at most `max_faces` faces,
// in cluster order. Nodes above the cut belong to no group and never carry links.
struct SourceGroups {
    std::vector<uint32_t> roots;       // per group: the subtree's root node
    std::vector<uint32_t> first_face;  // per group: its first position in face_order (+ end)
    std::vector<uint32_t> face_rank;   // per face: its position in face_order

    static SourceGroups cut(const Hierarchy& h, uint32_t max_faces);
    size_t count() const { return roots.size(); }
    uint32_t of(const Hierarchy& h, uint32_t node) const;
};

// A group's links are cut into chunks of at most kChunkLinks (the unit read, decoded and
// held in memory; a fixed size, so the store does not depend on the budget). Chunk keys in
// the store: group g, part p -> g * kPartsPerGroup + p.
constexpr uint64_t kChunkLinks = uint64_t(1) << 14;
constexpr uint32_t kPartsPerGroup = 16384;

// A round's links by source group, in parts; the reads may be called from several threads at
// once. read() gives whole links (for refinement and the gather); read_transport() only what
// a solve needs (on disk, the chunk's transport section alone).
class LinkChunks {
public:
    virtual ~LinkChunks() = default;
    virtual size_t groups() const = 0;
    virtual size_t parts(size_t group) const = 0;
    virtual uint64_t links(size_t group, size_t part) const = 0;
    virtual uint64_t transport_bytes(size_t group, size_t part) const = 0;  // decoded, in memory
    virtual void read(size_t group, size_t part, std::vector<Link>& out) const = 0;
    virtual void read_transport(size_t group, size_t part, TransportLinks& out) const = 0;
    // Where a part comes from, for errors about its contents: a chunk file's path, or a
    // description of the part in memory.
    virtual std::string where(size_t group, size_t part) const {
        return "links in memory, group " + std::to_string(group) + " part " + std::to_string(part);
    }
    uint64_t links(size_t group) const;
    void read(size_t group, std::vector<Link>& out) const;   // all parts, in order
    uint64_t total_links() const;
};

class MemoryChunks : public LinkChunks {
public:
    explicit MemoryChunks(std::vector<std::vector<Link>> by_group);
    using LinkChunks::links;
    using LinkChunks::read;
    size_t groups() const override { return chunks_.size(); }
    size_t parts(size_t g) const override { return (chunks_[g].size() + kChunkLinks - 1) / kChunkLinks; }
    uint64_t links(size_t g, size_t p) const override {
        return std::min<uint64_t>(kChunkLinks, chunks_[g].size() - p * kChunkLinks);
    }
    uint64_t transport_bytes(size_t g, size_t p) const override { return transport_bytes_[g][p]; }
    void read(size_t g, size_t p, std::vector<Link>& out) const override {
        const auto begin = chunks_[g].begin() + p * kChunkLinks;
        out.assign(begin, begin + links(g, p));
    }
    void read_transport(size_t g, size_t p, TransportLinks& out) const override {
        out.assign(chunks_[g].data() + p * kChunkLinks, links(g, p));
    }

private:
    std::vector<std::vector<Link>> chunks_;
    std::vector<std::vector<uint64_t>> transport_bytes_;  // per group and part
};

class StoreChunks : public LinkChunks {
public:
    StoreChunks(const std::string& dir, size_t groups);
    using LinkChunks::links;
    using LinkChunks::read;
    size_t groups() const override { return parts_.size(); }
    size_t parts(size_t g) const override { return parts_[g].size(); }
    uint64_t links(size_t g, size_t p) const override { return reader_.chunk(parts_[g][p]).link_count; }
    uint64_t transport_bytes(size_t g, size_t p) const override {
        const ChunkEntry& e = reader_.chunk(parts_[g][p]);
        return TransportLinks::bytes_for(e.link_count, e.run_count, e.escape_count);
    }
    void read(size_t g, size_t p, std::vector<Link>& out) const override { reader_.read_chunk(parts_[g][p], out); }
    std::string where(size_t g, size_t p) const override { return reader_.chunk_path(parts_[g][p]); }
    void read_transport(size_t g, size_t p, TransportLinks& out) const override {
        reader_.read_transport(parts_[g][p], out);
    }
    const LinkStoreReader& reader() const { return reader_; }

private:
    LinkStoreReader reader_;
    std::vector<std::vector<size_t>> parts_;  // per group: its chunks in the store, in part order
};

// The order of the links in a part wherever they are kept: by source, then receiver (the
// store's order; in memory too, so that both give the same bits).
void sort_part(std::vector<Link>& links);

// Writes part `part` of a group's links (at most kChunkLinks, sorted by sort_part) as a chunk.
void write_part(LinkStoreWriter& writer, uint32_t group, uint32_t part, const std::vector<Link>& links);

// RGB per node from a state file's flat array of doubles (written from the RGB arrays
// themselves: StateFile::put_view); `what` names the file in the error when the size does not
// match n nodes.
std::vector<RGB> unflatten_rgb(const std::vector<double>& flat, size_t n, const std::string& what);

struct StreamingOptions {
    double tolerance = 1e-4;          // on sqrt(sum A |B - shot|^2) / sqrt(sum A E^2) over sources
    uint64_t max_rounds = 100000;
    uint64_t memory_budget = 0;       // bytes for solver state and resident chunks; 0: unlimited
    double checkpoint_seconds = 0;    // 0: no checkpoints; at least this far apart (see solve_streaming)
    std::string checkpoint_path;
    uint64_t checkpoint_fingerprint = 0;
    std::function<bool(uint64_t round, double residual)> on_round;  // false stops the solve
};

constexpr double kCheckpointSpacing = 19;

struct StreamingStats {
    uint64_t rounds = 0;
    uint64_t groups_shot = 0;
    uint64_t links_shot = 0;
    uint64_t chunk_reads = 0;         // chunks read (and decoded) from the source
    uint64_t chunk_hits = 0;          // chunks shot from memory (kept decoded)
    uint64_t resident_bytes_peak = 0; // decoded chunks held at once (kept and in flight), at most
    uint64_t state_bytes = 0;         // per-node solver state
    uint64_t largest_chunk_bytes = 0; // the largest decoded chunk (2 per thread are in flight)
    uint64_t chunks_in_flight = 0;
    uint64_t minimum_budget = 0;      // state and chunks in flight: the smallest budget taken
    uint64_t decoded_bytes = 0;       // every chunk decoded: what the links take in memory
    uint64_t checkpoints = 0;
    bool resumed = false;
    double read_wait_seconds = 0;     // time the shooter waited for the reader
    double shoot_seconds = 0;
    double checkpoint_write_seconds = 0;  // writing checkpoints, in all
};

// `is_source` and `outgoing` (per node: sum of G / A_S over its links) come from link
// generation. Resumes from the checkpoint file when it exists with the same fingerprint.
// Checkpoints are written checkpoint_seconds apart, or further: the next one waits at least
// kCheckpointSpacing times as long as the last one took to write, so that writing them is at
// most a twentieth of the solve (on the 10M-triangle building a checkpoint is 1.9 GB, and
// written every minute it was half of the solve's time: bench/README.md, stop 44).
// `start` (per node; empty: the emission) becomes the solver's B: moved in, it is not copied.
HierarchicalSolution solve_streaming(const Hierarchy& h, const SourceGroups& groups, const LinkChunks& chunks,
                                     const std::vector<uint8_t>& is_source, const std::vector<double>& outgoing,
                                     std::vector<RGB> start, const StreamingOptions& options,
                                     StreamingStats& stats);

}  // namespace hirad
