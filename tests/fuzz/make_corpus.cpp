// Writes the fuzz target's seed corpus (the inputs are described in linkstore_fuzz.cpp):
// valid manifests and chunks in each mode, and a few broken ones.
//
// From the repository root:
//   g++ -std=c++17 -I. tests/fuzz/make_corpus.cpp formats/linkstore.cpp -lzstd -llz4 -lxxhash -o build/fuzz/make_corpus
//   build/fuzz/make_corpus tests/fuzz/corpus/linkstore
#include <cstdio>
#include <cstdlib>
#include <string>
#include <vector>

#include "formats/linkstore.h"

using namespace hirad;

namespace {

using Bytes = std::vector<uint8_t>;

// Links of the sources [begin, end) as refinement makes them: each source linked to a run
// of receivers, couplings falling off smoothly, a few partly visible.
std::vector<Link> links(uint32_t begin, uint32_t end, uint32_t per_source) {
    std::vector<Link> out;
    for (uint32_t s = begin; s < end; ++s)
        for (uint32_t r = 0; r < per_source; ++r) {
            const float g = 1.0f / float(1 + r + s);
            const float v = (r + s) % 7 == 0 ? 0.5f : 1.0f;
            out.push_back({20 + 3 * r, s, g * v, g, v, g * 0.01f});
        }
    return out;
}

Bytes concat(std::initializer_list<Bytes> parts) {
    Bytes out;
    for (const Bytes& p : parts) out.insert(out.end(), p.begin(), p.end());
    return out;
}

Bytes u32(uint32_t v) { return {uint8_t(v), uint8_t(v >> 8), uint8_t(v >> 16), uint8_t(v >> 24)}; }

void save(const std::string& dir, const char* name, const Bytes& b) {
    const std::string path = dir + "/" + name;
    FILE* f = std::fopen(path.c_str(), "wb");
    if (!f || std::fwrite(b.data(), 1, b.size(), f) != b.size() || std::fclose(f) != 0) {
        std::perror(path.c_str());
        std::exit(1);
    }
}

}  // namespace

int main(int argc, char** argv) {
    if (argc != 2) {
        std::fprintf(stderr, "usage: %s CORPUS_DIR\n", argv[0]);
        return 2;
    }
    const std::string dir = argv[1];
    const uint32_t nodes = 200;
    LinkStoreManifest m{{11, 22, nodes, 150}, {}};
    ChunkEntry e0, e1, e2;
    const std::vector<Link> l0 = links(0, 8, 12), l1 = links(8, 10, 5);
    const Bytes c0 = encode_chunk(0, 0, 8, l0.data(), l0.size(), e0);
    const Bytes c1 = encode_chunk(1, 8, 10, l1.data(), l1.size(), e1);
    const Bytes empty = encode_chunk(0, 10, 12, nullptr, 0, e2);
    m.chunks = {e0, e1};
    const Bytes manifest = encode_manifest(m);
    const Bytes manifest0 = encode_manifest({m.info, {}});

    Bytes flipped = manifest;
    flipped[30] ^= 4;
    std::vector<Link> out_of_range = l1;
    out_of_range[3].receiver = nodes + 5;
    ChunkEntry ignored;
    const Bytes c_bad = encode_chunk(0, 8, 10, out_of_range.data(), out_of_range.size(), ignored);
    Bytes c_garbled = c1;
    c_garbled[kChunkHeaderSize + 8] ^= 0x5a;  // inside the LZ4 block

    save(dir, "manifest_valid", concat({{0}, manifest}));
    save(dir, "manifest_no_chunks", concat({{0}, manifest0}));
    save(dir, "manifest_flipped", concat({{0}, flipped}));
    save(dir, "pair_valid", concat({{1}, u32(uint32_t(manifest.size())), manifest, c0}));
    save(dir, "pair_truncated", concat({{1}, u32(uint32_t(manifest.size())), manifest, Bytes(c0.begin(), c0.end() - 9)}));
    save(dir, "chunk_valid", concat({{2}, u32(nodes), c1}));
    save(dir, "chunk_empty", concat({{2}, u32(nodes), empty}));
    save(dir, "chunk_receiver_out_of_range", concat({{2}, u32(nodes), c_bad}));
    save(dir, "chunk_garbled_payload", concat({{2}, u32(nodes), c_garbled}));
    return 0;
}
