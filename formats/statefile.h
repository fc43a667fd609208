// State files: a few named arrays, checksummed and replaced atomically. They hold what the
// out-of-core pipeline needs to resume or reuse work beside its link store: the hierarchy's
// subdivision log, each round's radiosity, the solver's checkpoints.
//
// Layout (little-endian): magic "HRDSTATE", u32 version, u32 array count, u64 fingerprint;
// per array: u32 name length, the name, u32 type (1 u32, 2 f64, 3 u64), u64 element count,
// the elements; then XXH3_64 of every byte before it.
#pragma once
#include <cstdint>
#include <map>
#include <string>
#include <utility>
#include <vector>

namespace hirad {

class StateFile {
public:
    uint64_t fingerprint = 0;   // what the state belongs to (scene, settings), checked by the reader

    void put(const std::string& name, std::vector<uint32_t> values) { u32_[name] = std::move(values); }
    void put(const std::string& name, std::vector<uint64_t> values) { u64_[name] = std::move(values); }
    void put(const std::string& name, std::vector<double> values) {
        f64_views_.erase(name);
        f64_[name] = std::move(values);
    }
    // An f64 array the caller keeps, written from where it is: `count` doubles' bytes at `data`
    // (a vector of RGB, say), which must outlive encode() and write(). A checkpoint of a
    // 10M-triangle solve borrows its ~2 GB of state rather than copying it. A file that is
    // read back has the array as an owned one.
    void put_view(const std::string& name, const void* data, size_t count) {
        f64_.erase(name);
        f64_views_[name] = {data, count};
    }

    // The named array; throws std::runtime_error naming the file if it is absent.
    const std::vector<uint32_t>& u32(const std::string& name) const;
    const std::vector<uint64_t>& u64(const std::string& name) const;
    const std::vector<double>& f64(const std::string& name) const;
    bool has(const std::string& name) const { return u32_.count(name) || u64_.count(name) || f64_.count(name); }

    std::vector<uint8_t> encode() const;
    void write(const std::string& path) const;   // atomically (write_file_atomic)

    // Validates everything (magic, version, sizes, checksum); errors name `path`.
    static StateFile decode(const uint8_t* data, size_t size, const std::string& path);
    static StateFile read(const std::string& path);

private:
    std::string path_;  // where it was read from, for messages
    std::map<std::string, std::vector<uint32_t>> u32_;
    std::map<std::string, std::vector<uint64_t>> u64_;
    std::map<std::string, std::vector<double>> f64_;
    std::map<std::string, std::pair<const void*, size_t>> f64_views_;

    template <typename Put>
    void emit(Put&& put) const;
};

}  // namespace hirad
