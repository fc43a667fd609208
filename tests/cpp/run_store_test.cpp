// RunStore::open on a directory an earlier run left: its own names and their temporaries go
// (those of pipeline/core/atomic_file.h, "<name>.<pid>-<n>.tmp", and older "<name>.tmp"),
// every other file stays; keep_earlier (resume, reuse links) removes nothing.
#include "pipeline/outofcore/run_store.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

namespace hirad {
namespace {

namespace fs = std::filesystem;

class RunStoreOpen : public ::testing::Test {
protected:
    void SetUp() override {
        const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
        dir_ = fs::temp_directory_path() / ("hirad_run_store_" + std::to_string(::getpid()) + "_" + info->name());
        fs::remove_all(dir_);
        fs::create_directories(dir_ / "round-2");
        for (const char* name : {"round-2/manifest", "refined-1", "solved-1", "final", "checkpoint",
                                 "refined-2.4242-7.tmp", "final.17-0.tmp", "checkpoint.tmp",  // ours
                                 "notes.tmp", "mine.txt", "final.x-1.tmp", "result.12-3.tmp"})  // not ours
            std::ofstream(dir_ / name) << "x";
    }
    void TearDown() override { fs::remove_all(dir_); }

    std::vector<std::string> names() const {
        std::vector<std::string> out;
        for (const auto& e : fs::directory_iterator(dir_)) out.push_back(e.path().filename().string());
        std::sort(out.begin(), out.end());
        return out;
    }

    fs::path dir_;
};

TEST_F(RunStoreOpen, ClearsItsOwnFilesAndTemporariesOnly) {
    RunStore(dir_.string(), StoreFingerprints{}, 1).open(false);
    EXPECT_EQ(names(), (std::vector<std::string>{"final.x-1.tmp", "mine.txt", "notes.tmp", "result.12-3.tmp"}));
}

TEST_F(RunStoreOpen, KeepsEverythingWhenAskedTo) {
    const std::vector<std::string> before = names();
    RunStore(dir_.string(), StoreFingerprints{}, 1).open(true);
    EXPECT_EQ(names(), before);
    EXPECT_EQ(before.size(), 12u);  // 11 files and the round-2 directory
}

}  // namespace
}  // namespace hirad
