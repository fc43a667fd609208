// libFuzzer target for the link store's validation (formats/linkstore.h): any bytes must end
// in a decode or a std::runtime_error, never in a crash, a sanitizer report or a huge
// allocation. Built and run by `make fuzz`; seeds in corpus/linkstore (make_corpus.cpp).
//
// The first byte picks what the rest is:
//   0  a manifest file
//   1  [u32 manifest size][manifest][chunk file]: the chunk checked as the manifest's chunk 0
//   2  [u32 node count][chunk file] with its section sizes and checksums repaired and a
//      manifest made from its own header, so that mutations get past the checksums to the
//      decompressor and the record checks (with mode 1 alone, almost every mutation stops at
//      a checksum)
// Each chunk is decoded whole and by its transport section alone.
#include <xxhash.h>

#include <cstdint>
#include <stdexcept>
#include <vector>

#include "formats/linkstore.h"

namespace {

using namespace hirad;

uint32_t get32(const uint8_t* p) { return uint32_t(p[0]) | uint32_t(p[1]) << 8 | uint32_t(p[2]) << 16 | uint32_t(p[3]) << 24; }
uint64_t get64(const uint8_t* p) { return get32(p) | uint64_t(get32(p + 4)) << 32; }
void put32(uint8_t* p, uint32_t v) {
    for (int i = 0; i < 4; ++i) p[i] = uint8_t(v >> (8 * i));
}
void put64(uint8_t* p, uint64_t v) {
    for (int i = 0; i < 8; ++i) p[i] = uint8_t(v >> (8 * i));
}

// The harness allocates the output itself, so it keeps it small: up to 1.5 MB.
constexpr uint64_t kMaxFuzzLinks = 1 << 16;

// Both ways a chunk is read: whole, and its header and transport section alone.
void check_chunk(const uint8_t* chunk, size_t size, const LinkStoreManifest& m) {
    if (m.chunks.empty() || m.chunks[0].link_count > kMaxFuzzLinks) return;
    std::vector<Link> out(m.chunks[0].link_count);
    try {
        decode_chunk(chunk, size, m, 0, "fuzz.hlc", out.data());
    } catch (const std::runtime_error&) {
    }
    TransportLinks t;
    try {
        decode_transport(chunk, size, size, m, 0, "fuzz.hlc", t);
    } catch (const std::runtime_error&) {
    }
    // As a later read does: the header and the transport section only.
    const uint64_t prefix = kChunkHeaderSize + m.chunks[0].transport_size;
    if (size < prefix) return;  // the reader checks the file's size first
    decode_transport(chunk, size_t(prefix), size, m, 0, "fuzz.hlc", t);
}

void repaired_chunk(const uint8_t* data, size_t size) {
    if (size < 4 + kChunkHeaderSize) return;
    const uint32_t node_count = get32(data);
    std::vector<uint8_t> chunk(data + 4, data + size);
    uint8_t* h = chunk.data();  // offsets as documented in linkstore.h
    const uint64_t links = get64(h + 24);
    const uint64_t sections = chunk.size() - kChunkHeaderSize;
    if (links > kMaxFuzzLinks || get64(h + 40) > sections) return;
    const uint64_t transport = get64(h + 40), detail = sections - transport;
    put32(h + 12, 0);  // chunk index
    put64(h + 48, detail);
    put64(h + 56, XXH3_64bits(h + kChunkHeaderSize, transport));
    put64(h + 64, XXH3_64bits(h + kChunkHeaderSize + transport, detail));
    put64(h + 72, XXH3_64bits(h, 72));
    LinkStoreManifest m;
    m.info.node_count = node_count;
    m.chunks.push_back({get32(h + 16), get32(h + 20), links, get32(h + 32), transport, detail, get64(h + 56),
                        get64(h + 64), get32(h + 36)});
    // Through the manifest's own validation, as the reader would see it.
    const std::vector<uint8_t> manifest = encode_manifest(m);
    check_chunk(chunk.data(), chunk.size(), decode_manifest(manifest.data(), manifest.size(), "fuzz-manifest"));
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
    if (size < 1) return 0;
    const int mode = data[0] % 3;
    ++data;
    --size;
    try {
        if (mode == 0) {
            decode_manifest(data, size, "fuzz-manifest");
        } else if (mode == 1) {
            if (size < 4 || get32(data) > size - 4) return 0;
            const size_t msize = get32(data);
            const LinkStoreManifest m = decode_manifest(data + 4, msize, "fuzz-manifest");
            check_chunk(data + 4 + msize, size - 4 - msize, m);
        } else {
            repaired_chunk(data, size);
        }
    } catch (const std::runtime_error&) {
        // A clean refusal: what the reader is for. Anything else escapes and is a finding.
    }
    return 0;
}
