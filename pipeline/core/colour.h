// Colour: the one luminance weighting and the one emission norm of the engine.
//
// RGB values are linear Rec. 709 / sRGB primaries (what USD's colour attributes hold by
// default), so luminance is Y = 0.2126 R + 0.7152 G + 0.0722 B (ITU-R BT.709). It weighs
// channels wherever one number must stand for a colour: the emitted power refinement's
// epsilon is relative to, the brightest radiosity below a node, the unshot power that
// shooting solvers rank by.
//
// Kept free of other engine headers (it works on anything with .x, .y, .z), so that
// vecmath.h can include it.
#pragma once
#include <cmath>
#include <cstddef>

namespace hirad {

constexpr double kLuminanceR = 0.2126, kLuminanceG = 0.7152, kLuminanceB = 0.0722;

inline double luminance(double r, double g, double b) { return kLuminanceR * r + kLuminanceG * g + kLuminanceB * b; }

template <typename C>
double luminance(const C& c) {
    return luminance(c.x, c.y, c.z);
}

// Luminance of the channels' magnitudes: the size of a signed change (an unshot radiosity).
template <typename C>
double luminance_of_magnitude(const C& c) {
    return luminance(std::fabs(c.x), std::fabs(c.y), std::fabs(c.z));
}

// A norm from its sum of squares, or 1 when that is zero (or not a number): relative
// residuals divide by the emission norm, and a scene without emission then measures the
// absolute residual instead of dividing by zero.
inline double norm_or_one(double sum_of_squares) {
    const double e = std::sqrt(sum_of_squares);
    return e > 0 ? e : 1.0;
}

// The emission norm of the hierarchical solvers: sqrt(sum_k w_k |E_k|^2) over k in [0, n),
// summed in that order (the same bits every time), w_k an area. `weight(k)` and
// `emission(k)` give the k-th item's. The flat solvers use the same norm with every weight 1
// (their residual is per patch), summed in blocks (solvers.cpp: ordered_sum).
template <typename Weight, typename Emission>
double emission_norm(size_t n, Weight weight, Emission emission) {
    double s = 0;
    for (size_t k = 0; k < n; ++k) {
        const auto e = emission(k);
        s += weight(k) * (e.x * e.x + e.y * e.y + e.z * e.z);
    }
    return norm_or_one(s);
}

}  // namespace hirad
