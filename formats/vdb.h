// OpenVDB output for the irradiance volume: float3 (Vec3s) grids on a common lattice, and a
// small reader (Debian's python openvdb does not work with numpy 2). Nothing here includes
// OpenVDB: every use of it stays in vdb.cpp, which is slow to compile.
#pragma once
#include <array>
#include <cstdint>
#include <string>
#include <utility>
#include <vector>

namespace hirad {

using Metadata = std::vector<std::pair<std::string, std::string>>;

struct VdbGrid {
    std::string name;
    // Active voxels: integer lattice coordinates and one RGB (or xyz) value each. World
    // position of voxel (i, j, k) = origin + voxel_size * (i, j, k).
    std::vector<std::array<int32_t, 3>> coords;
    std::vector<std::array<float, 3>> values;
    Metadata metadata;  // string metadata on the grid (the reader returns every item as text)
    double voxel_size = 1;
    std::array<double, 3> origin{0, 0, 0};
};

// Writes the grids to `path` (through an AtomicFile: an exclusive temporary renamed into place).
// A value that is not finite is refused (std::invalid_argument naming the voxel) and nothing
// is written.
void write_vdb(const std::string& path, const std::vector<VdbGrid>& grids, const Metadata& file_metadata);

// Reads every Vec3s grid of a .vdb file (other grid types are skipped); `file_metadata`
// receives the file-level metadata as text.
std::vector<VdbGrid> read_vdb(const std::string& path, Metadata& file_metadata);

}  // namespace hirad
