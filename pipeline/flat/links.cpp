#include "pipeline/flat/links.h"

#include <tbb/parallel_for.h>

#include <atomic>

namespace hirad {

LinkMatrix LinkMatrix::from_upper(uint32_t n, std::vector<std::vector<std::pair<uint32_t, float>>>& upper) {
    LinkMatrix m;
    m.n = n;
    std::vector<uint64_t> lower_count(n, 0), count(n, 0);
    for (uint32_t i = 0; i < n; ++i) {
        count[i] += upper[i].size();
        for (const auto& [j, g] : upper[i]) { ++count[j]; ++lower_count[j]; }
    }
    m.offsets.assign(n + 1, 0);
    for (uint32_t i = 0; i < n; ++i) m.offsets[i + 1] = m.offsets[i] + count[i];
    m.columns.resize(m.offsets[n]);
    m.coupling.resize(m.offsets[n]);
    // Row r holds its lower entries (i < r, filled in increasing i as rows are visited) and
    // then its upper entries (j > r, already sorted): every row comes out sorted.
    std::vector<uint64_t> lower_cursor(m.offsets.begin(), m.offsets.end() - 1);
    for (uint32_t i = 0; i < n; ++i) {
        uint64_t up = m.offsets[i] + lower_count[i];
        for (const auto& [j, g] : upper[i]) {
            m.columns[up] = j;
            m.coupling[up++] = g;
            m.columns[lower_cursor[j]] = i;
            m.coupling[lower_cursor[j]++] = g;
        }
        std::vector<std::pair<uint32_t, float>>().swap(upper[i]);
    }
    return m;
}

LinkMatrix LinkMatrix::build(uint32_t n,
                             const std::function<void(uint32_t, std::vector<std::pair<uint32_t, float>>&)>& upper_row,
                             const std::function<void(uint32_t)>& progress) {
    std::vector<std::vector<std::pair<uint32_t, float>>> upper(n);
    std::atomic<uint32_t> done{0};
    tbb::parallel_for(tbb::blocked_range<uint32_t>(0, n, 1), [&](const tbb::blocked_range<uint32_t>& r) {
        for (uint32_t i = r.begin(); i < r.end(); ++i) {
            upper_row(i, upper[i]);
            uint32_t d = ++done;
            if (progress) progress(d);
        }
    });
    return from_upper(n, upper);
}

}  // namespace hirad
