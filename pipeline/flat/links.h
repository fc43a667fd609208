// Links of the flat method: the symmetric coupling matrix G_ij = A_i F_ij, stored once in
// compressed rows. Row i gives both F_ij = G_ij / A_i (gathering at i) and F_ji = G_ij / A_j
// (shooting from i), so gathering and shooting solvers read the same numbers.
#pragma once
#include <cstdint>
#include <functional>
#include <utility>
#include <vector>

namespace hirad {

struct LinkMatrix {
    uint32_t n = 0;
    std::vector<uint64_t> offsets;  // n + 1
    std::vector<uint32_t> columns;  // sorted within each row
    std::vector<float> coupling;    // G_ij in m^2

    uint64_t link_count() const { return columns.size(); }
    size_t bytes() const {
        return offsets.size() * sizeof(uint64_t) + columns.size() * (sizeof(uint32_t) + sizeof(float));
    }

    // Assembles the symmetric matrix from per-row upper-triangle entries (j > i).
    static LinkMatrix from_upper(uint32_t n, std::vector<std::vector<std::pair<uint32_t, float>>>& upper);
    // Builds it from a row function (j > i entries), rows evaluated in parallel.
    static LinkMatrix build(uint32_t n,
                            const std::function<void(uint32_t, std::vector<std::pair<uint32_t, float>>&)>& upper_row,
                            const std::function<void(uint32_t done)>& progress = nullptr);
};

}  // namespace hirad
