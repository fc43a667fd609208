#include "linkstore.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>
#include <xxhash.h>
#include <zstd.h>

#include <algorithm>
#include <array>
#include <cctype>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <memory>
#include <stdexcept>

namespace hirad {
namespace {

namespace fs = std::filesystem;

constexpr char kChunkMagic[8] = {'H', 'R', 'D', 'L', 'I', 'N', 'K', 'C'};
constexpr char kManifestMagic[8] = {'H', 'R', 'D', 'L', 'I', 'N', 'K', 'M'};
constexpr uint32_t kUnassignedIndex = 0xffffffff;
constexpr size_t kManifestHeaderSize = 40;
constexpr size_t kManifestEntrySize = 64;
constexpr size_t kNameSize = 32;
constexpr size_t kRecordSize = sizeof(LinkRecord);
constexpr int kZstdLevel = 1;          // level 3 saves ~1 % of the bytes, compressing ~30 % slower
constexpr int kZstdWindowLogMax = 24;  // bounds the decoder's memory whatever a frame asks for
const char* const kManifestName = "manifest";

void put32(uint8_t* p, uint32_t v) {
    for (int i = 0; i < 4; ++i) p[i] = uint8_t(v >> (8 * i));
}
void put64(uint8_t* p, uint64_t v) {
    for (int i = 0; i < 8; ++i) p[i] = uint8_t(v >> (8 * i));
}
uint32_t get32(const uint8_t* p) {
    uint32_t v = 0;
    for (int i = 0; i < 4; ++i) v |= uint32_t(p[i]) << (8 * i);
    return v;
}
uint64_t get64(const uint8_t* p) {
    uint64_t v = 0;
    for (int i = 0; i < 8; ++i) v |= uint64_t(p[i]) << (8 * i);
    return v;
}
uint64_t checksum(const uint8_t* p, size_t n) { return XXH3_64bits(p, n); }
uint32_t bits(float f) {
    uint32_t u;
    std::memcpy(&u, &f, 4);
    return u;
}
float from_bits(uint32_t u) {
    float f;
    std::memcpy(&f, &u, 4);
    return f;
}

[[noreturn]] void throw_os(const std::string& path, const std::string& what) {
    throw std::runtime_error(path + ": " + what + ": " + std::strerror(errno));
}
[[noreturn]] void chunk_fail(const std::string& path, size_t k, const std::string& what) {
    throw std::runtime_error(path + ": chunk " + std::to_string(k) + ": " + what);
}
std::string size_problem(uint64_t expected, uint64_t found) {
    return (found < expected ? "truncated: expected " : "too long: expected ") + std::to_string(expected) +
           " bytes, found " + std::to_string(found);
}

// Closes a file descriptor on every path out of a scope.
struct Fd {
    int fd;
    explicit Fd(int f) : fd(f) {}
    ~Fd() {
        if (fd >= 0) ::close(fd);
    }
    Fd(const Fd&) = delete;
    Fd& operator=(const Fd&) = delete;
    // Closes now, so that a failing close (a delayed write error) is seen.
    void close(const std::string& path) {
        const int f = fd;
        fd = -1;
        if (::close(f) != 0) throw_os(path, "close failed");
    }
};

void write_all(int fd, const uint8_t* p, size_t n, const std::string& path) {
    while (n > 0) {
        const ssize_t w = ::write(fd, p, n);
        if (w < 0) {
            if (errno == EINTR) continue;
            throw_os(path, "write failed");
        }
        p += w;
        n -= size_t(w);
    }
}

void fsync_dir(const std::string& dir) {
    Fd fd(::open(dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC));
    if (fd.fd < 0) throw_os(dir, "cannot open the directory to fsync it");
    if (::fsync(fd.fd) != 0) throw_os(dir, "fsync of the directory failed");
    fd.close(dir);
}

void rename_file(const std::string& from, const std::string& to) {
    if (::rename(from.c_str(), to.c_str()) != 0) throw_os(from, "cannot rename to " + to);
}

void remove_file(const std::string& path) {
    if (::unlink(path.c_str()) != 0 && errno != ENOENT) throw_os(path, "cannot remove");
}

// Reads a whole file of at most max_size bytes (checked before anything is allocated).
std::vector<uint8_t> read_small_file(const std::string& path, size_t max_size) {
    Fd fd(::open(path.c_str(), O_RDONLY | O_CLOEXEC));
    if (fd.fd < 0) throw_os(path, "cannot open");
    struct stat st;
    if (::fstat(fd.fd, &st) != 0) throw_os(path, "cannot stat");
    if (uint64_t(st.st_size) > max_size)
        throw std::runtime_error(path + ": " + std::to_string(st.st_size) + " bytes, more than the " +
                                 std::to_string(max_size) + " a valid file can have");
    std::vector<uint8_t> data(size_t(st.st_size));
    size_t got = 0;
    while (got < data.size()) {
        const ssize_t r = ::read(fd.fd, data.data() + got, data.size() - got);
        if (r < 0 && errno == EINTR) continue;
        if (r < 0) throw_os(path, "read failed");
        if (r == 0) break;  // shrank while being read: the caller sees a short buffer
        got += size_t(r);
    }
    data.resize(got);
    return data;
}

bool is_hex(const std::string& s, size_t begin, size_t end) {
    for (size_t i = begin; i < end; ++i)
        if (!std::isxdigit(static_cast<unsigned char>(s[i]))) return false;
    return true;
}

bool is_chunk_name(const std::string& s) {
    return s.size() == 27 && s.compare(0, 6, "chunk-") == 0 && s[14] == '-' && s.compare(23, 4, ".hlc") == 0 &&
           is_hex(s, 6, 14) && is_hex(s, 15, 23);
}

// Files a writer may leave in a store directory: the only ones it will clear.
bool is_store_file(const std::string& name) {
    const std::string tmp = ".tmp";
    const bool is_tmp = name.size() > tmp.size() && name.compare(name.size() - tmp.size(), tmp.size(), tmp) == 0;
    const std::string base = is_tmp ? name.substr(0, name.size() - tmp.size()) : name;
    return base == kManifestName || is_chunk_name(base);
}

std::array<uint8_t, kChunkHeaderSize> chunk_header(const ChunkEntry& e, uint32_t index) {
    std::array<uint8_t, kChunkHeaderSize> h{};
    std::memcpy(h.data(), kChunkMagic, 8);
    put32(&h[8], kLinkStoreVersion);
    put32(&h[12], index);
    put32(&h[16], e.source_begin);
    put32(&h[20], e.source_end);
    put64(&h[24], e.link_count);
    put64(&h[32], e.compressed_size);
    put64(&h[40], e.link_count * kRecordSize);
    put64(&h[48], e.checksum);
    put64(&h[56], checksum(h.data(), 56));
    return h;
}

// Empty if `r` may follow `prev` (null for a chunk's first record), else what is wrong.
// Which group a source belongs to is the engine's to check: the store does not know it.
std::string record_problem(const LinkRecord& r, const LinkRecord* prev, uint32_t node_count) {
    auto finite_nonnegative = [](float v) { return std::isfinite(v) && v >= 0; };
    if (r.receiver >= node_count)
        return "receiver index " + std::to_string(r.receiver) + " >= node count " + std::to_string(node_count);
    if (r.source >= node_count)
        return "source index " + std::to_string(r.source) + " >= node count " + std::to_string(node_count);
    if (prev && (r.source < prev->source || (r.source == prev->source && r.receiver <= prev->receiver)))
        return "(source " + std::to_string(r.source) + ", receiver " + std::to_string(r.receiver) +
               ") after (source " + std::to_string(prev->source) + ", receiver " + std::to_string(prev->receiver) +
               "): links must be sorted by source, then receiver, without duplicates";
    if (!finite_nonnegative(r.coupling)) return "coupling " + std::to_string(r.coupling) + " is not finite and >= 0";
    if (!finite_nonnegative(r.unoccluded))
        return "unoccluded coupling " + std::to_string(r.unoccluded) + " is not finite and >= 0";
    if (!(r.visibility >= 0 && r.visibility <= 1))
        return "visibility " + std::to_string(r.visibility) + " is not in [0, 1]";
    if (!std::isfinite(r.error)) return "error estimate " + std::to_string(r.error) + " is not finite";
    return {};
}

std::string record_name(size_t i, const LinkRecord& r) {
    return "link " + std::to_string(i) + " (receiver " + std::to_string(r.receiver) + ", source " +
           std::to_string(r.source) + ")";
}

// The payload transform (see the header): m records to 24 byte planes of m bytes. `prev` is
// the record before the block, and becomes its last.
void encode_block(const LinkRecord* r, size_t m, LinkRecord& prev, uint8_t* planes) {
    for (size_t i = 0; i < m; ++i) {
        const uint32_t w[6] = {r[i].receiver - (r[i].source == prev.source ? prev.receiver : 0),
                               r[i].source - prev.source,
                               bits(r[i].coupling),
                               bits(r[i].unoccluded) ^ bits(r[i].coupling),
                               bits(r[i].visibility),
                               bits(r[i].error)};
        for (size_t c = 0; c < 6; ++c)
            for (size_t b = 0; b < 4; ++b) planes[(4 * c + b) * m + i] = uint8_t(w[c] >> (8 * b));
        prev = r[i];
    }
}

// The inverse. Total on any input (unsigned arithmetic wraps); the caller validates. Plane by
// plane first (loops the compiler vectorises), then the deltas record by record.
void decode_block(const uint8_t* planes, size_t m, LinkRecord& prev, LinkRecord* r) {
    thread_local std::vector<uint32_t> words;
    words.assign(6 * m, 0);
    for (size_t c = 0; c < 6; ++c) {
        uint32_t* w = words.data() + c * m;
        for (size_t b = 0; b < 4; ++b) {
            const uint8_t* plane = planes + (4 * c + b) * m;
            for (size_t i = 0; i < m; ++i) w[i] |= uint32_t(plane[i]) << (8 * b);
        }
    }
    const uint32_t* w = words.data();
    for (size_t i = 0; i < m; ++i) {
        LinkRecord& o = r[i];
        o.source = prev.source + w[m + i];
        o.receiver = w[i] + (o.source == prev.source ? prev.receiver : 0);
        o.coupling = from_bits(w[2 * m + i]);
        o.unoccluded = from_bits(w[3 * m + i] ^ w[2 * m + i]);
        o.visibility = from_bits(w[4 * m + i]);
        o.error = from_bits(w[5 * m + i]);
        prev = o;
    }
}

// record_problem's checks without building a message: the fast path of reading.
inline bool record_ok(const LinkRecord& r, const LinkRecord* prev, uint32_t node_count) {
    return r.receiver < node_count && r.source < node_count &&
           (!prev || r.source > prev->source || (r.source == prev->source && r.receiver > prev->receiver)) &&
           std::isfinite(r.coupling) && r.coupling >= 0 && std::isfinite(r.unoccluded) && r.unoccluded >= 0 &&
           r.visibility >= 0 && r.visibility <= 1 && std::isfinite(r.error);
}

struct ZstdFree {
    void operator()(ZSTD_CCtx* c) const { ZSTD_freeCCtx(c); }
    void operator()(ZSTD_DCtx* d) const { ZSTD_freeDCtx(d); }
};

}  // namespace

std::string chunk_file_name(uint32_t source_begin, uint32_t source_end) {
    char name[kNameSize];
    std::snprintf(name, sizeof name, "chunk-%08x-%08x.hlc", source_begin, source_end);
    return name;
}

std::vector<uint8_t> encode_manifest(const LinkStoreManifest& m) {
    std::vector<uint8_t> out(kManifestHeaderSize + kManifestEntrySize * m.chunks.size() + 8, 0);
    uint8_t* p = out.data();
    std::memcpy(p, kManifestMagic, 8);
    put32(p + 8, kLinkStoreVersion);
    put32(p + 12, m.info.node_count);
    put32(p + 16, m.info.element_count);
    put32(p + 20, uint32_t(m.chunks.size()));
    put64(p + 24, m.info.scene_fingerprint);
    put64(p + 32, m.info.config_fingerprint);
    p += kManifestHeaderSize;
    for (const ChunkEntry& e : m.chunks) {
        const std::string name = chunk_file_name(e.source_begin, e.source_end);
        std::memcpy(p, name.data(), name.size());  // NUL padded: `out` starts zeroed
        put32(p + 32, e.source_begin);
        put32(p + 36, e.source_end);
        put64(p + 40, e.link_count);
        put64(p + 48, e.compressed_size);
        put64(p + 56, e.checksum);
        p += kManifestEntrySize;
    }
    put64(p, checksum(out.data(), out.size() - 8));
    return out;
}

LinkStoreManifest decode_manifest(const uint8_t* data, size_t size, const std::string& path) {
    auto fail = [&](const std::string& what) { throw std::runtime_error(path + ": " + what); };
    if (size < kManifestHeaderSize + 8)
        fail(size_problem(kManifestHeaderSize + 8, size) + " (the smallest manifest)");
    if (std::memcmp(data, kManifestMagic, 8) != 0) fail("not a link store manifest (bad magic)");
    if (get32(data + 8) != kLinkStoreVersion)
        fail("format version " + std::to_string(get32(data + 8)) + ", this reader reads version " +
             std::to_string(kLinkStoreVersion));
    if (checksum(data, size - 8) != get64(data + size - 8)) fail("checksum mismatch");
    LinkStoreManifest m;
    m.info.node_count = get32(data + 12);
    m.info.element_count = get32(data + 16);
    const uint32_t count = get32(data + 20);
    m.info.scene_fingerprint = get64(data + 24);
    m.info.config_fingerprint = get64(data + 32);
    if (count > kMaxChunks)
        fail(std::to_string(count) + " chunks, more than the maximum " + std::to_string(kMaxChunks));
    const size_t expected = kManifestHeaderSize + kManifestEntrySize * size_t(count) + 8;
    if (size != expected) fail(size_problem(expected, size) + " for " + std::to_string(count) + " chunks");
    if (m.info.element_count > m.info.node_count)
        fail("element count " + std::to_string(m.info.element_count) + " > node count " +
             std::to_string(m.info.node_count));
    m.chunks.resize(count);
    for (uint32_t i = 0; i < count; ++i) {
        const uint8_t* p = data + kManifestHeaderSize + kManifestEntrySize * i;
        ChunkEntry& e = m.chunks[i];
        e.source_begin = get32(p + 32);
        e.source_end = get32(p + 36);
        e.link_count = get64(p + 40);
        e.compressed_size = get64(p + 48);
        e.checksum = get64(p + 56);
        const std::string name = chunk_file_name(e.source_begin, e.source_end);
        const std::string where = "chunk " + std::to_string(i) + " (" + name + "): ";
        char expected_name[kNameSize] = {};
        std::memcpy(expected_name, name.data(), name.size());
        if (std::memcmp(p, expected_name, kNameSize) != 0)
            fail(where + "the file name does not match the group range");
        if (e.source_begin >= e.source_end)
            fail(where + "group range [" + std::to_string(e.source_begin) + ", " + std::to_string(e.source_end) +
                 ") is empty");
        if (i > 0 && e.source_begin < m.chunks[i - 1].source_end)
            fail(where + "group range overlaps or precedes the previous chunk's");
        // Links join distinct pairs, so a chunk has at most nodes^2 of them.
        if (e.link_count > kMaxLinksPerChunk || e.link_count > uint64_t(m.info.node_count) * m.info.node_count)
            fail(where + std::to_string(e.link_count) + " links: more than the maximum " +
                 std::to_string(kMaxLinksPerChunk) + " or than the nodes can have");
        if (e.compressed_size == 0 || e.compressed_size > ZSTD_compressBound(e.link_count * kRecordSize))
            fail(where + "compressed size " + std::to_string(e.compressed_size) + " impossible for " +
                 std::to_string(e.link_count) + " links");
    }
    return m;
}

std::vector<uint8_t> encode_chunk(uint32_t index, uint32_t source_begin, uint32_t source_end,
                                  const LinkRecord* links, size_t count, ChunkEntry& entry) {
    if (count > kMaxLinksPerChunk)
        throw std::invalid_argument("a chunk holds at most " + std::to_string(kMaxLinksPerChunk) + " links, not " +
                                    std::to_string(count));
    const size_t raw_size = count * kRecordSize;
    std::vector<uint8_t> out(kChunkHeaderSize + ZSTD_compressBound(raw_size));
    std::unique_ptr<ZSTD_CCtx, ZstdFree> cctx(ZSTD_createCCtx());
    if (!cctx) throw std::bad_alloc();
    auto check = [](size_t r) {
        if (ZSTD_isError(r)) throw std::runtime_error(std::string("zstd compression failed: ") + ZSTD_getErrorName(r));
        return r;
    };
    check(ZSTD_CCtx_setParameter(cctx.get(), ZSTD_c_compressionLevel, kZstdLevel));
    check(ZSTD_CCtx_setPledgedSrcSize(cctx.get(), raw_size));
    std::vector<uint8_t> planes(std::min<size_t>(count, kBlockLinks) * kRecordSize);
    ZSTD_outBuffer zout{out.data() + kChunkHeaderSize, out.size() - kChunkHeaderSize, 0};
    LinkRecord prev{0, source_begin, 0, 0, 0, 0};
    size_t done = 0;
    do {  // at least once, so that an empty chunk is still a complete frame
        const size_t m = std::min<size_t>(kBlockLinks, count - done);
        encode_block(links + done, m, prev, planes.data());
        done += m;
        const ZSTD_EndDirective mode = done == count ? ZSTD_e_end : ZSTD_e_continue;
        ZSTD_inBuffer in{planes.data(), m * kRecordSize, 0};
        // The output holds the compression bound, so each call consumes its whole block.
        const size_t left = check(ZSTD_compressStream2(cctx.get(), &zout, &in, mode));
        if (in.pos != in.size || (mode == ZSTD_e_end && left != 0))
            throw std::logic_error("zstd output exceeded its compression bound");
    } while (done < count);
    entry.source_begin = source_begin;
    entry.source_end = source_end;
    entry.link_count = count;
    entry.compressed_size = zout.pos;
    entry.checksum = checksum(out.data() + kChunkHeaderSize, zout.pos);
    const auto header = chunk_header(entry, index);
    std::copy(header.begin(), header.end(), out.begin());
    out.resize(kChunkHeaderSize + zout.pos);
    return out;
}

void decode_chunk(const uint8_t* data, size_t size, const LinkStoreManifest& manifest, size_t k,
                  const std::string& path, LinkRecord* out) {
    if (k >= manifest.chunks.size())
        chunk_fail(path, k, "no such chunk: the manifest lists " + std::to_string(manifest.chunks.size()));
    const ChunkEntry& e = manifest.chunks[k];
    if (e.link_count > kMaxLinksPerChunk) chunk_fail(path, k, "the manifest entry was not validated");
    const uint64_t expected_size = kChunkHeaderSize + e.compressed_size;
    if (size != expected_size) chunk_fail(path, k, size_problem(expected_size, size));
    if (std::memcmp(data, kChunkMagic, 8) != 0) chunk_fail(path, k, "not a link chunk (bad magic)");
    if (get32(data + 8) != kLinkStoreVersion)
        chunk_fail(path, k, "format version " + std::to_string(get32(data + 8)) + ", expected " +
                                std::to_string(kLinkStoreVersion));
    if (checksum(data, 56) != get64(data + 56)) chunk_fail(path, k, "header checksum mismatch");
    auto agree = [&](const char* field, uint64_t in_chunk, uint64_t in_manifest) {
        if (in_chunk != in_manifest)
            chunk_fail(path, k, std::string("header disagrees with the manifest: ") + field + " " +
                                    std::to_string(in_chunk) + " in the chunk, " + std::to_string(in_manifest) +
                                    " in the manifest");
    };
    agree("chunk index", get32(data + 12), k);
    agree("source_begin", get32(data + 16), e.source_begin);
    agree("source_end", get32(data + 20), e.source_end);
    agree("link count", get64(data + 24), e.link_count);
    agree("compressed size", get64(data + 32), e.compressed_size);
    agree("payload checksum", get64(data + 48), e.checksum);
    const uint64_t raw_size = e.link_count * kRecordSize;  // no overflow: link_count was bounded
    if (get64(data + 40) != raw_size)
        chunk_fail(path, k, "uncompressed size " + std::to_string(get64(data + 40)) + ", expected " +
                                std::to_string(raw_size) + " for " + std::to_string(e.link_count) + " links");
    const uint8_t* payload = data + kChunkHeaderSize;
    if (checksum(payload, e.compressed_size) != e.checksum) chunk_fail(path, k, "payload checksum mismatch");

    std::unique_ptr<ZSTD_DCtx, ZstdFree> dctx(ZSTD_createDCtx());
    if (!dctx) throw std::bad_alloc();
    ZSTD_DCtx_setParameter(dctx.get(), ZSTD_d_windowLogMax, kZstdWindowLogMax);
    ZSTD_inBuffer in{payload, e.compressed_size, 0};
    bool frame_done = false;
    // One zstd call; false when it made no progress.
    auto step = [&](ZSTD_outBuffer& o) {
        const size_t in_before = in.pos, out_before = o.pos;
        const size_t r = ZSTD_decompressStream(dctx.get(), &o, &in);
        if (ZSTD_isError(r)) chunk_fail(path, k, std::string("corrupt compressed payload: ") + ZSTD_getErrorName(r));
        frame_done = r == 0;
        return in.pos != in_before || o.pos != out_before;
    };
    const uint32_t node_count = manifest.info.node_count;
    std::vector<uint8_t> planes(std::min<uint64_t>(e.link_count, kBlockLinks) * kRecordSize);
    LinkRecord prev{0, e.source_begin, 0, 0, 0, 0};
    for (uint64_t done = 0; done < e.link_count;) {
        const size_t m = size_t(std::min<uint64_t>(kBlockLinks, e.link_count - done));
        ZSTD_outBuffer o{planes.data(), m * kRecordSize, 0};
        while (o.pos < o.size) {
            const bool progressed = !frame_done && step(o);  // one frame only: none may follow it
            if (o.pos < o.size && (frame_done || !progressed))
                chunk_fail(path, k, "payload decompresses to " + std::to_string(done * kRecordSize + o.pos) +
                                        " bytes, expected " + std::to_string(raw_size));
        }
        decode_block(planes.data(), m, prev, out + done);
        for (size_t i = 0; i < m; ++i) {
            const LinkRecord* before = done + i > 0 ? &out[done + i - 1] : nullptr;
            if (record_ok(out[done + i], before, node_count)) continue;
            chunk_fail(path, k, record_name(done + i, out[done + i]) + ": " + record_problem(out[done + i], before, node_count));
        }
        done += m;
    }
    // Every expected byte is out: the frame must end here, with nothing after it.
    while (!frame_done) {
        uint8_t extra;
        ZSTD_outBuffer o{&extra, 1, 0};
        const bool progressed = step(o);
        if (o.pos > 0) chunk_fail(path, k, "payload decompresses to more than " + std::to_string(raw_size) + " bytes");
        if (!frame_done && !progressed) chunk_fail(path, k, "compressed payload ends in the middle of its frame");
    }
    if (in.pos != in.size)
        chunk_fail(path, k, std::to_string(in.size - in.pos) + " bytes after the end of the compressed payload");
}

void write_file_synced(const std::string& path, const uint8_t* data, size_t size) {
    Fd fd(::open(path.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644));
    if (fd.fd < 0) throw_os(path, "cannot create");
    write_all(fd.fd, data, size, path);
    if (::fsync(fd.fd) != 0) throw_os(path, "fsync failed");
    fd.close(path);
}

void commit_file(const std::string& path, const uint8_t* data, size_t size) {
    const std::string tmp = path + ".tmp";
    write_file_synced(tmp, data, size);
    rename_file(tmp, path);
    const size_t slash = path.find_last_of('/');
    fsync_dir(slash == std::string::npos ? "." : (slash == 0 ? "/" : path.substr(0, slash)));
}

// ---------------------------------------------------------------------------------------------
// Writer

LinkStoreWriter::LinkStoreWriter(const std::string& dir, const LinkStoreInfo& info) : dir_(dir), info_(info) {
    if (info.element_count > info.node_count)
        throw std::invalid_argument(dir + ": element count " + std::to_string(info.element_count) + " > node count " +
                                    std::to_string(info.node_count));
    std::error_code ec;
    fs::create_directories(dir, ec);
    if (ec) throw std::runtime_error(dir + ": cannot create the store directory: " + ec.message());
    if (!fs::is_directory(dir, ec)) throw std::runtime_error(dir + ": not a directory");
    std::vector<std::string> old;
    bool has_manifest = false;
    for (const auto& entry : fs::directory_iterator(dir, ec)) {
        const std::string name = entry.path().filename().string();
        if (!entry.is_regular_file() || !is_store_file(name))
            throw std::runtime_error(dir + ": not a link store (it holds '" + name +
                                     "'); refusing to write a store there");
        if (name == kManifestName)
            has_manifest = true;
        else
            old.push_back(name);
    }
    if (ec) throw std::runtime_error(dir + ": cannot list the directory: " + ec.message());
    // The old manifest goes first, durably: from then on no crash can leave it in place
    // beside chunks of the new store.
    if (has_manifest) {
        remove_file(dir_ + "/" + kManifestName);
        fsync_dir(dir_);
    }
    for (const std::string& name : old) remove_file(dir_ + "/" + name);
    if (!old.empty()) fsync_dir(dir_);
}

void LinkStoreWriter::write_chunk(uint32_t source_begin, uint32_t source_end, const LinkRecord* links, size_t count) {
    const std::string what = dir_ + ": write_chunk [" + std::to_string(source_begin) + ", " +
                             std::to_string(source_end) + "): ";
    if (source_begin >= source_end) throw std::invalid_argument(what + "the group range is empty");
    if (count > kMaxLinksPerChunk)
        throw std::invalid_argument(what + std::to_string(count) + " links, more than the maximum " +
                                    std::to_string(kMaxLinksPerChunk));
    std::vector<LinkRecord> sorted(links, links + count);
    std::sort(sorted.begin(), sorted.end(), [](const LinkRecord& a, const LinkRecord& b) {
        return a.source != b.source ? a.source < b.source : a.receiver < b.receiver;
    });
    for (size_t i = 0; i < count; ++i) {
        const std::string problem =
            record_problem(sorted[i], i ? &sorted[i - 1] : nullptr, info_.node_count);
        if (!problem.empty()) throw std::invalid_argument(what + record_name(i, sorted[i]) + ": " + problem);
    }
    {
        // Reserve the range before writing, so that overlapping concurrent calls are caught.
        std::lock_guard<std::mutex> lock(mutex_);
        if (committed_) throw std::logic_error(what + "the store is already committed");
        for (size_t i = 0; i < count; ++i)
            indices_end_ = std::max({indices_end_, uint64_t(sorted[i].receiver) + 1, uint64_t(sorted[i].source) + 1});
        auto next = slots_.lower_bound(source_begin);
        if ((next != slots_.end() && next->first < source_end) ||
            (next != slots_.begin() && std::prev(next)->second.entry.source_end > source_begin))
            throw std::invalid_argument(what + "overlaps a chunk written before");
        slots_[source_begin].entry.source_end = source_end;
    }
    const std::string path = dir_ + "/" + chunk_file_name(source_begin, source_end);
    const std::string tmp = path + ".tmp";
    try {
        ChunkEntry entry;
        const std::vector<uint8_t> bytes =
            encode_chunk(kUnassignedIndex, source_begin, source_end, sorted.data(), count, entry);
        write_file_synced(tmp, bytes.data(), bytes.size());
        rename_file(tmp, path);
        std::lock_guard<std::mutex> lock(mutex_);
        slots_[source_begin] = {entry, true};
    } catch (...) {
        std::lock_guard<std::mutex> lock(mutex_);
        failed_ = true;
        ::unlink(tmp.c_str());  // best effort: the error being thrown is the one that matters
        throw;
    }
}

void LinkStoreWriter::set_counts(uint32_t node_count, uint32_t element_count) {
    std::lock_guard<std::mutex> lock(mutex_);
    if (node_count < indices_end_ || element_count > node_count)
        throw std::invalid_argument(dir_ + ": node count " + std::to_string(node_count) + " (elements " +
                                    std::to_string(element_count) + ") does not cover the indices written (up to " +
                                    std::to_string(indices_end_) + ")");
    info_.node_count = node_count;
    info_.element_count = element_count;
}

void LinkStoreWriter::commit() {
    std::lock_guard<std::mutex> lock(mutex_);
    if (committed_) throw std::logic_error(dir_ + ": the store is already committed");
    if (failed_) throw std::runtime_error(dir_ + ": cannot commit: a write_chunk failed");
    LinkStoreManifest manifest{info_, {}};
    for (const auto& [begin, slot] : slots_) {
        if (!slot.written) throw std::logic_error(dir_ + ": commit while a write_chunk is still running");
        // The chunk's position is known only now: write it into the header (and its checksum).
        const uint32_t index = uint32_t(manifest.chunks.size());
        const auto header = chunk_header(slot.entry, index);
        const std::string path = dir_ + "/" + chunk_file_name(begin, slot.entry.source_end);
        Fd fd(::open(path.c_str(), O_WRONLY | O_CLOEXEC));
        if (fd.fd < 0) throw_os(path, "cannot open to number the chunk");
        const ssize_t w = ::pwrite(fd.fd, header.data(), header.size(), 0);
        if (w < 0) throw_os(path, "header write failed");
        if (w != ssize_t(header.size())) throw std::runtime_error(path + ": header write failed: short write");
        if (::fsync(fd.fd) != 0) throw_os(path, "fsync failed");
        fd.close(path);
        manifest.chunks.push_back(slot.entry);
    }
    fsync_dir(dir_);  // the chunks' renames are durable before the manifest names them
    const std::vector<uint8_t> bytes = encode_manifest(manifest);
    const std::string path = dir_ + "/" + kManifestName;
    write_file_synced(path + ".tmp", bytes.data(), bytes.size());
    rename_file(path + ".tmp", path);
    fsync_dir(dir_);
    committed_ = true;
}

// ---------------------------------------------------------------------------------------------
// Reader

LinkStoreReader::LinkStoreReader(const std::string& dir) : dir_(dir) {
    std::error_code ec;
    if (!fs::is_directory(dir, ec)) throw std::runtime_error(dir + ": no link store here (not a directory)");
    const std::string path = dir + "/" + kManifestName;
    if (!fs::exists(path, ec))
        throw std::runtime_error(path + ": manifest missing: store at " + dir + " was never committed");
    const std::vector<uint8_t> data =
        read_small_file(path, kManifestHeaderSize + kManifestEntrySize * size_t(kMaxChunks) + 8);
    manifest_ = decode_manifest(data.data(), data.size(), path);
}

std::string LinkStoreReader::chunk_path(size_t k) const {
    const ChunkEntry& e = chunk(k);
    return dir_ + "/" + chunk_file_name(e.source_begin, e.source_end);
}

uint64_t LinkStoreReader::total_links() const {
    uint64_t n = 0;
    for (const ChunkEntry& e : manifest_.chunks) n += e.link_count;
    return n;
}

uint64_t LinkStoreReader::total_compressed_bytes() const {
    uint64_t n = 0;
    for (const ChunkEntry& e : manifest_.chunks) n += e.compressed_size;
    return n;
}

void LinkStoreReader::read_chunk(size_t k, std::vector<LinkRecord>& out) const {
    out.resize(k < chunk_count() ? size_t(chunk(k).link_count) : 0);  // a bad k throws below
    read_chunk(k, out.data(), out.size());
}

size_t LinkStoreReader::read_chunk(size_t k, LinkRecord* out, size_t capacity) const {
    if (k >= chunk_count())
        throw std::out_of_range(dir_ + ": chunk " + std::to_string(k) + " of " + std::to_string(chunk_count()));
    const ChunkEntry& e = chunk(k);
    const std::string path = chunk_path(k);
    if (capacity < e.link_count)
        throw std::invalid_argument(path + ": chunk " + std::to_string(k) + ": a buffer of " +
                                    std::to_string(capacity) + " links is too small for " +
                                    std::to_string(e.link_count));
    Fd fd(::open(path.c_str(), O_RDONLY | O_CLOEXEC));
    if (fd.fd < 0) chunk_fail(path, k, std::string("cannot open: ") + std::strerror(errno));
    struct stat st;
    if (::fstat(fd.fd, &st) != 0) chunk_fail(path, k, std::string("cannot stat: ") + std::strerror(errno));
    // The manifest bounds the size, so nothing larger than it allows is ever allocated.
    const uint64_t expected = kChunkHeaderSize + e.compressed_size;
    if (uint64_t(st.st_size) != expected) chunk_fail(path, k, size_problem(expected, uint64_t(st.st_size)));
    std::vector<uint8_t> data(static_cast<size_t>(expected));
    size_t got = 0;
    while (got < data.size()) {
        const ssize_t r = ::read(fd.fd, data.data() + got, data.size() - got);
        if (r < 0 && errno == EINTR) continue;
        if (r < 0) chunk_fail(path, k, std::string("read failed: ") + std::strerror(errno));
        if (r == 0) chunk_fail(path, k, size_problem(expected, got));
        got += size_t(r);
    }
    decode_chunk(data.data(), data.size(), manifest_, k, path, out);
    return size_t(e.link_count);
}

}  // namespace hirad
