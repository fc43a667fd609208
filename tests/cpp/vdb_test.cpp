// OpenVDB round trip of the irradiance volume writer/reader (formats/vdb.h).
#include <gtest/gtest.h>

#include <cstdio>
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
