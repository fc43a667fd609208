#include "formats/statefile.h"

#include <xxhash.h>

#include <cstring>
#include <fstream>
#include <iterator>
#include <memory>
#include <stdexcept>

#include "pipeline/core/atomic_file.h"

namespace hirad {

namespace {

constexpr char kMagic[8] = {'H', 'R', 'D', 'S', 'T', 'A', 'T', 'E'};
constexpr uint32_t kVersion = 1;
enum Type : uint32_t { kU32 = 1, kF64 = 2, kU64 = 3 };

template <typename T>
void append(std::vector<uint8_t>& out, const T& v) {
    const size_t at = out.size();
    out.resize(at + sizeof(T));
    std::memcpy(out.data() + at, &v, sizeof(T));  // little-endian host (x86-64, aarch64)
}

struct Cursor {
    const uint8_t* p;
    size_t left;
    const std::string& path;
    void need(size_t n, const char* what) const {
        if (n > left) throw std::runtime_error(path + ": truncated state file (reading " + what + ")");
    }
    template <typename T>
    T get(const char* what) {
        need(sizeof(T), what);
        T v;
        std::memcpy(&v, p, sizeof(T));
        p += sizeof(T);
        left -= sizeof(T);
        return v;
    }
};

template <typename T>
const std::vector<T>& find(const std::map<std::string, std::vector<T>>& m, const std::string& name,
                           const std::string& path) {
    auto it = m.find(name);
    if (it == m.end()) throw std::runtime_error(path + ": state file has no array '" + name + "'");
    return it->second;
}

}  // namespace

const std::vector<uint32_t>& StateFile::u32(const std::string& name) const { return find(u32_, name, path_); }
const std::vector<uint64_t>& StateFile::u64(const std::string& name) const { return find(u64_, name, path_); }
const std::vector<double>& StateFile::f64(const std::string& name) const { return find(f64_, name, path_); }

// Every byte of the file but the checksum, in order, to `put(data, size)`: the arrays by type
// then name, owned and borrowed f64 arrays alike.
template <typename Put>
void StateFile::emit(Put&& put) const {
    auto put_value = [&](const auto& v) { put(&v, sizeof(v)); };  // little-endian host (x86-64, aarch64)
    std::map<std::string, std::pair<const void*, size_t>> f64;
    for (const auto& [name, a] : f64_) f64[name] = {a.data(), a.size()};
    for (const auto& [name, v] : f64_views_) f64[name] = v;
    put(kMagic, 8);
    put_value(kVersion);
    put_value(static_cast<uint32_t>(u32_.size() + u64_.size() + f64.size()));
    put_value(fingerprint);
    auto put_array = [&](const std::string& name, uint32_t type, const void* data, size_t count, size_t size) {
        put_value(static_cast<uint32_t>(name.size()));
        put(name.data(), name.size());
        put_value(type);
        put_value(static_cast<uint64_t>(count));
        if (count > 0) put(data, count * size);
    };
    for (const auto& [name, a] : u32_) put_array(name, kU32, a.data(), a.size(), sizeof(uint32_t));
    for (const auto& [name, a] : u64_) put_array(name, kU64, a.data(), a.size(), sizeof(uint64_t));
    for (const auto& [name, v] : f64) put_array(name, kF64, v.first, v.second, sizeof(double));
}

std::vector<uint8_t> StateFile::encode() const {
    std::vector<uint8_t> out;
    emit([&](const void* data, size_t size) {
        const auto* b = static_cast<const uint8_t*>(data);
        out.insert(out.end(), b, b + size);
    });
    append(out, static_cast<uint64_t>(XXH3_64bits(out.data(), out.size())));
    return out;
}

// The same bytes as encode(), written as they are hashed: a checkpoint of the streaming solver
// holds the solver's state once (its arrays here, or borrowed: put_view), not once more as one
// encoded buffer (on the 1M-triangle kitchen about 360 MB more at every checkpoint).
void StateFile::write(const std::string& path) const {
    AtomicFile file(path);
    std::unique_ptr<XXH3_state_t, XXH_errorcode (*)(XXH3_state_t*)> hash(XXH3_createState(), XXH3_freeState);
    if (!hash || XXH3_64bits_reset(hash.get()) != XXH_OK) throw std::runtime_error(path + ": cannot start a checksum");
    emit([&](const void* data, size_t size) {
        XXH3_64bits_update(hash.get(), data, size);
        file.write(data, size);
    });
    const uint64_t sum = XXH3_64bits_digest(hash.get());
    file.write(&sum, sizeof(sum));
    file.commit();
}

StateFile StateFile::decode(const uint8_t* data, size_t size, const std::string& path) {
    StateFile f;
    f.path_ = path;
    if (size < 8 + 4 + 4 + 8 + 8 || std::memcmp(data, kMagic, 8) != 0)
        throw std::runtime_error(path + ": not a hirad state file (bad magic or too short)");
    uint64_t stored;
    std::memcpy(&stored, data + size - 8, 8);
    if (stored != XXH3_64bits(data, size - 8)) throw std::runtime_error(path + ": state file checksum mismatch");
    Cursor c{data + 8, size - 16, path};
    const uint32_t version = c.get<uint32_t>("version");
    if (version != kVersion)
        throw std::runtime_error(path + ": state file version " + std::to_string(version) + ", expected " +
                                 std::to_string(kVersion));
    const uint32_t arrays = c.get<uint32_t>("array count");
    f.fingerprint = c.get<uint64_t>("fingerprint");
    for (uint32_t k = 0; k < arrays; ++k) {
        const uint32_t len = c.get<uint32_t>("a name length");
        c.need(len, "a name");
        std::string name(reinterpret_cast<const char*>(c.p), len);
        c.p += len;
        c.left -= len;
        const uint32_t type = c.get<uint32_t>("a type");
        const uint64_t count = c.get<uint64_t>("an element count");
        const size_t width = type == kU32 ? 4 : (type == kF64 || type == kU64) ? 8 : 0;
        if (width == 0) throw std::runtime_error(path + ": array '" + name + "' has unknown type " + std::to_string(type));
        if (count > c.left / width) throw std::runtime_error(path + ": truncated state file (array '" + name + "')");
        auto take = [&](auto& vec) {
            vec.resize(count);
            if (count) std::memcpy(vec.data(), c.p, count * width);
            c.p += count * width;
            c.left -= count * width;
        };
        if (type == kU32) take(f.u32_[name]);
        else if (type == kU64) take(f.u64_[name]);
        else take(f.f64_[name]);
    }
    if (c.left != 0) throw std::runtime_error(path + ": state file has trailing bytes");
    return f;
}

StateFile StateFile::read(const std::string& path) {
    std::ifstream in(path, std::ios::binary);
    if (!in) throw std::runtime_error(path + ": cannot open the state file");
    std::vector<uint8_t> bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    if (in.bad()) throw std::runtime_error(path + ": read error");
    return decode(bytes.data(), bytes.size(), path);
}

}  // namespace hirad
