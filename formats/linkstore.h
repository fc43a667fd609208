// The on-disk link store: the links of hierarchical radiosity, out of core.
//
// A store is a directory holding one chunk file per range [source_begin, source_end) of
// source groups (the engine's partition of the source nodes: blocks of input faces in
// cluster order; which group a source belongs to is the engine's to check) and a manifest
// that lists them. A store without a committed manifest is never used.
//
//   <dir>/manifest                              written last, atomically, by commit()
//   <dir>/chunk-<begin:08x>-<end:08x>.hlc       one per write_chunk() call
//
// All integers are little-endian. Header fields are written byte by byte; the per-link arrays
// of the transport section are read and written in place (a little-endian machine is
// required, and checked when this is compiled).
// Checksums are XXH3_64bits (seed 0).
//
// Chunk file: an 80-byte header, then two sections. The transport section holds what a
// solve reads (who shoots to whom, and the coupling); the detail section holds what only
// refinement reads (unoccluded coupling, visibility, error estimate). A solve checks the
// whole file the first time it reads it, then reads and decodes only the transport section.
//    0  char[8]  magic "HRDLINKC"
//    8  u32      format version (kLinkStoreVersion)
//   12  u32      chunk index: the chunk's position in the manifest (0xffffffff until commit()
//                assigns it, because chunks may be written in any order)
//   16  u32      source_begin
//   20  u32      source_end
//   24  u64      link count n
//   32  u32      run count m: the distinct sources (runs of links with the same source)
//   36  u32      escape count e: receiver deltas that do not fit 16 bits (see below)
//   40  u64      transport section size T
//   48  u64      detail section size D (compressed); the file is exactly 80 + T + D bytes
//   56  u64      checksum of the transport section
//   64  u64      checksum of the detail section
//   72  u64      checksum of header bytes [0, 72)
// Records are sorted by source, then receiver, strictly (no two links join the same pair);
// the writer sorts them.
//   transport section: per link its coupling, a little-endian f32 (4 n bytes, stored as they
//     are: mantissa bits, which no compressor shrinks, and a solve reads them in place), then
//     one LZ4 block of 4 e + 2 n + 8 m bytes:
//       the escapes, u32 each;
//       per link its receiver delta, u16: the receiver minus the previous receiver of its run
//         (the first of a run: the receiver itself), or 0 when that difference is 0 or does
//         not fit 16 bits, in which case the difference is the next escape (the escapes are
//         in link order);
//       per run the source - the previous run's source (the first: the source itself), then
//         per run its link count (each >= 1, summing to n), as byte planes: byte 0 of every
//         word, then byte 1 of every word, and so on.
//     A solve sums the deltas as it shoots: decoding does not rebuild the receivers. LZ4
//     rather than zstd because a solve decodes every chunk in every round.
//   detail section: one zstd frame of the byte planes of, per link, unoccluded XOR coupling
//     (zero when the link is fully visible), then visibility, then error (12 n bytes).
//
// Manifest: a 40-byte header, 88 bytes per chunk, then a checksum of all preceding bytes.
//    0  char[8]  magic "HRDLINKM"
//    8  u32      format version
//   12  u32      node count: every receiver and source index is below it
//   16  u32      element count
//   20  u32      chunk count
//   24  u64      scene fingerprint
//   32  u64      config fingerprint
//   per chunk, sorted by source_begin, group ranges not empty and not overlapping:
//    0  char[32] file name, NUL padded (must be chunk_file_name(begin, end))
//   32  u32      source_begin
//   36  u32      source_end
//   40  u64      link count
//   48  u32      run count
//   52  u32      escape count
//   56  u64      transport section size
//   64  u64      detail section size
//   72  u64      checksum of the transport section
//   80  u64      checksum of the detail section
//   end u64      checksum of every byte before it
//
// Errors: problems with the files throw std::runtime_error naming the file, the chunk index
// and what is wrong; bad arguments to the writer throw std::invalid_argument, and misuse
// (write_chunk after commit, commit twice) std::logic_error.
#pragma once
#include <cstddef>
#include <cstdint>
#include <atomic>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <type_traits>
#include <vector>

#include "pipeline/core/link.h"

namespace hirad {

// A link as stored is the engine's Link (pipeline/core/link.h), the one record: the store
// takes and gives the links the refinement makes, with no copy field by field.
// LinkRecord is its former name here, kept for callers not yet renamed.
using LinkRecord = Link;

constexpr uint32_t kLinkStoreVersion = 3;
constexpr size_t kChunkHeaderSize = 80;
constexpr uint64_t kMaxLinksPerChunk = uint64_t(1) << 24;  // 384 MiB decoded
constexpr uint32_t kMaxChunks = uint32_t(1) << 20;

// What a solve needs of a chunk's links, in runs of one source: links
// [run_end[r - 1], run_end[r]) (from 0 for the first run) leave sources[r]. A link's receiver
// is the previous receiver of its run (0 before its first link) plus its delta: deltas()[i],
// or, when that is 0, the next escape (escape(j), in order through the chunk). Validated when
// decoded: receivers strictly increase within a run and are below receiver_end.
struct TransportLinks {
    std::vector<uint32_t> sources;    // per run, strictly increasing
    std::vector<uint32_t> run_end;    // per run, strictly increasing, the last = size()
    std::vector<float> coupling;      // per link: G, m^2, finite and >= 0
    std::vector<uint16_t> packed;     // the escapes (two words each), then the deltas
    size_t escape_count = 0;
    uint32_t receiver_end = 0;        // one past the largest receiver; 0 without links

    size_t size() const { return coupling.size(); }
    size_t runs() const { return sources.size(); }
    const uint16_t* deltas() const { return packed.data() + 2 * escape_count; }
    uint32_t escape(size_t j) const { return uint32_t(packed[2 * j]) | uint32_t(packed[2 * j + 1]) << 16; }
    // Every link's receiver (for whole reads and tests; a solve sums the deltas itself).
    std::vector<uint32_t> receivers() const;
    // What it holds in memory (for budgets: with the decoder's working room), and the same
    // for a chunk of n links in m runs with e escapes.
    static uint64_t bytes_for(uint64_t n, uint64_t m, uint64_t e) { return 6 * n + 16 * m + 4 * e; }
    uint64_t bytes() const { return bytes_for(size(), runs(), escape_count); }
    // From links sorted by source, then receiver.
    void assign(const Link* sorted_links, size_t count);
};

// What the engine compares to decide whether a store can be reused.
struct LinkStoreInfo {
    uint64_t scene_fingerprint = 0;
    uint64_t config_fingerprint = 0;
    uint32_t node_count = 0;
    uint32_t element_count = 0;  // at most node_count
};

// A manifest entry.
struct ChunkEntry {
    uint32_t source_begin = 0;
    uint32_t source_end = 0;
    uint64_t link_count = 0;
    uint32_t run_count = 0;
    uint64_t transport_size = 0;      // section bytes
    uint64_t detail_size = 0;
    uint64_t transport_checksum = 0;
    uint64_t detail_checksum = 0;
    uint32_t escape_count = 0;

    uint64_t compressed_size() const { return transport_size + detail_size; }
};

struct LinkStoreManifest {
    LinkStoreInfo info;
    std::vector<ChunkEntry> chunks;  // sorted by source_begin
};

// Writes a store. write_chunk() may be called from several threads at once; commit() once,
// after every write_chunk() has returned. Not for two writers on one directory.
class LinkStoreWriter {
public:
    // Creates `dir` if absent. A directory holding an earlier store (or the leftovers of an
    // uncommitted one) is cleared, its manifest first, so that new chunks are never paired
    // with the old manifest. A directory holding anything else is refused.
    LinkStoreWriter(const std::string& dir, const LinkStoreInfo& info);

    // Stores the links of the source groups [source_begin, source_end) (in any order; they
    // are sorted here) as one chunk, written to an exclusive temporary, fsynced and renamed. Ranges
    // must not overlap earlier calls'. Throws std::invalid_argument for an invalid link
    // (index out of range, duplicate pair, bad value).
    void write_chunk(uint32_t source_begin, uint32_t source_end, const Link* links, size_t count);
    void write_chunk(uint32_t source_begin, uint32_t source_end, const std::vector<Link>& links) {
        write_chunk(source_begin, source_end, links.data(), links.size());
    }

    // The final node and element counts, for a store written while its hierarchy still grows
    // (created with node_count UINT32_MAX): must cover every index written.
    void set_counts(uint32_t node_count, uint32_t element_count);

    // Numbers the chunks by source_begin, writes the manifest to a temporary file, fsyncs it,
    // renames it into place and fsyncs the directory. Refused after a failed write_chunk().
    void commit();

private:
    struct Slot {
        ChunkEntry entry;
        bool written = false;
    };
    std::string dir_;
    LinkStoreInfo info_;
    std::mutex mutex_;                // guards the members below
    std::map<uint32_t, Slot> slots_;  // by source_begin; reserved before the chunk is written
    bool failed_ = false;
    bool committed_ = false;
    uint64_t indices_end_ = 0;        // one past the largest receiver or source written
};

// Reads a committed store. Every method is const and may be called concurrently from several
// threads (e.g. prefetching ones); the only state kept is which chunks were checked whole.
class LinkStoreReader {
public:
    // Reads and validates the manifest.
    explicit LinkStoreReader(const std::string& dir);

    const LinkStoreInfo& info() const { return manifest_.info; }
    const LinkStoreManifest& manifest() const { return manifest_; }
    size_t chunk_count() const { return manifest_.chunks.size(); }
    const ChunkEntry& chunk(size_t k) const { return manifest_.chunks.at(k); }
    std::string chunk_path(size_t k) const;
    uint64_t total_links() const;
    uint64_t total_compressed_bytes() const;  // both sections of every chunk, without the headers
    uint64_t total_transport_bytes() const;   // the transport sections: what a solve reads

    // The links of chunk k, sorted by source then receiver. `out` is resized; its capacity is
    // reused, so a buffer kept across calls is not reallocated once it is large enough.
    void read_chunk(size_t k, std::vector<Link>& out) const;
    // Into a caller's buffer of `capacity` records (at least chunk(k).link_count); returns
    // the number of links.
    size_t read_chunk(size_t k, Link* out, size_t capacity) const;
    // What a solve needs of chunk k: its transport section, decoded and validated. The first
    // read of a chunk by this reader checks the whole file (sizes, header, both checksums);
    // later ones read only the header and the transport section, which are checked every time.
    void read_transport(size_t k, TransportLinks& out) const;

private:
    std::string dir_;
    LinkStoreManifest manifest_;
    // Per chunk: whether a whole read found it intact (set once, by any thread).
    std::unique_ptr<std::atomic<bool>[]> verified_;
};

// The format layer under the writer and the reader, from memory (the fuzz target and the
// tests use it directly). `path` only names the file in error messages.
std::string chunk_file_name(uint32_t source_begin, uint32_t source_end);
std::vector<uint8_t> encode_manifest(const LinkStoreManifest& manifest);
// Validates everything: magic, version, checksum, size, counts, every entry.
LinkStoreManifest decode_manifest(const uint8_t* data, size_t size, const std::string& path);
// A chunk file's bytes for `count` links. Does not validate the links (the writer does), so
// that tests can make invalid stores; `entry` receives the chunk's manifest entry.
std::vector<uint8_t> encode_chunk(uint32_t index, uint32_t source_begin, uint32_t source_end,
                                  const Link* sorted_links, size_t count, ChunkEntry& entry);
// Validates a chunk file's bytes against entry k of a manifest that decode_manifest()
// accepted (header against the entry field by field, checksums, sizes, every record) and
// decodes the links into out[0, link_count).
void decode_chunk(const uint8_t* data, size_t size, const LinkStoreManifest& manifest, size_t k,
                  const std::string& path, Link* out);
// The same for what a solve needs: `data` holds the first `available` bytes of a chunk file
// of `file_size` bytes, at least its header and transport section, which are validated and
// decoded. The detail section's checksum is checked when it is there (available == file_size).
void decode_transport(const uint8_t* data, size_t available, uint64_t file_size, const LinkStoreManifest& manifest,
                      size_t k, const std::string& path, TransportLinks& out);
// Every file of a store is written through write_file_atomic (pipeline/core/atomic_file.h).

}  // namespace hirad
