#include "pipeline/outofcore/outofcore.h"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <stdexcept>
#include <string>

#include "pipeline/hierarchy/hierarchical_solver.h"

namespace hirad {

RoundWriter::RoundWriter(const std::string& dir, size_t groups, LinkStoreInfo info) : dir_(dir), memory_(groups) {
    if (!dir_.empty()) writer_ = std::make_unique<LinkStoreWriter>(dir_, info);
}

void RoundWriter::add(uint32_t group, const std::vector<Link>& links) {
    for (const Link& l : links) {
        pending_.push_back(l);
        if (pending_.size() == kChunkLinks) put_part(group);
    }
}

void RoundWriter::end_group(uint32_t group) {
    if (!pending_.empty()) put_part(group);
    parts_ = 0;
}

std::unique_ptr<LinkChunks> RoundWriter::finish(uint32_t nodes, uint32_t elements) {
    if (!writer_) return std::make_unique<MemoryChunks>(std::move(memory_));
    writer_->set_counts(nodes, elements);
    writer_->commit();
    writer_.reset();
    return std::make_unique<StoreChunks>(dir_, memory_.size());
}

void RoundWriter::put_part(uint32_t group) {
    sort_part(pending_);
    if (on_part) on_part(pending_);
    if (writer_) write_part(*writer_, group, parts_++, pending_);
    else memory_[group].insert(memory_[group].end(), pending_.begin(), pending_.end());
    pending_.clear();
}

std::vector<Link> all_links(const LinkChunks& chunks) {
    std::vector<Link> out;
    out.reserve(chunks.total_links());
    std::vector<Link> buf;
    for (size_t g = 0; g < chunks.groups(); ++g) {
        chunks.read(g, buf);
        out.insert(out.end(), buf.begin(), buf.end());
    }
    sort_links(out);
    return out;
}

GatherLinks gather_links(const LinkChunks& chunks, size_t nodes) {
    GatherLinks out;
    out.first.assign(nodes + 1, 0);
    std::vector<Link> part;
    for (size_t g = 0; g < chunks.groups(); ++g)
        for (size_t p = 0; p < chunks.parts(g); ++p) {
            chunks.read(g, p, part);
            for (const Link& l : part) {
                if (l.receiver >= nodes || l.source >= nodes)
                    throw std::invalid_argument(chunks.where(g, p) + ": a link from node " + std::to_string(l.source) +
                                                " to node " + std::to_string(l.receiver) +
                                                " is out of the hierarchy's " + std::to_string(nodes) +
                                                " nodes (the store is not this bake's, or is damaged)");
                ++out.first[l.receiver + 1];
            }
        }
    for (size_t i = 0; i < nodes; ++i) out.first[i + 1] += out.first[i];
    out.links.resize(out.first[nodes]);
    std::vector<uint64_t> next(out.first.begin(), out.first.end() - 1);
    for (size_t g = 0; g < chunks.groups(); ++g)
        for (size_t p = 0; p < chunks.parts(g); ++p) {
            chunks.read(g, p, part);
            for (const Link& l : part) {
                if (next[l.receiver] == out.first[l.receiver + 1])
                    throw std::runtime_error(chunks.where(g, p) + ": node " + std::to_string(l.receiver) +
                                             " receives more links than when the store was first read (it "
                                             "changed while the gather read it)");
                out.links[next[l.receiver]++] = GatherLink{l.source, l.coupling, l.visibility};
            }
        }
    // Within a receiver by source, then by value (a total order: the same table whatever
    // order the parts came in).
    tbb::parallel_for(size_t(0), nodes, [&](size_t i) {
        std::sort(out.links.begin() + out.first[i], out.links.begin() + out.first[i + 1],
                  [](const GatherLink& a, const GatherLink& b) {
                      if (a.source != b.source) return a.source < b.source;
                      if (a.coupling != b.coupling) return a.coupling < b.coupling;
                      return a.visibility < b.visibility;
                  });
    });
    return out;
}

GatherLinks gather_links(const std::string& dir, size_t groups, size_t nodes) {
    return gather_links(StoreChunks(dir, groups), nodes);
}

}  // namespace hirad
