#include "formats/linkstore.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <sys/uio.h>
#include <unistd.h>
#include <lz4.h>
#define XXH_STATIC_LINKING_ONLY  // XXH3_state_t on the stack
#include <xxhash.h>
#include <zstd.h>

#include "pipeline/core/atomic_file.h"

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

// The transport section's per-link arrays are read and written in place.
static_assert(__BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__, "the link store needs a little-endian machine");

namespace hirad {
namespace {

namespace fs = std::filesystem;

constexpr char kChunkMagic[8] = {'H', 'R', 'D', 'L', 'I', 'N', 'K', 'C'};
constexpr char kManifestMagic[8] = {'H', 'R', 'D', 'L', 'I', 'N', 'K', 'M'};
constexpr uint32_t kUnassignedIndex = 0xffffffff;
constexpr size_t kManifestHeaderSize = 40;
constexpr size_t kManifestEntrySize = 88;
constexpr size_t kNameSize = 32;
constexpr size_t kDetailBytesPerLink = 12;  // three words per link
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

[[noreturn]] void throw_os(const std::string& path, const std::string& what) { throw_os_error(path, what); }
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
// (The temporaries of files being written, see pipeline/core/atomic_file.h, are left by a
// writer killed mid-write; "<name>.tmp" by writers before them.)
bool is_store_file(const std::string& name) {
    const std::string tmp = ".tmp";
    std::string base = name;
    if (!is_atomic_temporary(name, &base) && name.size() > tmp.size() &&
        name.compare(name.size() - tmp.size(), tmp.size(), tmp) == 0)
        base = name.substr(0, name.size() - tmp.size());
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
    put32(&h[32], e.run_count);
    put32(&h[36], e.escape_count);
    put64(&h[40], e.transport_size);
    put64(&h[48], e.detail_size);
    put64(&h[56], e.transport_checksum);
    put64(&h[64], e.detail_checksum);
    put64(&h[72], checksum(h.data(), 72));
    return h;
}

// Empty if `r` may follow `prev` (null for a chunk's first record), else what is wrong.
// Which group a source belongs to is the engine's to check: the store does not know it.
std::string record_problem(const Link& r, const Link* prev, uint32_t node_count) {
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

std::string record_name(size_t i, const Link& r) {
    return "link " + std::to_string(i) + " (receiver " + std::to_string(r.receiver) + ", source " +
           std::to_string(r.source) + ")";
}

// Byte planes (see the header): `count` words to 4 planes of `count` bytes, and back.
void put_planes(const uint32_t* w, size_t count, uint8_t* out) {
    for (size_t b = 0; b < 4; ++b)
        for (size_t i = 0; i < count; ++i) out[b * count + i] = uint8_t(w[i] >> (8 * b));
}
void get_planes(const uint8_t* in, size_t count, uint32_t* w) {
    const uint8_t *p0 = in, *p1 = in + count, *p2 = in + 2 * count, *p3 = in + 3 * count;
    for (size_t i = 0; i < count; ++i)
        w[i] = uint32_t(p0[i]) | uint32_t(p1[i]) << 8 | uint32_t(p2[i]) << 16 | uint32_t(p3[i]) << 24;
}


// A buffer kept by each thread across chunks, grown but never cleared (decoding writes every
// byte it reads back).
template <class T>
T* scratch(std::unique_ptr<T[]>& buffer, size_t& capacity, size_t n) {
    if (n > capacity) {
        buffer.reset(new T[n]);
        capacity = n;
    }
    return buffer.get();
}

// Two per thread: the file's bytes as read, and a section decompressed.
enum Scratch { kFileBytes, kSectionBytes };
uint8_t* byte_scratch(Scratch which, size_t n) {
    thread_local std::unique_ptr<uint8_t[]> buffer[2];
    thread_local size_t capacity[2] = {0, 0};
    return scratch(buffer[which], capacity[which], std::max<size_t>(n, 1));
}

struct ZstdFree {
    void operator()(ZSTD_CCtx* c) const { ZSTD_freeCCtx(c); }
    void operator()(ZSTD_DCtx* d) const { ZSTD_freeDCtx(d); }
};

// One zstd frame of `raw` bytes, appended to `out`; returns its size.
size_t compress_section(const uint8_t* raw, size_t n, std::vector<uint8_t>& out) {
    thread_local std::unique_ptr<ZSTD_CCtx, ZstdFree> cctx(ZSTD_createCCtx());
    if (!cctx) throw std::bad_alloc();
    const size_t at = out.size();
    out.resize(at + ZSTD_compressBound(n));
    const size_t r = ZSTD_compressCCtx(cctx.get(), out.data() + at, out.size() - at, raw, n, kZstdLevel);
    if (ZSTD_isError(r)) throw std::runtime_error(std::string("zstd compression failed: ") + ZSTD_getErrorName(r));
    out.resize(at + r);
    return r;
}

// The transport section's compressed part: one LZ4 block (it decodes several times faster
// than zstd, and a solve decodes every chunk again in every round), appended to `out`.
size_t compress_lz4(const uint8_t* raw, size_t n, std::vector<uint8_t>& out) {
    const size_t at = out.size();
    out.resize(at + size_t(LZ4_compressBound(int(n))));
    const int r = LZ4_compress_default(reinterpret_cast<const char*>(raw), reinterpret_cast<char*>(out.data() + at),
                                       int(n), int(out.size() - at));
    if (r <= 0) throw std::runtime_error("lz4 compression failed");
    out.resize(at + size_t(r));
    return size_t(r);
}

// The inverse, into `raw`: must give exactly `raw_size` bytes. LZ4's safe decoder never
// reads or writes outside the buffers it is given, whatever the input.
void decompress_lz4(const uint8_t* data, size_t size, void* raw, size_t raw_size, const std::string& path, size_t k) {
    const int r = LZ4_decompress_safe(reinterpret_cast<const char*>(data), static_cast<char*>(raw), int(size),
                                      int(raw_size));
    if (r < 0) chunk_fail(path, k, "corrupt compressed transport section (lz4)");
    if (size_t(r) != raw_size)
        chunk_fail(path, k, "transport section decompresses to " + std::to_string(r) + " bytes, expected " +
                                std::to_string(raw_size));
}

// Decompresses a section that must give exactly `raw_size` bytes into a per-thread buffer.
const uint8_t* decompress_section(const uint8_t* data, size_t size, size_t raw_size, const char* section,
                                  const std::string& path, size_t k) {
    thread_local std::unique_ptr<ZSTD_DCtx, ZstdFree> dctx(ZSTD_createDCtx());
    if (!dctx) throw std::bad_alloc();
    // One byte more than expected, so that a section decompressing to more is seen as such.
    uint8_t* raw = byte_scratch(kSectionBytes, raw_size + 1);
    const size_t r = ZSTD_decompressDCtx(dctx.get(), raw, raw_size + 1, data, size);
    if (ZSTD_isError(r))
        chunk_fail(path, k, std::string("corrupt compressed ") + section + " section: " + ZSTD_getErrorName(r));
    if (r != raw_size)
        chunk_fail(path, k, std::string(section) + " section decompresses to " +
                                (r > raw_size ? "more than " + std::to_string(raw_size)
                                              : std::to_string(r) + " bytes, expected " + std::to_string(raw_size)) +
                                " bytes");
    return raw;
}

// The header of chunk k's file (of `size` bytes, its header at `data`) against the
// manifest, field by field.
void check_header(const uint8_t* data, uint64_t size, const LinkStoreManifest& manifest, size_t k,
                  const std::string& path) {
    if (k >= manifest.chunks.size())
        chunk_fail(path, k, "no such chunk: the manifest lists " + std::to_string(manifest.chunks.size()));
    const ChunkEntry& e = manifest.chunks[k];
    if (e.link_count > kMaxLinksPerChunk || e.run_count > e.link_count || e.escape_count > e.link_count)
        chunk_fail(path, k, "the manifest entry was not validated");
    const uint64_t expected_size = kChunkHeaderSize + e.transport_size + e.detail_size;
    if (size != expected_size) chunk_fail(path, k, size_problem(expected_size, size));
    if (std::memcmp(data, kChunkMagic, 8) != 0) chunk_fail(path, k, "not a link chunk (bad magic)");
    if (get32(data + 8) != kLinkStoreVersion)
        chunk_fail(path, k, "format version " + std::to_string(get32(data + 8)) + ", expected " +
                                std::to_string(kLinkStoreVersion));
    if (checksum(data, 72) != get64(data + 72)) chunk_fail(path, k, "header checksum mismatch");
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
    agree("run count", get32(data + 32), e.run_count);
    agree("escape count", get32(data + 36), e.escape_count);
    agree("transport size", get64(data + 40), e.transport_size);
    agree("detail size", get64(data + 48), e.detail_size);
    agree("transport checksum", get64(data + 56), e.transport_checksum);
    agree("detail checksum", get64(data + 64), e.detail_checksum);
}

void check_detail_checksum(const uint8_t* data, const LinkStoreManifest& manifest, size_t k, const std::string& path) {
    const ChunkEntry& e = manifest.chunks[k];
    if (checksum(data + kChunkHeaderSize + e.transport_size, e.detail_size) != e.detail_checksum)
        chunk_fail(path, k, "detail checksum mismatch");
}

std::string link_name(size_t i, uint32_t receiver, uint32_t source) {
    return "link " + std::to_string(i) + " (receiver " + std::to_string(receiver) + ", source " +
           std::to_string(source) + ")";
}

// The transport section's checksum: the couplings, then the LZ4 block (one pass over
// the section's bytes, wherever the two parts were read to).
uint64_t transport_checksum(const float* coupling, size_t n, const uint8_t* block, size_t block_size) {
    XXH3_state_t state;
    XXH3_64bits_reset(&state);
    XXH3_64bits_update(&state, coupling, 4 * n);
    XXH3_64bits_update(&state, block, block_size);
    return XXH3_64bits_digest(&state);
}

// The first link of a run [begin, stop) of `source` whose receiver is at or past
// `node_count` or does not increase, named (a slow walk, for the error only).
[[noreturn]] void bad_receiver(const TransportLinks& t, size_t begin, size_t stop, size_t first_escape,
                               uint32_t source, uint32_t node_count, const std::string& path, size_t k) {
    const char* const unsorted = "links must be sorted by source, then receiver, without duplicates";
    const uint16_t* dl = t.deltas();
    uint32_t receiver = 0;
    for (size_t i = begin, j = first_escape; i < stop; ++i) {
        const uint32_t d = dl[i] ? dl[i] : (j < t.escape_count ? t.escape(j++) : 0);
        const uint32_t next = receiver + d;
        // Unsigned deltas: a receiver before the previous one wraps around past it.
        if (i > begin && (d == 0 || next < receiver))
            chunk_fail(path, k, link_name(i, next, source) + ": after receiver " + std::to_string(receiver) + ": " +
                                    unsorted);
        if (next >= node_count)
            chunk_fail(path, k, link_name(i, next, source) + ": receiver index " + std::to_string(next) +
                                    " >= node count " + std::to_string(node_count));
        receiver = next;
    }
    chunk_fail(path, k, "runs use more escapes than the chunk's " + std::to_string(t.escape_count));
}

// The transport section of a chunk whose header check_header() accepted, its couplings
// already in out.coupling and its LZ4 block at `block`: checked against its checksum,
// decoded into `out` and validated (runs, index ranges, order, couplings).
void decode_transport_section(const uint8_t* block, const LinkStoreManifest& manifest, size_t k,
                              const std::string& path, TransportLinks& out) {
    const ChunkEntry& e = manifest.chunks[k];
    const size_t n = size_t(e.link_count), m = e.run_count, ne = e.escape_count;
    const size_t block_size = size_t(e.transport_size) - 4 * n;
    if (out.coupling.size() != n) throw std::logic_error("decode_transport_section: couplings not read");
    if (transport_checksum(out.coupling.data(), n, block, block_size) != e.transport_checksum)
        chunk_fail(path, k, "transport checksum mismatch");
    out.escape_count = ne;
    out.packed.resize(2 * ne + n + 4 * m);
    uint16_t none = 0;  // where an empty chunk's block decompresses to (nothing)
    decompress_lz4(block, block_size, out.packed.empty() ? &none : out.packed.data(), 2 * out.packed.size(), path, k);
    const uint8_t* planes = reinterpret_cast<const uint8_t*>(out.packed.data() + 2 * ne + n);
    out.sources.resize(m);
    out.run_end.resize(m);
    get_planes(planes, m, out.sources.data());
    get_planes(planes + 4 * m, m, out.run_end.data());
    const uint32_t node_count = manifest.info.node_count;
    const char* const unsorted = "links must be sorted by source, then receiver, without duplicates";
    const uint16_t* dl = out.deltas();
    uint32_t source = 0;
    uint64_t end = 0;
    size_t escapes = 0;
    uint64_t receiver_end = 0;
    for (size_t r = 0; r < m; ++r) {
        const uint32_t delta = out.sources[r], length = out.run_end[r];
        auto first = [&](uint32_t s) { return "link " + std::to_string(end) + " (source " + std::to_string(s); };
        // Unsigned deltas: a source before the previous one wraps around past it.
        if (r > 0 && (delta == 0 || uint32_t(source + delta) < source))
            chunk_fail(path, k, first(source + delta) + ") after source " + std::to_string(source) + ": " + unsorted);
        source += delta;
        if (source >= node_count)
            chunk_fail(path, k, first(source) + "): source index " + std::to_string(source) + " >= node count " +
                                    std::to_string(node_count));
        if (length == 0) chunk_fail(path, k, first(source) + "): a run of no links");
        if (end + length > n)
            chunk_fail(path, k, first(source) + "): runs hold more than the chunk's " + std::to_string(n) + " links");
        out.sources[r] = source;
        // The run's last receiver is the sum of its deltas (a loop the compiler vectorises),
        // and the largest, since every delta after the first is at least 1: an inline delta
        // is never 0, an escaped one must not be.
        const size_t begin = size_t(end), stop = size_t(end + length);
        uint64_t sum = 0;
        uint32_t zeros = 0;
        for (size_t i = begin; i < stop; ++i) {
            sum += dl[i];
            zeros += uint32_t(dl[i] == 0);
        }
        if (zeros > 0) {
            if (zeros > ne - escapes) bad_receiver(out, begin, stop, escapes, source, node_count, path, k);
            for (size_t j = escapes; j < escapes + zeros; ++j) {
                const uint32_t v = out.escape(j);
                if (v == 0 && !(j == escapes && dl[begin] == 0))
                    bad_receiver(out, begin, stop, escapes, source, node_count, path, k);
                sum += v;
            }
        }
        if (sum >= node_count) bad_receiver(out, begin, stop, escapes, source, node_count, path, k);
        escapes += zeros;
        receiver_end = std::max(receiver_end, sum + 1);
        end = stop;
        out.run_end[r] = uint32_t(end);
    }
    if (end != n)
        chunk_fail(path, k, "runs hold " + std::to_string(end) + " links, the chunk " + std::to_string(n));
    if (escapes != ne)
        chunk_fail(path, k, "runs use " + std::to_string(escapes) + " escapes, the chunk has " + std::to_string(ne));
    out.receiver_end = uint32_t(receiver_end);
    out.packed.resize(2 * ne + n);  // the planes are decoded (the capacity stays)
    // The couplings' bits, checked in one loop the compiler vectorises.
    {
        const float* c = out.coupling.data();
        uint32_t bad = 0;
        for (size_t i = 0; i < n; ++i) {
            // Finite and >= 0 (-0 included): below the bits of +inf, or -0 itself.
            const uint32_t u = bits(c[i]);
            bad |= uint32_t(u >= 0x7f800000u) & uint32_t(u != 0x80000000u);
        }
        if (!bad) return;
    }
    const std::vector<uint32_t> receivers = out.receivers();
    for (size_t r = 0, i = 0; i < n; ++i) {
        while (out.run_end[r] <= i) ++r;
        if (!(std::isfinite(out.coupling[i]) && out.coupling[i] >= 0))
            chunk_fail(path, k, link_name(i, receivers[i], out.sources[r]) + ": coupling " +
                                    std::to_string(out.coupling[i]) + " is not finite and >= 0");
    }
}

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
        put32(p + 48, e.run_count);
        put32(p + 52, e.escape_count);
        put64(p + 56, e.transport_size);
        put64(p + 64, e.detail_size);
        put64(p + 72, e.transport_checksum);
        put64(p + 80, e.detail_checksum);
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
             std::to_string(kLinkStoreVersion) + " (a store written by another version of hirad: rebuild it)");
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
        e.run_count = get32(p + 48);
        e.escape_count = get32(p + 52);
        e.transport_size = get64(p + 56);
        e.detail_size = get64(p + 64);
        e.transport_checksum = get64(p + 72);
        e.detail_checksum = get64(p + 80);
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
        if (e.escape_count > e.link_count)
            fail(where + std::to_string(e.escape_count) + " escapes: more than the " + std::to_string(e.link_count) +
                 " links");
        if (e.run_count > e.link_count || (e.run_count == 0) != (e.link_count == 0))
            fail(where + std::to_string(e.run_count) + " runs impossible for " + std::to_string(e.link_count) +
                 " links");
        const uint64_t stored_raw = 4 * e.link_count;
        const uint64_t frame_raw = 4 * uint64_t(e.escape_count) + 2 * e.link_count + 8 * uint64_t(e.run_count);
        if (e.transport_size <= stored_raw || e.transport_size - stored_raw > uint64_t(LZ4_compressBound(int(frame_raw))))
            fail(where + "transport section size " + std::to_string(e.transport_size) + " impossible for " +
                 std::to_string(e.link_count) + " links");
        if (e.detail_size == 0 || e.detail_size > ZSTD_compressBound(kDetailBytesPerLink * e.link_count))
            fail(where + "detail section size " + std::to_string(e.detail_size) + " impossible for " +
                 std::to_string(e.link_count) + " links");
    }
    return m;
}

void TransportLinks::assign(const Link* links, size_t count) {
    sources.clear();
    run_end.clear();
    coupling.resize(count);
    std::vector<uint16_t> deltas(count);
    std::vector<uint32_t> escaped;
    for (size_t i = 0; i < count; ++i) {
        const bool first = i == 0 || links[i].source != links[i - 1].source;
        if (first) {
            if (i > 0) run_end.push_back(uint32_t(i));
            sources.push_back(links[i].source);
        }
        const uint32_t d = links[i].receiver - (first ? 0 : links[i - 1].receiver);
        deltas[i] = d > 0 && d <= 0xffff ? uint16_t(d) : 0;
        if (deltas[i] == 0) escaped.push_back(d);
        coupling[i] = links[i].coupling;
    }
    if (count > 0) run_end.push_back(uint32_t(count));
    escape_count = escaped.size();
    packed.resize(2 * escape_count + count);
    for (size_t j = 0; j < escape_count; ++j) {
        packed[2 * j] = uint16_t(escaped[j]);
        packed[2 * j + 1] = uint16_t(escaped[j] >> 16);
    }
    std::copy(deltas.begin(), deltas.end(), packed.begin() + 2 * escape_count);
    receiver_end = 0;
    for (size_t i = 0; i < count; ++i) receiver_end = std::max(receiver_end, links[i].receiver + 1);
}

std::vector<uint32_t> TransportLinks::receivers() const {
    std::vector<uint32_t> out(size());
    const uint16_t* dl = deltas();
    for (size_t r = 0, i = 0, j = 0; r < runs(); ++r) {
        uint32_t receiver = 0;
        for (; i < run_end[r]; ++i) out[i] = receiver += dl[i] ? dl[i] : escape(j++);
    }
    return out;
}

std::vector<uint8_t> encode_chunk(uint32_t index, uint32_t source_begin, uint32_t source_end,
                                  const Link* links, size_t count, ChunkEntry& entry) {
    if (count > kMaxLinksPerChunk)
        throw std::invalid_argument("a chunk holds at most " + std::to_string(kMaxLinksPerChunk) + " links, not " +
                                    std::to_string(count));
    TransportLinks t;
    t.assign(links, count);
    const size_t n = count, m = t.runs();
    // The LZ4 block: escapes and deltas as the solver holds them, then the runs as planes.
    std::vector<uint32_t> words(2 * m);
    for (size_t r = 0; r < m; ++r) {
        words[r] = t.sources[r] - (r > 0 ? t.sources[r - 1] : 0);
        words[m + r] = t.run_end[r] - (r > 0 ? t.run_end[r - 1] : 0);
    }
    std::vector<uint8_t> block(2 * t.packed.size() + 8 * m);
    if (!t.packed.empty()) std::memcpy(block.data(), t.packed.data(), 2 * t.packed.size());
    put_planes(words.data(), m, block.data() + 2 * t.packed.size());
    put_planes(words.data() + m, m, block.data() + 2 * t.packed.size() + 4 * m);
    std::vector<uint8_t> out(kChunkHeaderSize + 4 * n);
    if (n > 0) std::memcpy(out.data() + kChunkHeaderSize, t.coupling.data(), 4 * n);
    const size_t block_size = compress_lz4(block.data(), block.size(), out);
    entry.transport_size = 4 * n + block_size;
    words.assign(3 * n, 0);
    for (size_t i = 0; i < n; ++i) {
        words[i] = bits(links[i].unoccluded) ^ bits(links[i].coupling);
        words[n + i] = bits(links[i].visibility);
        words[2 * n + i] = bits(links[i].error);
    }
    std::vector<uint8_t> raw(kDetailBytesPerLink * n);
    for (size_t c = 0; c < 3; ++c) put_planes(words.data() + c * n, n, raw.data() + 4 * c * n);
    entry.detail_size = compress_section(raw.data(), raw.size(), out);
    entry.source_begin = source_begin;
    entry.source_end = source_end;
    entry.link_count = count;
    entry.run_count = uint32_t(m);
    entry.escape_count = uint32_t(t.escape_count);
    entry.transport_checksum = checksum(out.data() + kChunkHeaderSize, entry.transport_size);
    entry.detail_checksum = checksum(out.data() + kChunkHeaderSize + entry.transport_size, entry.detail_size);
    const auto header = chunk_header(entry, index);
    std::copy(header.begin(), header.end(), out.begin());
    return out;
}

void decode_transport(const uint8_t* data, size_t available, uint64_t file_size, const LinkStoreManifest& manifest,
                      size_t k, const std::string& path, TransportLinks& out) {
    check_header(data, file_size, manifest, k, path);
    const ChunkEntry& e = manifest.chunks[k];
    if (available < kChunkHeaderSize + e.transport_size || available > file_size)
        throw std::invalid_argument(path + ": chunk " + std::to_string(k) + ": " + std::to_string(available) +
                                    " bytes given: not the header and the transport section of a file of " +
                                    std::to_string(file_size));
    out.coupling.resize(size_t(e.link_count));
    if (!out.coupling.empty()) std::memcpy(out.coupling.data(), data + kChunkHeaderSize, 4 * out.coupling.size());
    decode_transport_section(data + kChunkHeaderSize + 4 * out.coupling.size(), manifest, k, path, out);
    if (available == file_size) check_detail_checksum(data, manifest, k, path);
}

void decode_chunk(const uint8_t* data, size_t size, const LinkStoreManifest& manifest, size_t k,
                  const std::string& path, Link* out) {
    thread_local TransportLinks t;
    decode_transport(data, size, size, manifest, k, path, t);
    const ChunkEntry& e = manifest.chunks[k];
    const uint8_t* section = data + kChunkHeaderSize + e.transport_size;
    const size_t n = t.size();
    const uint8_t* raw = decompress_section(section, e.detail_size, kDetailBytesPerLink * n, "detail", path, k);
    thread_local std::unique_ptr<uint32_t[]> words_buffer;
    thread_local size_t words_capacity = 0;
    uint32_t* w = scratch(words_buffer, words_capacity, std::max<size_t>(3 * n, 1));
    for (size_t c = 0; c < 3; ++c) get_planes(raw + 4 * c * n, n, w + c * n);
    const uint16_t* dl = t.deltas();
    for (size_t r = 0, i = 0, j = 0; r < t.runs(); ++r) {
        uint32_t receiver = 0;
        for (; i < t.run_end[r]; ++i) {
            Link& o = out[i];
            o.receiver = receiver += dl[i] ? dl[i] : t.escape(j++);
            o.source = t.sources[r];
            o.coupling = t.coupling[i];
            o.unoccluded = from_bits(w[i] ^ bits(o.coupling));
            o.visibility = from_bits(w[n + i]);
            o.error = from_bits(w[2 * n + i]);
            if (!(std::isfinite(o.unoccluded) && o.unoccluded >= 0 && o.visibility >= 0 && o.visibility <= 1 &&
                  std::isfinite(o.error)))
                chunk_fail(path, k, link_name(i, o.receiver, o.source) + ": " +
                                        record_problem(o, nullptr, manifest.info.node_count));
        }
    }
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
        fsync_directory(dir_);
    }
    for (const std::string& name : old) remove_file(dir_ + "/" + name);
    if (!old.empty()) fsync_directory(dir_);
}

void LinkStoreWriter::write_chunk(uint32_t source_begin, uint32_t source_end, const Link* links, size_t count) {
    const std::string what = dir_ + ": write_chunk [" + std::to_string(source_begin) + ", " +
                             std::to_string(source_end) + "): ";
    if (source_begin >= source_end) throw std::invalid_argument(what + "the group range is empty");
    if (count > kMaxLinksPerChunk)
        throw std::invalid_argument(what + std::to_string(count) + " links, more than the maximum " +
                                    std::to_string(kMaxLinksPerChunk));
    std::vector<Link> sorted(links, links + count);
    std::sort(sorted.begin(), sorted.end(), [](const Link& a, const Link& b) {
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
    try {
        ChunkEntry entry;
        const std::vector<uint8_t> bytes =
            encode_chunk(kUnassignedIndex, source_begin, source_end, sorted.data(), count, entry);
        // The directory is fsynced once, by commit(), before the manifest names the chunks.
        AtomicFile::Options options;
        options.sync_directory = false;
        write_file_atomic(path, bytes.data(), bytes.size(), options);
        std::lock_guard<std::mutex> lock(mutex_);
        slots_[source_begin] = {entry, true};
    } catch (...) {
        std::lock_guard<std::mutex> lock(mutex_);
        failed_ = true;
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
        Fd fd(::open(path.c_str(), O_WRONLY | O_NOFOLLOW | O_CLOEXEC));
        if (fd.fd < 0) throw_os(path, "cannot open to number the chunk");
        const ssize_t w = ::pwrite(fd.fd, header.data(), header.size(), 0);
        if (w < 0) throw_os(path, "header write failed");
        if (w != ssize_t(header.size())) throw std::runtime_error(path + ": header write failed: short write");
        if (::fsync(fd.fd) != 0) throw_os(path, "fsync failed");
        fd.close(path);
        manifest.chunks.push_back(slot.entry);
    }
    fsync_directory(dir_);  // the chunks' renames are durable before the manifest names them
    const std::vector<uint8_t> bytes = encode_manifest(manifest);
    write_file_atomic(dir_ + "/" + kManifestName, bytes.data(), bytes.size());
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
    verified_.reset(new std::atomic<bool>[manifest_.chunks.size()]);
    for (size_t k = 0; k < manifest_.chunks.size(); ++k) verified_[k].store(false);
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
    for (const ChunkEntry& e : manifest_.chunks) n += e.compressed_size();
    return n;
}

uint64_t LinkStoreReader::total_transport_bytes() const {
    uint64_t n = 0;
    for (const ChunkEntry& e : manifest_.chunks) n += e.transport_size;
    return n;
}

namespace {

// Chunk k's file opened, its size checked against the manifest before anything is read (so
// nothing larger than the manifest allows is ever allocated).
int open_chunk(const std::string& path, size_t k, const ChunkEntry& e) {
    const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
    if (fd < 0) chunk_fail(path, k, std::string("cannot open: ") + std::strerror(errno));
    struct stat st;
    const uint64_t expected = kChunkHeaderSize + e.compressed_size();
    if (::fstat(fd, &st) != 0) {
        const int err = errno;
        ::close(fd);
        chunk_fail(path, k, std::string("cannot stat: ") + std::strerror(err));
    }
    if (uint64_t(st.st_size) != expected) {
        ::close(fd);
        chunk_fail(path, k, size_problem(expected, uint64_t(st.st_size)));
    }
    return fd;
}

// Fills the buffers from the start of the file, in order (short reads resumed).
void read_fully(int fd, iovec* iov, int count, const std::string& path, size_t k, const ChunkEntry& e) {
    off_t at = 0;
    while (count > 0) {
        const ssize_t r = ::preadv(fd, iov, count, at);
        if (r < 0 && errno == EINTR) continue;
        if (r < 0) chunk_fail(path, k, std::string("read failed: ") + std::strerror(errno));
        if (r == 0) chunk_fail(path, k, size_problem(kChunkHeaderSize + e.compressed_size(), uint64_t(at)));
        at += r;
        for (size_t left = size_t(r); left > 0 && count > 0;) {
            const size_t step = std::min(left, iov->iov_len);
            iov->iov_base = static_cast<uint8_t*>(iov->iov_base) + step;
            iov->iov_len -= step;
            left -= step;
            if (iov->iov_len == 0) ++iov, --count;
        }
        while (count > 0 && iov->iov_len == 0) ++iov, --count;
    }
}

// Chunk k's whole file into a per-thread buffer.
const uint8_t* read_chunk_file(const std::string& path, size_t k, const ChunkEntry& e, size_t& size) {
    Fd fd(open_chunk(path, k, e));
    size = size_t(kChunkHeaderSize + e.compressed_size());
    uint8_t* data = byte_scratch(kFileBytes, size);
    iovec iov{data, size};
    read_fully(fd.fd, &iov, 1, path, k, e);
    return data;
}

}  // namespace

void LinkStoreReader::read_chunk(size_t k, std::vector<Link>& out) const {
    out.resize(k < chunk_count() ? size_t(chunk(k).link_count) : 0);  // a bad k throws below
    read_chunk(k, out.data(), out.size());
}

size_t LinkStoreReader::read_chunk(size_t k, Link* out, size_t capacity) const {
    if (k >= chunk_count())
        throw std::out_of_range(dir_ + ": chunk " + std::to_string(k) + " of " + std::to_string(chunk_count()));
    const ChunkEntry& e = chunk(k);
    const std::string path = chunk_path(k);
    if (capacity < e.link_count)
        throw std::invalid_argument(path + ": chunk " + std::to_string(k) + ": a buffer of " +
                                    std::to_string(capacity) + " links is too small for " +
                                    std::to_string(e.link_count));
    size_t size = 0;
    const uint8_t* data = read_chunk_file(path, k, e, size);
    decode_chunk(data, size, manifest_, k, path, out);
    verified_[k].store(true, std::memory_order_relaxed);
    return size_t(e.link_count);
}

void LinkStoreReader::read_transport(size_t k, TransportLinks& out) const {
    if (k >= chunk_count())
        throw std::out_of_range(dir_ + ": chunk " + std::to_string(k) + " of " + std::to_string(chunk_count()));
    const ChunkEntry& e = chunk(k);
    const std::string path = chunk_path(k);
    const bool whole = !verified_[k].load(std::memory_order_relaxed);
    Fd fd(open_chunk(path, k, e));
    // One read: the header, the couplings straight into `out`, the LZ4 block (and the detail
    // section the first time) into a per-thread buffer.
    const size_t n = size_t(e.link_count), block = size_t(e.transport_size) - 4 * n;
    const size_t tail = block + (whole ? size_t(e.detail_size) : 0);
    uint8_t header[kChunkHeaderSize];
    out.coupling.resize(n);
    uint8_t* rest = byte_scratch(kFileBytes, tail);
    iovec iov[3] = {{header, kChunkHeaderSize}, {out.coupling.data(), 4 * n}, {rest, tail}};
    read_fully(fd.fd, iov, 3, path, k, e);
    fd.close(path);
    check_header(header, kChunkHeaderSize + e.compressed_size(), manifest_, k, path);
    decode_transport_section(rest, manifest_, k, path, out);
    if (whole) {
        if (checksum(rest + block, size_t(e.detail_size)) != e.detail_checksum)
            chunk_fail(path, k, "detail checksum mismatch");
        verified_[k].store(true, std::memory_order_relaxed);
    }
}

}  // namespace hirad
