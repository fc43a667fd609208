#include "formats/exr.h"

#include <Imath/half.h>
#include <OpenEXR/ImfChannelList.h>
#include <OpenEXR/ImfFrameBuffer.h>
#include <OpenEXR/ImfHeader.h>
#include <OpenEXR/ImfIO.h>
#include <OpenEXR/ImfInputFile.h>
#include <OpenEXR/ImfOutputFile.h>
#include <OpenEXR/ImfStringAttribute.h>

#include <cmath>
#include <stdexcept>
#include <string>

#include "pipeline/core/atomic_file.h"

namespace hirad {

namespace {

// OpenEXR's output stream over the atomic temporary's descriptor. A write error is kept as
// well as thrown: OutputFile's destructor writes the line offsets and swallows exceptions,
// so the writer asks failed() before committing.
class FdStream : public Imf::OStream {
public:
    FdStream(int fd, const std::string& name) : Imf::OStream(name.c_str()), fd_(fd), name_(name) {}
    void write(const char c[], int n) override {
        try {
            pwrite_all(fd_, c, size_t(n), at_, name_);
        } catch (const std::exception& e) {
            if (error_.empty()) error_ = e.what();
            throw;
        }
        at_ += uint64_t(n);
    }
    uint64_t tellp() override { return at_; }
    void seekp(uint64_t pos) override { at_ = pos; }
    const std::string& error() const { return error_; }

private:
    int fd_;
    std::string name_;
    uint64_t at_ = 0;
    std::string error_;
};

}  // namespace

void write_exr_rgb(const std::string& path, int width, int height, const float* rgb,
                   const std::vector<std::pair<std::string, std::string>>& metadata) {
    if (width <= 0 || height <= 0) throw std::invalid_argument(path + ": empty image");
    // Never write a value that is not a finite number, nor one that half floats cannot hold
    // (it would be written as infinity).
    constexpr float kHalfMax = 65504.0f;
    size_t bad = 0, first = 0;
    for (size_t i = 0; i < size_t(width) * height * 3; ++i)
        if (!(std::fabs(rgb[i]) <= kHalfMax) && bad++ == 0) first = i;
    if (bad > 0) {
        const size_t px = first / 3;
        throw std::invalid_argument(path + ": " + std::to_string(bad) + " values are not finite or beyond half float's " +
                                    "range (65504); the first is pixel (" + std::to_string(px % size_t(width)) + ", " +
                                    std::to_string(px / size_t(width)) + ") channel " + "RGB"[first % 3] + " = " +
                                    std::to_string(rgb[first]) + "; nothing was written");
    }
    std::vector<Imath::half> channels[3];
    for (auto& c : channels) c.resize(size_t(width) * height);
    for (size_t i = 0; i < size_t(width) * height; ++i)
        for (int c = 0; c < 3; ++c) channels[c][i] = Imath::half(rgb[3 * i + c]);
    Imf::Header header(width, height);
    header.compression() = Imf::ZIP_COMPRESSION;  // lossless
    for (const auto& [key, value] : metadata) header.insert(key, Imf::StringAttribute(value));
    const char* names[3] = {"R", "G", "B"};
    Imf::FrameBuffer fb;
    for (int c = 0; c < 3; ++c) {
        header.channels().insert(names[c], Imf::Channel(Imf::HALF));
        fb.insert(names[c], Imf::Slice(Imf::HALF, reinterpret_cast<char*>(channels[c].data()), sizeof(Imath::half),
                                       sizeof(Imath::half) * width));
    }
    AtomicFile out(path);  // throws naming the temporary when it cannot be created
    try {
        FdStream stream(out.fd(), out.temporary());
        {
            Imf::OutputFile file(stream, header);
            file.setFrameBuffer(fb);
            file.writePixels(height);
        }  // the destructor writes the line offset table
        if (!stream.error().empty()) throw std::runtime_error(stream.error());
        out.commit();
    } catch (const std::exception& e) {
        out.discard();
        throw std::runtime_error(path + ": could not write EXR: " + e.what());
    }
}

std::vector<float> read_exr_rgb(const std::string& path, int& width, int& height) {
    try {
        Imf::InputFile file(path.c_str());
        Imath::Box2i dw = file.header().dataWindow();
        width = dw.max.x - dw.min.x + 1;
        height = dw.max.y - dw.min.y + 1;
        std::vector<float> rgb(size_t(width) * height * 3, 0.0f);
        Imf::FrameBuffer fb;
        const char* names[3] = {"R", "G", "B"};
        char* base = reinterpret_cast<char*>(rgb.data()) -
                     (size_t(dw.min.y) * width + dw.min.x) * 3 * sizeof(float);
        for (int c = 0; c < 3; ++c)
            fb.insert(names[c], Imf::Slice(Imf::FLOAT, base + c * sizeof(float), 3 * sizeof(float),
                                           3 * sizeof(float) * width));
        file.setFrameBuffer(fb);
        file.readPixels(dw.min.y, dw.max.y);
        return rgb;
    } catch (const std::exception& e) {
        throw std::runtime_error(path + ": could not read EXR: " + e.what());
    }
}

}  // namespace hirad
