// EXR output: half-float round trip, metadata, and the write-to-temporary-then-rename rule.
#include "formats/exr.h"

#include <OpenEXR/ImfChannelList.h>
#include <OpenEXR/ImfHeader.h>
#include <OpenEXR/ImfInputFile.h>
#include <OpenEXR/ImfStringAttribute.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <stdexcept>
#include <string>
#include <vector>

namespace hirad {
namespace {

namespace fs = std::filesystem;

// A fresh directory per test, removed afterwards.
class ExrTest : public ::testing::Test {
protected:
    void SetUp() override {
        const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
        dir_ = fs::path(::testing::TempDir()) /
               ("hirad_exr_" + std::to_string(::getpid()) + "_" + info->name());
        fs::remove_all(dir_);
        fs::create_directories(dir_);
    }
    void TearDown() override { fs::remove_all(dir_); }
    fs::path dir_;
};

// Values spanning six decades (all normal halves), both signs and exact zero.
std::vector<float> test_image(int w, int h) {
    std::vector<float> rgb(size_t(w) * h * 3);
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x)
            for (int c = 0; c < 3; ++c) {
                const size_t i = (size_t(y) * w + x) * 3 + c;
                rgb[i] = static_cast<float>(std::pow(10.0, -3 + 6.0 * (x + w * y) / (w * h)) * (1 + 0.37 * c));
            }
    rgb[0] = 0.0f;
    rgb[4] = -2.5f;
    return rgb;
}

TEST_F(ExrTest, RoundTripWithinHalfPrecision) {
    const int w = 13, h = 7;  // not square, odd: a transposed or flipped read shows
    const std::vector<float> rgb = test_image(w, h);
    const std::string path = (dir_ / "image.exr").string();
    write_exr_rgb(path, w, h, rgb.data(), {{"hirad:note", "round trip"}});
    int rw = 0, rh = 0;
    std::vector<float> back = read_exr_rgb(path, rw, rh);
    ASSERT_EQ(rw, w);
    ASSERT_EQ(rh, h);
    ASSERT_EQ(back.size(), rgb.size());
    // Half floats keep 11 significant bits: relative error <= 2^-11 ~ 4.9e-4.
    for (size_t i = 0; i < rgb.size(); ++i) EXPECT_NEAR(back[i], rgb[i], 1e-3 * std::fabs(rgb[i])) << i;
    EXPECT_EQ(back[0], 0.0f);
    EXPECT_EQ(back[4], -2.5f);  // exactly representable
}

TEST_F(ExrTest, RowZeroIsTheTopLineAndMetadataIsStored) {
    const int w = 3, h = 2;
    std::vector<float> rgb(w * h * 3, 0.0f);
    rgb[0] = 1.0f;                 // top-left red
    rgb[(1 * w + 2) * 3 + 2] = 4;  // bottom-right blue
    const std::string path = (dir_ / "tiny.exr").string();
    write_exr_rgb(path, w, h, rgb.data(), {{"hirad:scene", "cornell"}, {"hirad:patches", "4500"}});
    Imf::InputFile file(path.c_str());
    const Imath::Box2i dw = file.header().dataWindow();
    EXPECT_EQ(dw.max.x - dw.min.x + 1, w);
    EXPECT_EQ(dw.max.y - dw.min.y + 1, h);
    const auto* scene = file.header().findTypedAttribute<Imf::StringAttribute>("hirad:scene");
    const auto* patches = file.header().findTypedAttribute<Imf::StringAttribute>("hirad:patches");
    ASSERT_NE(scene, nullptr);
    ASSERT_NE(patches, nullptr);
    EXPECT_EQ(scene->value(), "cornell");
    EXPECT_EQ(patches->value(), "4500");
    EXPECT_NE(file.header().channels().findChannel("R"), nullptr);
    EXPECT_NE(file.header().channels().findChannel("G"), nullptr);
    EXPECT_NE(file.header().channels().findChannel("B"), nullptr);
    int rw = 0, rh = 0;
    std::vector<float> back = read_exr_rgb(path, rw, rh);
    EXPECT_EQ(back, rgb);  // 0, 1 and 4 are exact halves
}

TEST_F(ExrTest, PartialFileIsGoneAfterSuccess) {
    const std::vector<float> rgb = test_image(4, 4);
    const fs::path path = dir_ / "done.exr";
    write_exr_rgb(path.string(), 4, 4, rgb.data(), {});
    EXPECT_TRUE(fs::exists(path));
    // Only the finished file is left in the directory (no temporary).
    int entries = 0;
    for (const auto& e : fs::directory_iterator(dir_)) {
        ++entries;
        EXPECT_EQ(e.path().filename(), "done.exr");
    }
    EXPECT_EQ(entries, 1);
}

TEST_F(ExrTest, OverwritesAnExistingFile) {
    const fs::path path = dir_ / "again.exr";
    std::vector<float> a(2 * 2 * 3, 1.0f), b(2 * 2 * 3, 2.0f);
    write_exr_rgb(path.string(), 2, 2, a.data(), {});
    write_exr_rgb(path.string(), 2, 2, b.data(), {});
    int w = 0, h = 0;
    EXPECT_EQ(read_exr_rgb(path.string(), w, h), b);
}

TEST_F(ExrTest, APlantedSymlinkIsReplacedNotWrittenThrough) {
    const fs::path victim = dir_ / "victim.txt", path = dir_ / "page0.exr";
    { std::ofstream(victim) << "precious"; }
    fs::create_symlink(victim, path);
    std::vector<float> a(2 * 2 * 3, 1.0f);
    write_exr_rgb(path.string(), 2, 2, a.data(), {});
    std::ifstream in(victim);
    EXPECT_EQ(std::string((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>()), "precious");
    EXPECT_FALSE(fs::is_symlink(path));
    int w = 0, h = 0;
    EXPECT_EQ(read_exr_rgb(path.string(), w, h), a);
}

TEST_F(ExrTest, NonFiniteOrUnrepresentableValuesAreNeverWritten) {
    const std::string path = (dir_ / "bad.exr").string();
    for (const float bad : {std::nanf(""), INFINITY, -INFINITY, 70000.0f}) {
        SCOPED_TRACE(bad);
        std::vector<float> rgb(3 * 2 * 3, 0.5f);
        rgb[(1 * 3 + 2) * 3 + 1] = bad;  // pixel (2, 1), green
        rgb[(1 * 3 + 2) * 3 + 2] = bad;
        try {
            write_exr_rgb(path, 3, 2, rgb.data(), {});
            ADD_FAILURE() << "no error";
        } catch (const std::invalid_argument& e) {
            EXPECT_NE(std::string(e.what()).find(path + ": 2 values are not finite or beyond half float's range"),
                      std::string::npos) << e.what();
            EXPECT_NE(std::string(e.what()).find("pixel (2, 1) channel G"), std::string::npos) << e.what();
        }
        EXPECT_FALSE(fs::exists(path));
    }
    std::vector<float> edge(3, 65504.0f);  // the largest half is fine
    write_exr_rgb(path, 1, 1, edge.data(), {});
    int w = 0, h = 0;
    EXPECT_EQ(read_exr_rgb(path, w, h), edge);
}

TEST_F(ExrTest, MissingDirectoryThrowsWithThePathAndLeavesNothing) {
    const std::vector<float> rgb = test_image(4, 4);
    const fs::path missing = dir_ / "no" / "such" / "dir";
    const std::string path = (missing / "out.exr").string();
    try {
        write_exr_rgb(path, 4, 4, rgb.data(), {});
        FAIL() << "no exception";
    } catch (const std::runtime_error& e) {
        EXPECT_NE(std::string(e.what()).find(path), std::string::npos) << e.what();
    }
    EXPECT_FALSE(fs::exists(path));
    EXPECT_FALSE(fs::exists(dir_ / "no"));  // nor were directories created (nor temporaries)
}

TEST_F(ExrTest, ReadingAMissingFileThrowsWithThePath) {
    const std::string path = (dir_ / "absent.exr").string();
    int w = 0, h = 0;
    try {
        read_exr_rgb(path, w, h);
        FAIL() << "no exception";
    } catch (const std::runtime_error& e) {
        EXPECT_NE(std::string(e.what()).find(path), std::string::npos) << e.what();
    }
}

TEST_F(ExrTest, EmptyImageIsRejected) {
    const std::string path = (dir_ / "empty.exr").string();
    float dummy[3] = {0, 0, 0};
    EXPECT_THROW(write_exr_rgb(path, 0, 4, dummy, {}), std::invalid_argument);
    EXPECT_FALSE(fs::exists(path));
}

}  // namespace
}  // namespace hirad
