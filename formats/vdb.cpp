// The only translation unit that includes OpenVDB (see vdb.h).
#include "formats/vdb.h"

#include <openvdb/openvdb.h>
#include <openvdb/io/File.h>

#include <ext/stdio_filebuf.h>

#include <cmath>
#include <mutex>
#include <string>
#include <ostream>
#include <stdexcept>

#include "pipeline/core/atomic_file.h"

namespace hirad {

namespace {

void init_once() {
    static std::once_flag flag;
    std::call_once(flag, [] { openvdb::initialize(); });
}

openvdb::math::Transform::Ptr lattice_transform(double voxel_size, const std::array<double, 3>& origin) {
    auto xform = openvdb::math::Transform::createLinearTransform(voxel_size);
    xform->postTranslate(openvdb::Vec3d(origin[0], origin[1], origin[2]));
    return xform;
}

// What io::File::write does (Archive::write to a seekable stream, so the grid offsets are
// stored and io::File reads the result), but to a stream of our choosing: the atomic
// temporary's descriptor, not a path opened again.
class StreamArchive : public openvdb::io::Archive {
public:
    void write_seekable(std::ostream& os, const openvdb::GridPtrVec& grids, const openvdb::MetaMap& meta) const {
        openvdb::io::Archive::write(os, grids, /*seekable=*/true, meta);
    }
};

}  // namespace

void write_vdb(const std::string& path, const std::vector<VdbGrid>& grids, const Metadata& file_metadata) {
    init_once();
    openvdb::GridPtrVec out;
    for (const VdbGrid& g : grids) {
        if (g.coords.size() != g.values.size())
            throw std::invalid_argument("vdb grid " + g.name + ": coords and values differ in length");
        if (!(g.voxel_size > 0)) throw std::invalid_argument("vdb grid " + g.name + ": voxel size must be positive");
        for (size_t k = 0; k < g.values.size(); ++k)
            for (int c = 0; c < 3; ++c)
                if (!std::isfinite(g.values[k][c]))
                    throw std::invalid_argument(path + ": vdb grid " + g.name + ": voxel (" + std::to_string(g.coords[k][0]) +
                                                ", " + std::to_string(g.coords[k][1]) + ", " +
                                                std::to_string(g.coords[k][2]) + ") holds a value that is not finite (" +
                                                std::to_string(g.values[k][c]) + "); nothing was written");
        auto grid = openvdb::Vec3SGrid::create(openvdb::Vec3s(0, 0, 0));
        grid->setName(g.name);
        grid->setTransform(lattice_transform(g.voxel_size, g.origin));
        grid->setGridClass(openvdb::GRID_UNKNOWN);
        grid->setVectorType(openvdb::VEC_INVARIANT);
        auto acc = grid->getAccessor();
        for (size_t k = 0; k < g.coords.size(); ++k) {
            const auto& c = g.coords[k];
            const auto& v = g.values[k];
            acc.setValueOn(openvdb::Coord(c[0], c[1], c[2]), openvdb::Vec3s(v[0], v[1], v[2]));
        }
        for (const auto& [key, value] : g.metadata) grid->insertMeta(key, openvdb::StringMetadata(value));
        out.push_back(grid);
    }
    openvdb::MetaMap meta;
    for (const auto& [key, value] : file_metadata) meta.insertMeta(key, openvdb::StringMetadata(value));
    AtomicFile file(path);  // throws naming the temporary when it cannot be created
    try {
        const int fd = ::dup(file.fd());  // the stream buffer closes its own descriptor
        if (fd < 0) throw_os_error(file.temporary(), "cannot duplicate the descriptor");
        {
            __gnu_cxx::stdio_filebuf<char> buffer(fd, std::ios::out | std::ios::binary);
            std::ostream os(&buffer);
            StreamArchive archive;
            archive.setCompression(openvdb::io::COMPRESS_BLOSC | openvdb::io::COMPRESS_ACTIVE_MASK);
            archive.write_seekable(os, out, meta);
            os.flush();
            if (!os) throw std::runtime_error(file.temporary() + ": write failed");
            if (buffer.close() == nullptr) throw std::runtime_error(file.temporary() + ": write failed on close");
        }
        file.commit();
    } catch (const std::exception& e) {
        file.discard();
        throw std::runtime_error(path + ": could not write the VDB file: " + e.what());
    }
}

std::vector<VdbGrid> read_vdb(const std::string& path, Metadata& file_metadata) {
    init_once();
    openvdb::io::File file(path);
    try {
        file.open();
    } catch (const openvdb::Exception& e) {
        throw std::runtime_error(path + ": " + e.what());
    }
    file_metadata.clear();
    if (auto meta = file.getMetadata())
        for (auto it = meta->beginMeta(); it != meta->endMeta(); ++it) file_metadata.emplace_back(it->first, it->second->str());
    std::vector<VdbGrid> result;
    openvdb::GridPtrVecPtr grids = file.getGrids();
    for (const auto& base : *grids) {
        auto grid = openvdb::gridPtrCast<openvdb::Vec3SGrid>(base);
        if (!grid) continue;
        VdbGrid g;
        g.name = grid->getName();
        g.voxel_size = grid->transform().voxelSize()[0];
        openvdb::Vec3d o = grid->transform().indexToWorld(openvdb::Vec3d(0, 0, 0));
        g.origin = {o[0], o[1], o[2]};
        for (auto it = grid->cbeginValueOn(); it; ++it) {
            const openvdb::Coord c = it.getCoord();
            const openvdb::Vec3s v = *it;
            g.coords.push_back({c.x(), c.y(), c.z()});
            g.values.push_back({v[0], v[1], v[2]});
        }
        for (auto it = grid->beginMeta(); it != grid->endMeta(); ++it) g.metadata.emplace_back(it->first, it->second->str());
        result.push_back(std::move(g));
    }
    file.close();
    return result;
}

}  // namespace hirad
