// The one atomic file write (pipeline/core/atomic_file.h): the file is replaced whole or not
// at all, the temporary is exclusive and never follows a link, errors name the file, and
// nothing is left behind.
#include "pipeline/core/atomic_file.h"

#include <gtest/gtest.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <filesystem>
#include <functional>
#include <fstream>
#include <iterator>
#include <string>
#include <vector>

namespace hirad {
namespace {

namespace fs = std::filesystem;

std::string slurp(const fs::path& p) {
    std::ifstream in(p, std::ios::binary);
    return std::string((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
}

void spit(const fs::path& p, const std::string& s) {
    std::ofstream out(p, std::ios::binary);
    out << s;
}

std::string error_of(const std::function<void()>& f) {
    try {
        f();
    } catch (const std::exception& e) {
        return e.what();
    }
    return "(no exception)";
}

class AtomicFileTest : public ::testing::Test {
protected:
    void SetUp() override {
        const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
        dir_ = fs::temp_directory_path() / ("hirad_atomic_" + std::to_string(::getpid()) + "_" + info->name());
        fs::remove_all(dir_);
        fs::create_directories(dir_);
    }
    void TearDown() override { fs::remove_all(dir_); }
    std::vector<std::string> entries() const {
        std::vector<std::string> out;
        for (const auto& e : fs::directory_iterator(dir_)) out.push_back(e.path().filename().string());
        std::sort(out.begin(), out.end());
        return out;
    }
    fs::path dir_;
};

TEST_F(AtomicFileTest, WritesAndReplacesLeavingOnlyTheFile) {
    const fs::path path = dir_ / "out.bin";
    write_file_atomic(path.string(), "first", 5);
    EXPECT_EQ(slurp(path), "first");
    write_file_atomic(path.string(), "second!", 7);
    EXPECT_EQ(slurp(path), "second!");
    EXPECT_EQ(entries(), std::vector<std::string>{"out.bin"});
    write_file_atomic(path.string(), "", 0);  // empty is a valid content
    EXPECT_EQ(fs::file_size(path), 0u);
}

TEST_F(AtomicFileTest, TheTargetChangesOnlyAtCommit) {
    const fs::path path = dir_ / "state";
    spit(path, "old");
    {
        AtomicFile f(path.string());
        f.write("new", 3);
        EXPECT_EQ(slurp(path), "old");  // a reader still sees the old file whole
        EXPECT_TRUE(fs::exists(f.temporary()));
        std::string target;
        EXPECT_TRUE(is_atomic_temporary(fs::path(f.temporary()).filename().string(), &target));
        EXPECT_EQ(target, "state");
        f.commit();
        EXPECT_FALSE(fs::exists(f.temporary()));
    }
    EXPECT_EQ(slurp(path), "new");
    {
        AtomicFile f(path.string());
        f.write("abandoned", 9);
    }  // dropped without commit, as by an exception
    EXPECT_EQ(slurp(path), "new");
    EXPECT_EQ(entries(), std::vector<std::string>{"state"});
}

TEST_F(AtomicFileTest, ASymlinkAtThePathIsReplacedNotFollowed) {
    const fs::path victim = dir_ / "victim";
    spit(victim, "precious");
    const fs::path path = dir_ / "out";
    fs::create_symlink(victim, path);
    write_file_atomic(path.string(), "result", 6);
    EXPECT_EQ(slurp(victim), "precious");
    EXPECT_FALSE(fs::is_symlink(path));
    EXPECT_EQ(slurp(path), "result");
}

TEST_F(AtomicFileTest, APlantedTemporaryIsNeverOpenedNorFollowed) {
    const fs::path victim = dir_ / "victim";
    spit(victim, "precious");
    const fs::path path = dir_ / "out";
    // Learn the naming from one temporary, then plant a link at the next name it will use.
    std::string used;
    {
        AtomicFile probe(path.string());
        used = probe.temporary();
    }
    const std::string prefix = path.string() + "." + std::to_string(::getpid()) + "-";
    ASSERT_EQ(used.compare(0, prefix.size(), prefix), 0) << used;
    const uint64_t n = std::stoull(used.substr(prefix.size()));
    const std::string next = prefix + std::to_string(n + 1) + ".tmp";
    fs::create_symlink(victim, next);
    const std::string msg = error_of([&] { write_file_atomic(path.string(), "result", 6); });
    EXPECT_NE(msg.find(next + ": cannot create: " + std::strerror(EEXIST)), std::string::npos) << msg;
    EXPECT_EQ(slurp(victim), "precious");
    EXPECT_TRUE(fs::is_symlink(next));  // left as it was
    EXPECT_FALSE(fs::exists(path));
    // The next write takes the next name and succeeds.
    write_file_atomic(path.string(), "result", 6);
    EXPECT_EQ(slurp(path), "result");
}

TEST_F(AtomicFileTest, FailuresNameThePathAndLeaveNothing) {
    const fs::path missing = dir_ / "no" / "such" / "out";
    std::string msg = error_of([&] { write_file_atomic(missing.string(), "x", 1); });
    EXPECT_NE(msg.find(missing.string() + "."), std::string::npos) << msg;
    EXPECT_NE(msg.find(std::strerror(ENOENT)), std::string::npos) << msg;
    EXPECT_FALSE(fs::exists(dir_ / "no"));

    // The target is a directory: the rename fails, the directory and its contents survive.
    const fs::path taken = dir_ / "taken";
    fs::create_directories(taken);
    spit(taken / "inside", "keep");
    msg = error_of([&] { write_file_atomic(taken.string(), "x", 1); });
    EXPECT_NE(msg.find(taken.string() + ": cannot rename "), std::string::npos) << msg;
    EXPECT_NE(msg.find(std::strerror(EISDIR)), std::string::npos) << msg;
    EXPECT_EQ(slurp(taken / "inside"), "keep");
    EXPECT_EQ(entries(), std::vector<std::string>{"taken"});

    EXPECT_NE(error_of([&] { write_file_atomic(dir_.string() + "/", "x", 1); }).find("not a file name"),
              std::string::npos);
    msg = error_of([&] { fsync_directory((dir_ / "absent").string()); });
    EXPECT_NE(msg.find((dir_ / "absent").string() + ": cannot open the directory"), std::string::npos) << msg;
}

TEST_F(AtomicFileTest, ModeIsTheRequestedOne) {
    const fs::path path = dir_ / "private";
    AtomicFile::Options options;
    options.mode = 0600;
    write_file_atomic(path.string(), "x", 1, options);
    struct stat st;
    ASSERT_EQ(::stat(path.c_str(), &st), 0);
    EXPECT_EQ(st.st_mode & 0777, 0600u);
}

TEST(AtomicTemporaryNames, OnlyTheWritersOwnPattern) {
    std::string target;
    EXPECT_TRUE(is_atomic_temporary("manifest.12-0.tmp", &target));
    EXPECT_EQ(target, "manifest");
    EXPECT_TRUE(is_atomic_temporary("/a/b/page0.exr.7-123.tmp", &target));
    EXPECT_EQ(target, "/a/b/page0.exr");
    for (const char* other : {"manifest.tmp", "manifest.12.tmp", "manifest.-1.tmp", "manifest.1-.tmp",
                              "manifest.x-1.tmp", ".1-2.tmp", "manifest.1-2.tmpx", "manifest.1-2"})
        EXPECT_FALSE(is_atomic_temporary(other)) << other;
}

TEST(ParentDirectory, OfBareNamesRootAndPaths) {
    EXPECT_EQ(parent_directory("file"), ".");
    EXPECT_EQ(parent_directory("/file"), "/");
    EXPECT_EQ(parent_directory("/a/b/file"), "/a/b");
    EXPECT_EQ(parent_directory("a/file"), "a");
}

}  // namespace
}  // namespace hirad
