// EXR output: half-float RGB, written to an AtomicFile's exclusive temporary and renamed
// (pipeline/core/atomic_file.h), so a reader never sees a partial file.
#pragma once
#include <string>
#include <utility>
#include <vector>

namespace hirad {

// rgb: height*width*3 floats, row 0 at the top. Metadata become string attributes. A value
// that is not finite or beyond half float's range (65504) is refused (std::invalid_argument
// naming the pixel) and nothing is written.
void write_exr_rgb(const std::string& path, int width, int height, const float* rgb,
                   const std::vector<std::pair<std::string, std::string>>& metadata);

// Reads an RGB EXR back as floats (for tests and `hirad render` comparisons).
std::vector<float> read_exr_rgb(const std::string& path, int& width, int& height);

}  // namespace hirad
