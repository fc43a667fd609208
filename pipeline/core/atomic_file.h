// The one way the engine replaces a file: write a temporary beside it, fsync it, rename it
// over the target, fsync the directory. A reader sees the old file or the new one, never a
// partial one, and after a crash the rename is durable once commit() has returned.
//
// The temporary, "<path>.<pid>-<n>.tmp", is created exclusively (O_CREAT | O_EXCL |
// O_NOFOLLOW): it is never an existing file and never a link planted under that name, so a
// write can follow no symlink into someone else's file; the rename replaces `path` itself
// (a symlink at `path` is replaced, its target is left alone). Two writers of one path each
// have their own temporary; the last rename wins. Errors are std::runtime_error naming the
// file, what failed and the OS error; an uncommitted temporary is removed.
//
// Header-only (inline), so that formats/ and the fuzz build use it without another source.
#pragma once
#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <stdexcept>
#include <string>

namespace hirad {

[[noreturn]] inline void throw_os_error(const std::string& path, const std::string& what, int err = errno) {
    throw std::runtime_error(path + ": " + what + ": " + std::strerror(err));
}

// Writes all of `data` at the file offset (short writes resumed, EINTR retried).
inline void write_all(int fd, const void* data, size_t size, const std::string& path) {
    const char* p = static_cast<const char*>(data);
    while (size > 0) {
        const ssize_t w = ::write(fd, p, size);
        if (w < 0 && errno == EINTR) continue;
        if (w < 0) throw_os_error(path, "write failed");
        if (w == 0) throw std::runtime_error(path + ": write failed: no progress");
        p += w;
        size -= size_t(w);
    }
}

// The same at offset `at`, leaving the file offset alone.
inline void pwrite_all(int fd, const void* data, size_t size, uint64_t at, const std::string& path) {
    const char* p = static_cast<const char*>(data);
    while (size > 0) {
        const ssize_t w = ::pwrite(fd, p, size, off_t(at));
        if (w < 0 && errno == EINTR) continue;
        if (w < 0) throw_os_error(path, "write failed");
        if (w == 0) throw std::runtime_error(path + ": write failed: no progress");
        p += w;
        at += uint64_t(w);
        size -= size_t(w);
    }
}

// The directory holding `path` ("." for a bare name, "/" for a file in the root).
inline std::string parent_directory(const std::string& path) {
    const size_t slash = path.find_last_of('/');
    if (slash == std::string::npos) return ".";
    return slash == 0 ? "/" : path.substr(0, slash);
}

inline void fsync_directory(const std::string& dir) {
    const int fd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
    if (fd < 0) throw_os_error(dir, "cannot open the directory to fsync it");
    if (::fsync(fd) != 0) {
        const int err = errno;
        ::close(fd);
        throw_os_error(dir, "fsync of the directory failed", err);
    }
    ::close(fd);
}

// Whether `name` (a file name or a path) is one of AtomicFile's temporaries; `target`
// receives the name it was to replace.
inline bool is_atomic_temporary(const std::string& name, std::string* target = nullptr) {
    const std::string suffix = ".tmp";
    if (name.size() <= suffix.size() || name.compare(name.size() - suffix.size(), suffix.size(), suffix) != 0)
        return false;
    // <target>.<digits>-<digits>.tmp
    size_t i = name.size() - suffix.size();
    const size_t seq_end = i;
    while (i > 0 && name[i - 1] >= '0' && name[i - 1] <= '9') --i;
    if (i == seq_end || i == 0 || name[i - 1] != '-') return false;
    const size_t pid_end = --i;
    while (i > 0 && name[i - 1] >= '0' && name[i - 1] <= '9') --i;
    if (i == pid_end || i < 2 || name[i - 1] != '.') return false;
    if (target) *target = name.substr(0, i - 1);
    return true;
}

class AtomicFile {
public:
    struct Options {
        mode_t mode = 0644;          // of the new file (less the umask)
        bool sync_directory = true;  // fsync the directory after the rename; a caller that
                                     // renames many files may do it once itself
    };

    explicit AtomicFile(const std::string& path) : AtomicFile(path, Options()) {}
    AtomicFile(const std::string& path, Options options) : path_(path), options_(options) {
        if (path.empty() || path.back() == '/') throw std::runtime_error("'" + path + "': not a file name");
        static std::atomic<uint64_t> sequence{0};
        temporary_ = path + "." + std::to_string(::getpid()) + "-" + std::to_string(sequence.fetch_add(1)) + ".tmp";
        fd_ = ::open(temporary_.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_NOFOLLOW | O_CLOEXEC, options.mode);
        if (fd_ < 0) throw_os_error(temporary_, "cannot create");
    }
    AtomicFile(const AtomicFile&) = delete;
    AtomicFile& operator=(const AtomicFile&) = delete;
    ~AtomicFile() { discard(); }

    const std::string& path() const { return path_; }
    const std::string& temporary() const { return temporary_; }
    int fd() const { return fd_; }  // the temporary, open for writing (for writers that need it)
    bool committed() const { return committed_; }

    // Appends to the temporary.
    void write(const void* data, size_t size) {
        require_open("write");
        write_all(fd_, data, size, temporary_);
    }

    // fsync, close, rename over `path`, fsync of the directory. On failure the temporary is
    // removed and `path` is as it was.
    void commit() {
        require_open("commit");
        try {
            if (::fsync(fd_) != 0) throw_os_error(temporary_, "fsync failed");
            const int fd = fd_;
            fd_ = -1;
            if (::close(fd) != 0) throw_os_error(temporary_, "close failed");
            if (::rename(temporary_.c_str(), path_.c_str()) != 0) throw_os_error(path_, "cannot rename " + temporary_ + " to it");
        } catch (...) {
            discard();
            throw;
        }
        committed_ = true;
        if (options_.sync_directory) fsync_directory(parent_directory(path_));
    }

    // Closes and removes the temporary (best effort: an error being thrown matters more).
    void discard() noexcept {
        if (committed_ || discarded_) return;
        if (fd_ >= 0) ::close(fd_);
        fd_ = -1;
        ::unlink(temporary_.c_str());
        discarded_ = true;
    }

private:
    void require_open(const char* what) const {
        if (fd_ < 0) throw std::logic_error(path_ + ": " + what + " after the file was committed or discarded");
    }
    std::string path_, temporary_;
    Options options_;
    int fd_ = -1;
    bool committed_ = false, discarded_ = false;
};

// Replaces `path` with `size` bytes atomically.
inline void write_file_atomic(const std::string& path, const void* data, size_t size,
                              AtomicFile::Options options = AtomicFile::Options()) {
    AtomicFile file(path, options);
    file.write(data, size);
    file.commit();
}

}  // namespace hirad
