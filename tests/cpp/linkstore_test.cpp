// The on-disk link store: round trips, determinism, corruption of every kind detected with a
// message naming the file, the store's life cycle (commit, re-creation) and write errors.
#include "formats/linkstore.h"

#include <fcntl.h>
#include <grp.h>
#include <gtest/gtest.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>
#define XXH_INLINE_ALL  // header-only: the tests forge checksums to reach deeper checks
#include <xxhash.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <exception>
#include <filesystem>
#include <functional>
#include <fstream>
#include <iterator>
#include <limits>
#include <random>
#include <set>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include "pipeline/core/atomic_file.h"

namespace hirad {
namespace {

namespace fs = std::filesystem;

std::vector<uint8_t> slurp(const fs::path& p) {
    std::ifstream f(p, std::ios::binary);
    return {std::istreambuf_iterator<char>(f), std::istreambuf_iterator<char>()};
}

void spit(const fs::path& p, const std::vector<uint8_t>& bytes) {
    std::ofstream f(p, std::ios::binary | std::ios::trunc);
    f.write(reinterpret_cast<const char*>(bytes.data()), std::streamsize(bytes.size()));
}

void put32(uint8_t* p, uint32_t v) {
    for (int i = 0; i < 4; ++i) p[i] = uint8_t(v >> (8 * i));
}
void put64(uint8_t* p, uint64_t v) {
    for (int i = 0; i < 8; ++i) p[i] = uint8_t(v >> (8 * i));
}

// Rewrites the trailing checksum of a manifest after its bytes were edited.
void reseal_manifest(std::vector<uint8_t>& m) { put64(m.data() + m.size() - 8, XXH3_64bits(m.data(), m.size() - 8)); }

::testing::AssertionResult Contains(const std::string& text, const std::string& part) {
    if (text.find(part) != std::string::npos) return ::testing::AssertionSuccess();
    return ::testing::AssertionFailure() << "\n  message: " << text << "\n  lacks:   " << part;
}

std::string error_of(const std::function<void()>& f) {
    try {
        f();
    } catch (const std::runtime_error& e) {
        return e.what();
    }
    return "(no std::runtime_error)";
}

struct Chunk {
    uint32_t begin, end;
    std::vector<Link> links;  // sorted by source, then receiver
};

bool by_source_receiver(const Link& a, const Link& b) {
    return a.source != b.source ? a.source < b.source : a.receiver < b.receiver;
}

// Distinct random pairs with sources in [begin, end), values spanning many magnitudes and
// the edge cases (zero, negative zero, subnormal, visibility exactly 0 and 1).
std::vector<Link> random_links(std::mt19937_64& rng, uint32_t node_count, uint32_t begin, uint32_t end,
                                     size_t count) {
    std::uniform_int_distribution<uint32_t> src(begin, end - 1), rcv(0, node_count - 1);
    std::uniform_real_distribution<float> u(0, 1);
    std::set<std::pair<uint32_t, uint32_t>> pairs;
    while (pairs.size() < count) pairs.insert({src(rng), rcv(rng)});
    std::vector<Link> links;
    for (const auto& [s, r] : pairs) {
        Link l{r, s, 0, 0, 0, 0};
        l.unoccluded = std::ldexp(u(rng), -int(rng() % 30));
        const int kind = int(rng() % 4);
        l.visibility = kind == 0 ? 1.0f : kind == 1 ? 0.0f : u(rng);
        l.coupling = l.unoccluded * l.visibility;
        l.error = (u(rng) - 0.25f) * 10;
        links.push_back(l);
    }
    links[0].coupling = -0.0f;
    links.back().unoccluded = std::numeric_limits<float>::denorm_min();
    std::sort(links.begin(), links.end(), by_source_receiver);
    return links;
}

constexpr LinkStoreInfo kInfo{0x1234567890abcdefull, 0xfedcba0987654321ull, 1000, 700};

// Chunks of consecutive group ranges (one empty), 1..600 links each.
std::vector<Chunk> make_chunks(size_t n, uint64_t seed) {
    std::mt19937_64 rng(seed);
    std::vector<Chunk> chunks;
    uint32_t begin = 3;
    for (size_t i = 0; i < n; ++i) {
        const uint32_t end = begin + 1 + uint32_t(rng() % 40);
        chunks.push_back({begin, end, i == 2 ? std::vector<Link>{} :
                                                random_links(rng, kInfo.node_count, begin, end, 1 + rng() % 600)});
        begin = end + uint32_t(rng() % 3);  // sometimes a gap: sources without links
    }
    return chunks;
}

// Writes `chunks` in the order `order` from `threads` threads, then commits. A worker's
// exception is rethrown here.
void write_store(const fs::path& dir, const std::vector<Chunk>& chunks, std::vector<size_t> order, int threads) {
    LinkStoreWriter w(dir.string(), kInfo);
    std::atomic<size_t> next{0};
    std::vector<std::exception_ptr> errors(static_cast<size_t>(threads));
    std::vector<std::thread> pool;
    for (int t = 0; t < threads; ++t)
        pool.emplace_back([&, t] {
            try {
                for (size_t i; (i = next++) < order.size();) {
                    const Chunk& c = chunks[order[i]];
                    std::vector<Link> shuffled = c.links;  // the writer must sort
                    std::reverse(shuffled.begin(), shuffled.end());
                    w.write_chunk(c.begin, c.end, shuffled);
                }
            } catch (...) {
                errors[size_t(t)] = std::current_exception();
            }
        });
    for (auto& t : pool) t.join();
    for (const auto& e : errors)
        if (e) std::rethrow_exception(e);
    w.commit();
}

std::vector<size_t> iota(size_t n) {
    std::vector<size_t> v(n);
    for (size_t i = 0; i < n; ++i) v[i] = i;
    return v;
}

bool same_bits(const std::vector<Link>& a, const std::vector<Link>& b) {
    return a.size() == b.size() && (a.empty() || std::memcmp(a.data(), b.data(), a.size() * sizeof(Link)) == 0);
}

class LinkStoreTest : public ::testing::Test {
protected:
    void SetUp() override {
        const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
        dir_ = fs::temp_directory_path() /
               ("hirad_linkstore_" + std::to_string(::getpid()) + "_" + info->test_suite_name() + "_" + info->name());
        fs::remove_all(dir_);
        fs::create_directories(dir_);
    }
    void TearDown() override {
        std::error_code ec;
        fs::permissions(dir_ / "store", fs::perms::owner_all, fs::perm_options::add, ec);
        fs::remove_all(dir_);
    }
    // A committed store of `n` chunks at dir_/store.
    std::vector<Chunk> small_store(size_t n = 3) {
        std::vector<Chunk> chunks = make_chunks(n, 7);
        write_store(store(), chunks, iota(n), 1);
        return chunks;
    }
    fs::path store() const { return dir_ / "store"; }
    fs::path dir_;
};

using LinkStore = LinkStoreTest;
using LinkStoreCorruption = LinkStoreTest;
using LinkStoreWriterChecks = LinkStoreTest;
using LinkStoreLifecycle = LinkStoreTest;
using LinkStoreWriteErrors = LinkStoreTest;

TEST_F(LinkStore, RoundTripOfManyChunksWrittenFromSeveralThreads) {
    const std::vector<Chunk> chunks = make_chunks(40, 1);
    std::vector<size_t> order = iota(chunks.size());
    std::shuffle(order.begin(), order.end(), std::mt19937_64(5));
    write_store(store(), chunks, order, 4);

    LinkStoreReader r(store().string());
    EXPECT_EQ(r.info().scene_fingerprint, kInfo.scene_fingerprint);
    EXPECT_EQ(r.info().config_fingerprint, kInfo.config_fingerprint);
    EXPECT_EQ(r.info().node_count, kInfo.node_count);
    EXPECT_EQ(r.info().element_count, kInfo.element_count);
    ASSERT_EQ(r.chunk_count(), chunks.size());
    uint64_t links = 0, payload = 0;
    for (size_t k = 0; k < chunks.size(); ++k) {
        // Manifest order is by source_begin, whatever the write order.
        EXPECT_EQ(r.chunk(k).source_begin, chunks[k].begin);
        EXPECT_EQ(r.chunk(k).source_end, chunks[k].end);
        links += chunks[k].links.size();
        payload += fs::file_size(r.chunk_path(k)) - kChunkHeaderSize;
    }
    EXPECT_EQ(r.total_links(), links);
    EXPECT_EQ(r.total_compressed_bytes(), payload);

    // Bit-identical, sorted by source then receiver, read concurrently from four threads.
    std::atomic<int> mismatches{0};
    std::vector<std::thread> pool;
    for (int t = 0; t < 4; ++t)
        pool.emplace_back([&, t] {
            std::vector<Link> out;
            for (size_t i = 0; i < chunks.size(); ++i) {
                const size_t k = (i * 7 + size_t(t) * 11) % chunks.size();
                r.read_chunk(k, out);
                if (!same_bits(out, chunks[k].links)) ++mismatches;
            }
        });
    for (auto& t : pool) t.join();
    EXPECT_EQ(mismatches.load(), 0);
}

TEST_F(LinkStore, ReceiverDeltasBeyondSixteenBitsAndReceiverZeroRoundTrip) {
    // Receivers spread over 2^22 nodes: most deltas need an escape; some runs start at
    // receiver 0 (an escaped delta of 0, allowed only first in a run) or have deltas of
    // exactly 65535 and 65536 (the last inline one, the first escaped one).
    constexpr LinkStoreInfo info{1, 2, 1u << 22, 1u << 21};
    std::mt19937_64 rng(3);
    std::vector<Link> links = random_links(rng, info.node_count, 0, 40, 3000);
    for (uint32_t s = 0; s < 40; s += 3) {
        links.push_back({0, s, 0.5f, 0.5f, 1, 0});
        links.push_back({1u << 21, s, 0.25f, 0.5f, 0.5f, 0});
        links.push_back({(1u << 21) + 65535, s, 0.25f, 0.5f, 0.5f, 0});
        links.push_back({(1u << 21) + 2 * 65535 + 1, s, 0.25f, 0.5f, 0.5f, 0});
    }
    std::sort(links.begin(), links.end(), by_source_receiver);
    links.erase(std::unique(links.begin(), links.end(),
                            [](const Link& a, const Link& b) {
                                return a.source == b.source && a.receiver == b.receiver;
                            }),
                links.end());
    LinkStoreWriter w(store().string(), info);
    w.write_chunk(0, 1, links);
    w.commit();
    LinkStoreReader r(store().string());
    EXPECT_GT(r.chunk(0).escape_count, links.size() / 4);
    std::vector<Link> out;
    r.read_chunk(0, out);
    EXPECT_TRUE(same_bits(out, links));
    TransportLinks t;
    r.read_transport(0, t);
    EXPECT_EQ(t.escape_count, r.chunk(0).escape_count);
    const std::vector<uint32_t> receivers = t.receivers();
    ASSERT_EQ(receivers.size(), links.size());
    for (size_t i = 0; i < links.size(); ++i) ASSERT_EQ(receivers[i], links[i].receiver) << i;
}

TEST_F(LinkStore, ReadsIntoTheCallersBuffers) {
    const std::vector<Chunk> chunks = small_store();
    LinkStoreReader r(store().string());
    std::vector<Link> out;
    out.reserve(1000);
    const Link* data = out.data();
    for (size_t k = 0; k < chunks.size(); ++k) {
        r.read_chunk(k, out);
        EXPECT_TRUE(same_bits(out, chunks[k].links));
        EXPECT_EQ(out.data(), data);  // large enough already: not reallocated
    }
    // What a solve reads: the transport section alone, the same links in runs of one source.
    for (size_t k = 0; k < chunks.size(); ++k) {
        TransportLinks t;
        r.read_transport(k, t);
        ASSERT_EQ(t.size(), chunks[k].links.size());
        ASSERT_EQ(t.runs(), r.chunk(k).run_count);
        EXPECT_EQ(t.bytes(),
                  TransportLinks::bytes_for(r.chunk(k).link_count, r.chunk(k).run_count, r.chunk(k).escape_count));
        const std::vector<uint32_t> receivers = t.receivers();
        uint32_t receiver_end = 0;
        for (const Link& l : chunks[k].links) receiver_end = std::max(receiver_end, l.receiver + 1);
        EXPECT_EQ(t.receiver_end, receiver_end);
        for (size_t run = 0, i = 0; run < t.runs(); ++run) {
            ASSERT_GT(t.run_end[run], i);
            for (; i < t.run_end[run]; ++i) {
                const Link& l = chunks[k].links[i];
                EXPECT_EQ(t.sources[run], l.source);
                EXPECT_EQ(receivers[i], l.receiver);
                EXPECT_EQ(std::memcmp(&t.coupling[i], &l.coupling, 4), 0);
            }
            EXPECT_TRUE(run + 1 == t.runs() || t.sources[run + 1] > t.sources[run]);
        }
        EXPECT_EQ(t.run_end.empty() ? 0u : t.run_end.back(), t.size());
    }
    std::vector<Link> raw(chunks[0].links.size() + 5);
    EXPECT_EQ(r.read_chunk(0, raw.data(), raw.size()), chunks[0].links.size());
    raw.resize(chunks[0].links.size());
    EXPECT_TRUE(same_bits(raw, chunks[0].links));
    EXPECT_THROW(r.read_chunk(0, raw.data(), raw.size() - 1), std::invalid_argument);
    EXPECT_THROW(r.read_chunk(chunks.size(), out), std::out_of_range);
}

TEST_F(LinkStore, ManifestAndChunkBytesDoNotDependOnTheWriteOrder) {
    const std::vector<Chunk> chunks = make_chunks(12, 2);
    std::vector<size_t> reverse = iota(chunks.size()), shuffled = iota(chunks.size());
    std::reverse(reverse.begin(), reverse.end());
    std::shuffle(shuffled.begin(), shuffled.end(), std::mt19937_64(9));
    write_store(dir_ / "a", chunks, iota(chunks.size()), 1);
    write_store(dir_ / "b", chunks, reverse, 1);
    write_store(dir_ / "c", chunks, shuffled, 3);
    const std::vector<uint8_t> manifest = slurp(dir_ / "a" / "manifest");
    ASSERT_GT(manifest.size(), 40u);
    for (const char* other : {"b", "c"}) {
        EXPECT_EQ(slurp(dir_ / other / "manifest"), manifest) << other;
        for (const Chunk& c : chunks) {
            const std::string name = chunk_file_name(c.begin, c.end);
            EXPECT_EQ(slurp(dir_ / other / name), slurp(dir_ / "a" / name)) << other << " " << name;
        }
    }
}

TEST_F(LinkStoreCorruption, EveryFlippedChunkByteIsDetected) {
    const std::vector<Chunk> chunks = small_store();
    LinkStoreReader r(store().string());
    const size_t k = 1;
    const fs::path path = r.chunk_path(k);
    const std::vector<uint8_t> good = slurp(path);
    const size_t detail_begin = kChunkHeaderSize + r.chunk(k).transport_size;
    ASSERT_GT(r.chunk(k).transport_size, 100u);
    ASSERT_GT(r.chunk(k).detail_size, 100u);
    std::vector<Link> out;
    TransportLinks t;
    for (size_t i = 0; i < good.size(); ++i) {
        std::vector<uint8_t> bad = good;
        bad[i] ^= uint8_t(1u << (i % 8));
        spit(path, bad);
        const std::string msg = error_of([&] { r.read_chunk(k, out); });
        ASSERT_TRUE(Contains(msg, path.filename().string() + ": chunk 1: ")) << "byte " << i;
        if (i >= 8 && i < 12) EXPECT_TRUE(Contains(msg, "format version"));
        if (i >= 12 && i < kChunkHeaderSize) EXPECT_TRUE(Contains(msg, "header checksum mismatch")) << i;
        if (i >= kChunkHeaderSize && i < detail_begin) EXPECT_TRUE(Contains(msg, "transport checksum mismatch")) << i;
        if (i >= detail_begin) EXPECT_TRUE(Contains(msg, "detail checksum mismatch")) << i;
        // What a solve reads checks the whole file too, though it decodes only the transport.
        const std::string tmsg = error_of([&] { r.read_transport(k, t); });
        ASSERT_TRUE(Contains(tmsg, path.filename().string() + ": chunk 1: ")) << "byte " << i;
        if (i >= detail_begin) EXPECT_TRUE(Contains(tmsg, "detail checksum mismatch")) << i;
    }
    spit(path, good);
    r.read_chunk(k, out);
    EXPECT_TRUE(same_bits(out, chunks[k].links));
}

// A solve reads each chunk many times: the first read checks the whole file, later ones the
// header and the transport section (what they decode) and the file's size.
TEST_F(LinkStoreCorruption, LaterTransportReadsCheckWhatTheyRead) {
    small_store();
    LinkStoreReader r(store().string());
    const size_t k = 1;
    const fs::path path = r.chunk_path(k);
    const std::vector<uint8_t> good = slurp(path);
    const size_t detail_begin = kChunkHeaderSize + r.chunk(k).transport_size;
    TransportLinks t;
    r.read_transport(k, t);  // whole: now known intact
    for (size_t i : {size_t(20), kChunkHeaderSize + 3, detail_begin - 1}) {
        std::vector<uint8_t> bad = good;
        bad[i] ^= 0x40;
        spit(path, bad);
        EXPECT_TRUE(Contains(error_of([&] { r.read_transport(k, t); }), path.filename().string() + ": chunk 1: "))
            << i;
    }
    std::vector<uint8_t> bad = good;
    bad[detail_begin + 2] ^= 0x40;
    spit(path, bad);
    EXPECT_NO_THROW(r.read_transport(k, t));  // not read: the solve does not use it
    EXPECT_TRUE(Contains(error_of([&] { LinkStoreReader(store().string()).read_transport(k, t); }),
                         "detail checksum mismatch"));  // a new reader checks it again
    std::vector<Link> out;
    EXPECT_TRUE(Contains(error_of([&] { r.read_chunk(k, out); }), "detail checksum mismatch"));
    spit(path, std::vector<uint8_t>(good.begin(), good.end() - 1));
    EXPECT_TRUE(Contains(error_of([&] { r.read_transport(k, t); }), "truncated"));
}

TEST_F(LinkStoreCorruption, EveryFlippedManifestByteIsDetected) {
    small_store();
    const fs::path path = store() / "manifest";
    const std::vector<uint8_t> good = slurp(path);
    for (size_t i = 0; i < good.size(); ++i) {
        std::vector<uint8_t> bad = good;
        bad[i] ^= 0x10;
        spit(path, bad);
        ASSERT_TRUE(Contains(error_of([&] { LinkStoreReader r(store().string()); }), path.string() + ": "))
            << "byte " << i;
    }
}

TEST_F(LinkStoreCorruption, TruncatedOrExtendedChunk) {
    small_store();
    LinkStoreReader r(store().string());
    const fs::path path = r.chunk_path(0);
    const std::vector<uint8_t> good = slurp(path);
    std::vector<Link> out;
    for (size_t size : {size_t(0), size_t(10), kChunkHeaderSize, good.size() - 1}) {
        spit(path, std::vector<uint8_t>(good.begin(), good.begin() + long(size)));
        EXPECT_TRUE(Contains(error_of([&] { r.read_chunk(0, out); }),
                             path.string() + ": chunk 0: truncated: expected " + std::to_string(good.size()) +
                             " bytes, found " + std::to_string(size)));
    }
    TransportLinks t;
    spit(path, std::vector<uint8_t>(good.begin(), good.end() - 1));
    EXPECT_TRUE(Contains(error_of([&] { r.read_transport(0, t); }), path.string() + ": chunk 0: truncated"));
    std::vector<uint8_t> longer = good;
    longer.push_back(0);
    spit(path, longer);
    EXPECT_TRUE(Contains(error_of([&] { r.read_chunk(0, out); }), "too long"));
    EXPECT_TRUE(Contains(error_of([&] { r.read_transport(0, t); }), "too long"));
    fs::remove(path);
    EXPECT_TRUE(Contains(error_of([&] { r.read_chunk(0, out); }), path.string() + ": chunk 0: cannot open"));
}

TEST_F(LinkStoreCorruption, ManifestEntryThatDisagreesWithTheChunkHeader) {
    const std::vector<Chunk> chunks = small_store();
    const std::string manifest_path = (store() / "manifest").string();
    const std::vector<uint8_t> bytes = slurp(manifest_path);
    const LinkStoreManifest good = decode_manifest(bytes.data(), bytes.size(), manifest_path);
    auto expect = [&](LinkStoreManifest m, const std::string& what) {
        spit(manifest_path, encode_manifest(m));
        LinkStoreReader r(store().string());  // a consistent manifest on its own
        std::vector<Link> out;
        EXPECT_TRUE(Contains(error_of([&] { r.read_chunk(1, out); }), r.chunk_path(1) + ": chunk 1: " + what));
    };
    LinkStoreManifest m = good;
    m.chunks[1].link_count -= 1;
    expect(m, "header disagrees with the manifest: link count " + std::to_string(chunks[1].links.size()) +
                  " in the chunk, " + std::to_string(chunks[1].links.size() - 1) + " in the manifest");
    m = good;
    m.chunks[1].transport_checksum ^= 1;
    expect(m, "header disagrees with the manifest: transport checksum");
    m = good;
    m.chunks[1].detail_checksum ^= 1;
    expect(m, "header disagrees with the manifest: detail checksum");
    m = good;
    m.chunks[1].run_count -= 1;
    expect(m, "header disagrees with the manifest: run count");
    // A chunk numbered for another position: drop chunk 0 from the manifest.
    m = good;
    m.chunks.erase(m.chunks.begin());
    spit(manifest_path, encode_manifest(m));
    std::vector<Link> out;
    EXPECT_TRUE(Contains(error_of([&] { LinkStoreReader(store().string()).read_chunk(0, out); }),
                         "chunk index 1 in the chunk, 0 in the manifest"));
}

TEST_F(LinkStoreCorruption, ChunkFilesSwappedWithEachOther) {
    small_store();
    LinkStoreReader r(store().string());
    const std::vector<uint8_t> a = slurp(r.chunk_path(0)), b = slurp(r.chunk_path(1));
    spit(r.chunk_path(0), b);
    spit(r.chunk_path(1), a);
    std::vector<Link> out;
    for (size_t k : {0, 1}) EXPECT_TRUE(Contains(error_of([&] { r.read_chunk(k, out); }), r.chunk_path(k)));
}

// Chunks that pass every checksum but hold invalid records (made with the format layer,
// which does not validate): each is refused with the record and what is wrong.
TEST_F(LinkStoreCorruption, InvalidRecordsInAWellFormedChunk) {
    const uint32_t nodes = 10;
    const Link ok{1, 4, 0.5f, 0.5f, 1.0f, 0.0f};
    struct Case {
        std::vector<Link> links;
        std::string message;
    };
    const float nan = std::numeric_limits<float>::quiet_NaN(), inf = std::numeric_limits<float>::infinity();
    const std::vector<Case> cases = {
        {{ok, {10, 4, 0.5f, 0.5f, 1, 0}}, "link 1 (receiver 10, source 4): receiver index 10 >= node count 10"},
        {{{1, 10, 0.5f, 0.5f, 1, 0}}, "source index 10 >= node count 10"},
        {{{2, 4, 0.5f, 0.5f, 1, 0}, ok}, "sorted by source, then receiver"},
        {{ok, ok}, "without duplicates"},
        {{{1, 4, -1.0f, 0.5f, 1, 0}}, "coupling -1.000000 is not finite"},
        {{{1, 4, 0.5f, inf, 1, 0}}, "unoccluded coupling inf"},
        {{{1, 4, 0.5f, 0.5f, 1.5f, 0}}, "visibility 1.500000 is not in [0, 1]"},
        {{{1, 4, 0.5f, 0.5f, nan, 0}}, "visibility nan"},
        {{{1, 4, 0.5f, 0.5f, 1, nan}}, "error estimate nan is not finite"},
    };
    for (const Case& c : cases) {
        LinkStoreManifest m{{1, 2, nodes, nodes}, {}};
        ChunkEntry e;
        const std::vector<uint8_t> bytes = encode_chunk(0, 4, 6, c.links.data(), c.links.size(), e);
        m.chunks.push_back(e);
        std::vector<Link> out(c.links.size());
        const std::string msg = error_of([&] { decode_chunk(bytes.data(), bytes.size(), m, 0, "x.hlc", out.data()); });
        EXPECT_TRUE(Contains(msg, "x.hlc: chunk 0: link "));
        EXPECT_TRUE(Contains(msg, c.message));
        // The same through the files.
        const fs::path dir = dir_ / "bad";
        fs::create_directories(dir);
        write_file_atomic((dir / chunk_file_name(4, 6)).string(), bytes.data(), bytes.size());
        const std::vector<uint8_t> mb = encode_manifest(m);
        write_file_atomic((dir / "manifest").string(), mb.data(), mb.size());
        const std::string from_file = error_of([&] { LinkStoreReader(dir.string()).read_chunk(0, out); });
        EXPECT_TRUE(Contains(from_file, (dir / chunk_file_name(4, 6)).string() + ": chunk 0: link "));
        EXPECT_TRUE(Contains(from_file, c.message));
    }
}

// Sizes read from a file are checked against hard limits before anything is allocated.
TEST_F(LinkStoreCorruption, ImplausibleManifestsAreRefused) {
    LinkStoreManifest m{{1, 2, 100, 50}, {{0, 10, 5, 2, 40, 30, 0, 0}, {10, 20, 5, 1, 40, 30, 0, 0}}};
    const std::vector<uint8_t> good = encode_manifest(m);
    EXPECT_NO_THROW(decode_manifest(good.data(), good.size(), "m"));
    auto refused = [](std::vector<uint8_t> bytes, const std::string& what) {
        reseal_manifest(bytes);
        const std::string msg = error_of([&] { decode_manifest(bytes.data(), bytes.size(), "m"); });
        EXPECT_EQ(msg.rfind("m: ", 0), 0u) << msg;
        EXPECT_TRUE(Contains(msg, what));
    };
    std::vector<uint8_t> b = good;
    put32(b.data() + 20, 0xffffffff);  // chunk count
    refused(b, "4294967295 chunks, more than the maximum");
    b = good;
    put32(b.data() + 8, kLinkStoreVersion - 1);  // a store of an earlier format
    refused(b, "format version " + std::to_string(kLinkStoreVersion - 1) + ", this reader reads version " +
                   std::to_string(kLinkStoreVersion) + " (a store written by another version of hirad: rebuild it)");
    b = good;
    b[20] = 3;  // three chunks claimed, two present
    refused(b, "truncated: expected 312 bytes, found 224 for 3 chunks");
    b = good;
    put64(b.data() + 40 + 40, uint64_t(1) << 40);  // chunk 0's link count
    refused(b, "chunk 0 (chunk-00000000-0000000a.hlc): 1099511627776 links");
    b = good;
    put64(b.data() + 40 + 56, uint64_t(1) << 40);  // chunk 0's transport section size
    refused(b, "transport section size 1099511627776 impossible");
    b = good;
    put64(b.data() + 40 + 56, 20);  // no more than the 4 coupling bytes of each of its 5 links
    refused(b, "transport section size 20 impossible");
    b = good;
    put64(b.data() + 40 + 64, 0);  // chunk 0's detail section size
    refused(b, "detail section size 0 impossible");
    b = good;
    put32(b.data() + 40 + 48, 6);  // chunk 0's run count: more runs than links
    refused(b, "6 runs impossible for 5 links");
    b = good;
    put32(b.data() + 40 + 52, 6);  // chunk 0's escape count: more escapes than links
    refused(b, "6 escapes: more than the 5 links");
    b = good;
    b[40 + 88 + 32] = 9;  // chunk 1 begins at 9, inside chunk 0
    refused(b, "chunk 1 (chunk-00000009-00000014.hlc): the file name does not match");
    m.chunks[1].source_begin = 9;  // named consistently, still overlapping
    refused(encode_manifest(m), "overlaps");
    m.chunks[1] = {20, 20, 5, 1, 40, 30, 0, 0};
    refused(encode_manifest(m), "group range [20, 20) is empty");
    m.chunks.pop_back();
    m.info.element_count = 101;
    refused(encode_manifest(m), "element count 101 > node count 100");
    EXPECT_TRUE(Contains(error_of([] { decode_manifest(nullptr, 0, "m"); }),
                         "m: truncated: expected 48 bytes, found 0"));
}

TEST_F(LinkStoreWriterChecks, RefusesInvalidLinksAndRanges) {
    LinkStoreWriter w(store().string(), kInfo);
    const Link ok{1, 4, 0.5f, 0.5f, 1.0f, 0.0f};
    auto refused = [&](uint32_t begin, uint32_t end, std::vector<Link> links, const std::string& what) {
        try {
            w.write_chunk(begin, end, links);
            ADD_FAILURE() << "accepted: " << what;
        } catch (const std::invalid_argument& e) {
            EXPECT_TRUE(Contains(e.what(), what));
        }
    };
    refused(4, 6, {ok, {kInfo.node_count, 4, 0.5f, 0.5f, 1, 0}}, "receiver index 1000 >= node count 1000");
    refused(4, 6, {{1, kInfo.node_count, 0.5f, 0.5f, 1, 0}}, "source index 1000 >= node count 1000");
    refused(4, 6, {ok, ok}, "without duplicates");
    refused(4, 6, {{1, 4, std::nanf(""), 0.5f, 1, 0}}, "coupling nan");
    refused(4, 6, {{1, 4, 0.5f, -0.5f, 1, 0}}, "unoccluded coupling -0.5");
    refused(4, 6, {{1, 4, 0.5f, 0.5f, -0.1f, 0}}, "visibility -0.1");
    refused(4, 4, {}, "the group range is empty");
    w.write_chunk(4, 6, {ok});
    refused(5, 8, {}, "overlaps");
    refused(0, 5, {}, "overlaps");
    refused(4, 6, {ok}, "overlaps");
    w.write_chunk(6, 8, {});  // adjacent is fine; refused calls left nothing behind
    w.commit();
    LinkStoreReader r(store().string());
    ASSERT_EQ(r.chunk_count(), 2u);
    std::vector<Link> out;
    r.read_chunk(0, out);
    EXPECT_TRUE(same_bits(out, {ok}));
    EXPECT_THROW(w.commit(), std::logic_error);
    EXPECT_THROW(w.write_chunk(20, 30, {}), std::logic_error);
}

TEST_F(LinkStoreLifecycle, DeletedManifestMeansNeverCommitted) {
    small_store();
    fs::remove(store() / "manifest");
    EXPECT_TRUE(Contains(error_of([&] { LinkStoreReader r(store().string()); }),
                         "manifest missing: store at " + store().string() + " was never committed"));
    EXPECT_TRUE(Contains(error_of([&] { LinkStoreReader r((dir_ / "nowhere").string()); }), "no link store here"));
}

TEST_F(LinkStoreLifecycle, UncommittedStoreIsRefused) {
    const std::vector<Chunk> chunks = make_chunks(3, 4);
    {
        LinkStoreWriter w(store().string(), kInfo);
        for (const Chunk& c : chunks) w.write_chunk(c.begin, c.end, c.links);
    }  // dropped without commit(), as by a crash
    EXPECT_TRUE(fs::exists(store() / chunk_file_name(chunks[0].begin, chunks[0].end)));
    EXPECT_TRUE(Contains(error_of([&] { LinkStoreReader r(store().string()); }), "was never committed"));
}

TEST_F(LinkStoreLifecycle, RecreatingOverACommittedStoreNeverPairsTheOldManifestWithNewChunks) {
    const std::vector<Chunk> old_chunks = small_store();
    const std::vector<Chunk> new_chunks = make_chunks(2, 99);  // the same first range, other links
    ASSERT_EQ(new_chunks[0].begin, old_chunks[0].begin);
    {
        LinkStoreWriter w(store().string(), kInfo);
        // The old store is gone as soon as the writer exists: manifest and chunks.
        EXPECT_TRUE(fs::is_empty(store()));
        EXPECT_TRUE(Contains(error_of([&] { LinkStoreReader r(store().string()); }), "was never committed"));
        w.write_chunk(new_chunks[0].begin, new_chunks[0].end, new_chunks[0].links);
        EXPECT_TRUE(Contains(error_of([&] { LinkStoreReader r(store().string()); }), "was never committed"));
    }  // abandoned half way
    EXPECT_TRUE(Contains(error_of([&] { LinkStoreReader r(store().string()); }), "was never committed"));
    write_store(store(), new_chunks, {1, 0}, 2);  // over the leftovers of the abandoned one
    LinkStoreReader r(store().string());
    ASSERT_EQ(r.chunk_count(), 2u);
    std::vector<Link> out;
    for (size_t k = 0; k < 2; ++k) {
        r.read_chunk(k, out);
        EXPECT_TRUE(same_bits(out, new_chunks[k].links));
    }
}

TEST_F(LinkStoreLifecycle, DirectoryWithOtherFilesIsRefusedAndLeftAlone) {
    fs::create_directories(store());
    spit(store() / "notes.txt", {'h', 'i'});
    spit(store() / "manifest", {'x'});
    EXPECT_TRUE(Contains(error_of([&] { LinkStoreWriter w(store().string(), kInfo); }),
                         store().string() + ": not a link store (it holds 'notes.txt')"));
    EXPECT_TRUE(fs::exists(store() / "notes.txt"));
    EXPECT_TRUE(fs::exists(store() / "manifest"));
}

TEST_F(LinkStoreWriteErrors, DiskFullNamesTheFileAndTheError) {
    // The writer's write loop on a device that is always full (never write_file_atomic on
    // /dev/full: as root, its rename would replace the device node).
    const int fd = ::open("/dev/full", O_WRONLY | O_CLOEXEC);
    if (fd < 0) GTEST_SKIP() << "no /dev/full";
    const std::vector<uint8_t> data(1 << 16, 7);
    EXPECT_TRUE(Contains(error_of([&] { write_all(fd, data.data(), data.size(), "/dev/full"); }),
                         std::string("/dev/full: write failed: ") + std::strerror(ENOSPC)));
    ::close(fd);
}

// Runs `f` in a forked child with the privileges of `nobody` when this process is root (CI
// is), so that permissions bind; returns what `f` returned, or a description of what went
// wrong in the child.
std::string unprivileged(const std::function<std::string()>& f) {
    if (::geteuid() != 0) return f();
    int pipe_fd[2];
    if (::pipe(pipe_fd) != 0) return "pipe failed";
    const pid_t pid = ::fork();
    if (pid < 0) return "fork failed";
    if (pid == 0) {
        ::close(pipe_fd[0]);
        std::string out;
        const uid_t nobody = 65534;
        if (::setgroups(0, nullptr) != 0 || ::setresgid(nobody, nobody, nobody) != 0 ||
            ::setresuid(nobody, nobody, nobody) != 0 || ::geteuid() != nobody)
            out = "could not drop root privileges";
        else
            out = f();
        (void)!::write(pipe_fd[1], out.data(), out.size());
        ::_exit(0);
    }
    ::close(pipe_fd[1]);
    std::string out;
    char buf[4096];
    for (ssize_t r; (r = ::read(pipe_fd[0], buf, sizeof buf)) != 0;) {
        if (r < 0 && errno == EINTR) continue;
        if (r < 0) break;
        out.append(buf, size_t(r));
    }
    ::close(pipe_fd[0]);
    int status = 0;
    ::waitpid(pid, &status, 0);
    if (!WIFEXITED(status) || WEXITSTATUS(status) != 0) return "the unprivileged child failed";
    return out;
}

TEST_F(LinkStoreWriteErrors, UnwritableLocationsNameThePath) {
    // A store whose parent is a regular file.
    spit(dir_ / "plain", {'x'});
    const std::string under_file = (dir_ / "plain" / "store").string();
    EXPECT_TRUE(Contains(error_of([&] { LinkStoreWriter w(under_file, kInfo); }),
                         under_file + ": cannot create the store directory: " + std::strerror(ENOTDIR)));

    // The directory replaced by a file after the writer was made: the chunk fails, then commit.
    const std::vector<Chunk> chunks = make_chunks(1, 3);
    {
        LinkStoreWriter w(store().string(), kInfo);
        fs::remove_all(store());
        spit(store(), {'x'});
        const std::string chunk = (store() / chunk_file_name(chunks[0].begin, chunks[0].end)).string();
        const std::string msg = error_of([&] { w.write_chunk(chunks[0].begin, chunks[0].end, chunks[0].links); });
        EXPECT_TRUE(Contains(msg, chunk + ".")) << msg;  // its temporary
        EXPECT_TRUE(Contains(msg, ".tmp: cannot create: " + std::string(std::strerror(ENOTDIR)))) << msg;
        EXPECT_TRUE(Contains(error_of([&] { w.commit(); }), "cannot commit: a write_chunk failed"));
    }
    fs::remove(store());

    // A store directory the process may not write to: permissions bind only other users, so
    // as root the writes run in a child that has become `nobody`.
    {
        LinkStoreWriter w(store().string(), kInfo);
        fs::permissions(store(), fs::perms::owner_read | fs::perms::owner_exec | fs::perms::group_read |
                                     fs::perms::group_exec | fs::perms::others_read | fs::perms::others_exec);
        const std::string msg = unprivileged([&] {
            return error_of([&] { w.write_chunk(chunks[0].begin, chunks[0].end, chunks[0].links); });
        });
        EXPECT_TRUE(Contains(msg, store().string() + "/chunk-")) << msg;
        EXPECT_TRUE(Contains(msg, ": cannot create: " + std::string(std::strerror(EACCES)))) << msg;
        fs::permissions(store(), fs::perms::owner_all);
    }
    EXPECT_TRUE(fs::is_empty(store()));  // nothing was written, not even a temporary
}

TEST_F(LinkStoreWriteErrors, FailedCommitNamesTheManifestAndCanBeRetried) {
    const std::vector<Chunk> chunks = make_chunks(2, 8);
    LinkStoreWriter w(store().string(), kInfo);
    for (const Chunk& c : chunks) w.write_chunk(c.begin, c.end, c.links);
    fs::create_directories(store() / "manifest");  // the manifest's name taken by a directory
    const std::string msg = error_of([&] { w.commit(); });
    EXPECT_TRUE(Contains(msg, (store() / "manifest").string() + ": cannot rename ")) << msg;
    EXPECT_TRUE(Contains(msg, std::strerror(EISDIR))) << msg;
    fs::remove(store() / "manifest");
    EXPECT_TRUE(Contains(error_of([&] { LinkStoreReader r(store().string()); }), "was never committed"));
    for (const auto& e : fs::directory_iterator(store()))  // the failed manifest's temporary is gone
        EXPECT_FALSE(is_atomic_temporary(e.path().filename().string())) << e.path();
    w.commit();
    EXPECT_EQ(LinkStoreReader(store().string()).total_links(), chunks[0].links.size() + chunks[1].links.size());
}

TEST_F(LinkStoreLifecycle, LeftoverTemporariesAreClearedWithTheOldStore) {
    small_store();
    // What writers killed mid-write leave: this format's temporaries and older ".tmp" ones.
    spit(store() / (chunk_file_name(0, 1) + ".4242-7.tmp"), {'x'});
    spit(store() / "manifest.99-0.tmp", {'x'});
    spit(store() / "manifest.tmp", {'x'});
    LinkStoreWriter w(store().string(), kInfo);
    EXPECT_TRUE(fs::is_empty(store()));
    // A name that only looks like one is not the store's: refused, left alone.
    w.commit();
    spit(store() / "manifest.x-1.tmp", {'x'});
    EXPECT_TRUE(Contains(error_of([&] { LinkStoreWriter w2(store().string(), kInfo); }), "not a link store"));
    EXPECT_TRUE(fs::exists(store() / "manifest.x-1.tmp"));
}

}  // namespace
}  // namespace hirad
