#include "pipeline/outofcore/outofcore.h"

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

std::vector<Link> load_links(const std::string& dir, size_t groups) { return all_links(StoreChunks(dir, groups)); }

}  // namespace hirad
