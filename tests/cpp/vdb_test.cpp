// OpenVDB round trip of the irradiance volume writer/reader (formats/vdb.h).
#include <gtest/gtest.h>

#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <stdexcept>
#include <string>

#include "formats/vdb.h"

using namespace hirad;

TEST(Vdb, WritesAndReadsNamedVec3GridsWithMetadata) {
    const std::string path = ::testing::TempDir() + "hirad_vdb_test.vdb";
    VdbGrid a;
    a.name = "irradiance";
    a.voxel_size = 0.25;
    a.origin = {1.0, -2.0, 0.5};
    a.coords = {{0, 0, 0}, {3, -1, 2}, {-5, 7, 1}};
    a.values = {{1, 2, 3}, {0.5f, 0.25f, 0.125f}, {4, 5, 6}};
    a.metadata = {{"units", "W/m^2"}, {"spacing", "0.25"}};
    VdbGrid b = a;
    b.name = "direction";
    b.values = {{0, 1, 0}, {1, 0, 0}, {0, 0, -1}};
    write_vdb(path, {a, b}, {{"hirad:version", "test"}});

    Metadata file_meta;
    std::vector<VdbGrid> got = read_vdb(path, file_meta);
    ASSERT_EQ(got.size(), 2u);
    bool version = false;
    for (auto& [k, v] : file_meta) version |= (k == "hirad:version" && v == "test");
    EXPECT_TRUE(version);
    for (const VdbGrid& g : got) {
        const VdbGrid& want = g.name == "irradiance" ? a : b;
        ASSERT_TRUE(g.name == "irradiance" || g.name == "direction");
        EXPECT_DOUBLE_EQ(g.voxel_size, 0.25);
        for (int c = 0; c < 3; ++c) EXPECT_NEAR(g.origin[c], a.origin[c], 1e-12);
        ASSERT_EQ(g.coords.size(), 3u);
        for (size_t k = 0; k < want.coords.size(); ++k) {
            size_t j = 0;
            while (j < g.coords.size() && g.coords[j] != want.coords[k]) ++j;
            ASSERT_LT(j, g.coords.size());
            for (int c = 0; c < 3; ++c) EXPECT_FLOAT_EQ(g.values[j][c], want.values[k][c]);
        }
        bool units = false;
        for (auto& [k, v] : g.metadata) units |= (k == "units" && v == "W/m^2");
        EXPECT_TRUE(units);
    }
    std::remove(path.c_str());
}

TEST(Vdb, MissingFileThrows) {
    Metadata m;
    EXPECT_THROW(read_vdb("/nonexistent/hirad.vdb", m), std::exception);
}

// The file goes through the one atomic write: a symlink planted at the output is replaced,
// its target untouched; an unwritable place is an error naming the path, leaving nothing.
TEST(Vdb, ReplacesAPlantedSymlinkWithoutWritingThroughIt) {
    namespace fs = std::filesystem;
    const fs::path dir = fs::path(::testing::TempDir()) / ("hirad_vdb_link_" + std::to_string(::getpid()));
    fs::remove_all(dir);
    fs::create_directories(dir);
    const fs::path victim = dir / "victim.txt", out = dir / "volume.vdb";
    { std::ofstream(victim) << "precious"; }
    fs::create_symlink(victim, out);
    VdbGrid g;
    g.name = "irradiance";
    g.coords = {{1, 2, 3}};
    g.values = {{0.5f, 1.5f, 2.5f}};
    write_vdb(out.string(), {g}, {});
    std::ifstream in(victim);
    std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    EXPECT_EQ(text, "precious");
    EXPECT_FALSE(fs::is_symlink(out));
    Metadata m;
    const std::vector<VdbGrid> back = read_vdb(out.string(), m);
    ASSERT_EQ(back.size(), 1u);
    ASSERT_EQ(back[0].values.size(), 1u);
    EXPECT_EQ(back[0].values[0][2], 2.5f);
    size_t entries = 0;
    for (auto it = fs::directory_iterator(dir); it != fs::directory_iterator(); ++it) ++entries;
    EXPECT_EQ(entries, 2u);  // victim and volume: no temporary

    const std::string missing = (dir / "no" / "volume.vdb").string();
    try {
        write_vdb(missing, {g}, {});
        ADD_FAILURE() << "no exception";
    } catch (const std::runtime_error& e) {
        EXPECT_NE(std::string(e.what()).find(missing), std::string::npos) << e.what();
    }
    fs::remove_all(dir);
}

TEST(Vdb, NonFiniteValuesAreNeverWritten) {
    namespace fs = std::filesystem;
    const std::string path = ::testing::TempDir() + "hirad_vdb_nan_" + std::to_string(::getpid()) + ".vdb";
    VdbGrid g;
    g.name = "irradiance";
    g.coords = {{0, 0, 0}, {4, 5, 6}};
    g.values = {{1, 1, 1}, {0.5f, std::nanf(""), 0.5f}};
    try {
        write_vdb(path, {g}, {});
        ADD_FAILURE() << "no error";
    } catch (const std::invalid_argument& e) {
        EXPECT_NE(std::string(e.what()).find("voxel (4, 5, 6) holds a value that is not finite"), std::string::npos)
            << e.what();
    }
    EXPECT_FALSE(fs::exists(path));
}
