// State files: round trip of every array type, and every byte of a file flipped or cut off is
// detected with the file named.
#include "formats/statefile.h"

#include "pipeline/core/atomic_file.h"

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <iterator>
#include <stdexcept>
#include <string>

namespace hirad {
namespace {

StateFile sample() {
    StateFile f;
    f.fingerprint = 0x1234ABCDull;
    f.put("log", std::vector<uint32_t>{3, 1, 4, 1, 5});
    f.put("counters", std::vector<uint64_t>{uint64_t(1) << 40, 7});
    f.put("radiosity", std::vector<double>{0.5, -1e-300, 3.25});
    f.put("empty", std::vector<double>{});
    return f;
}

TEST(StateFile, RoundTripsThroughAFile) {
    const std::string path = (std::filesystem::temp_directory_path() / "hirad_statefile_test").string();
    sample().write(path);
    for (const auto& e : std::filesystem::directory_iterator(std::filesystem::temp_directory_path())) {
        std::string target;  // no temporary of this file is left beside it
        if (is_atomic_temporary(e.path().string(), &target)) EXPECT_NE(target, path) << e.path();
    }
    StateFile g = StateFile::read(path);
    EXPECT_EQ(g.fingerprint, 0x1234ABCDull);
    EXPECT_EQ(g.u32("log"), (std::vector<uint32_t>{3, 1, 4, 1, 5}));
    EXPECT_EQ(g.u64("counters"), (std::vector<uint64_t>{uint64_t(1) << 40, 7}));
    EXPECT_EQ(g.f64("radiosity"), (std::vector<double>{0.5, -1e-300, 3.25}));
    EXPECT_TRUE(g.f64("empty").empty());
    EXPECT_FALSE(g.has("missing"));
    // write() streams the file as it hashes it: the bytes are encode()'s, one for one
    std::ifstream in(path, std::ios::binary);
    const std::vector<uint8_t> written((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    EXPECT_EQ(written, sample().encode());
    try {
        g.u32("missing");
        FAIL() << "an absent array was returned";
    } catch (const std::runtime_error& e) {
        EXPECT_NE(std::string(e.what()).find(path), std::string::npos);
    }
    std::filesystem::remove(path);
}

// An array borrowed with put_view (a checkpoint's RGB arrays, written where they are) is the
// same file, byte for byte, as the array copied in, among the owned arrays in name order; read
// back it is an owned array; put and put_view of one name replace each other.
TEST(StateFile, BorrowedArraysWriteTheSameBytesAsCopiedOnes) {
    struct Three { double x, y, z; };  // as RGB is laid out
    const std::vector<Three> rgb{{0.5, -1e-300, 3.25}};
    StateFile f;
    f.fingerprint = 0x1234ABCDull;
    f.put("log", std::vector<uint32_t>{3, 1, 4, 1, 5});
    f.put("counters", std::vector<uint64_t>{uint64_t(1) << 40, 7});
    f.put("radiosity", std::vector<double>{9.0});   // replaced by the view below
    f.put_view("radiosity", rgb.data(), 3);
    f.put_view("empty", nullptr, 0);
    f.put("empty", std::vector<double>{});          // and this replaces the empty view
    EXPECT_EQ(f.encode(), sample().encode());
    const std::string path = (std::filesystem::temp_directory_path() / "hirad_statefile_view_test").string();
    f.write(path);
    std::ifstream in(path, std::ios::binary);
    const std::vector<uint8_t> written((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    EXPECT_EQ(written, sample().encode());
    EXPECT_EQ(StateFile::read(path).f64("radiosity"), (std::vector<double>{0.5, -1e-300, 3.25}));
    std::filesystem::remove(path);
}

TEST(StateFile, EveryFlippedByteAndEveryTruncationIsDetected) {
    const std::vector<uint8_t> good = sample().encode();
    for (size_t i = 0; i < good.size(); ++i) {
        std::vector<uint8_t> bad = good;
        bad[i] ^= 0x01;
        EXPECT_THROW(StateFile::decode(bad.data(), bad.size(), "f"), std::runtime_error) << "byte " << i;
    }
    for (size_t n = 0; n < good.size(); ++n)
        EXPECT_THROW(StateFile::decode(good.data(), n, "f"), std::runtime_error) << "length " << n;
    try {
        std::vector<uint8_t> bad = good;
        bad[good.size() / 2] ^= 0x80;
        StateFile::decode(bad.data(), bad.size(), "/some/state");
        FAIL();
    } catch (const std::runtime_error& e) {
        EXPECT_NE(std::string(e.what()).find("/some/state: state file checksum mismatch"), std::string::npos);
    }
}

}  // namespace
}  // namespace hirad
