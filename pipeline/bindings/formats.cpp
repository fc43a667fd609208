// File formats: EXR images (formats/exr.h) and OpenVDB grids (formats/vdb.h).
#include <nanobind/stl/pair.h>
#include <nanobind/stl/string.h>
#include <nanobind/stl/vector.h>

#include "formats/exr.h"
#include "formats/vdb.h"
#include "pipeline/bindings/common.h"

namespace hirad::py {

using namespace nb::literals;

namespace {

void write_exr(const std::string& path, In<float> rgb, const Metadata& meta) {
    require_shape(rgb, {-1, -1, 3}, "rgb");
    write_exr_rgb(path, static_cast<int>(rgb.shape(1)), static_cast<int>(rgb.shape(0)), rgb.data(), meta);
}

Array<float> read_exr(const std::string& path) {
    int w = 0, h = 0;
    std::vector<float> rgb = read_exr_rgb(path, w, h);
    return to_numpy(std::move(rgb), {size_t(h), size_t(w), 3});
}

// grids: list of (name, coords int32 (n,3), values float32 (n,3), [(key, value)]).
void write_vdb_py(const std::string& path, nb::list grids, double voxel_size, const std::vector<double>& origin,
                  const Metadata& file_metadata) {
    if (origin.size() != 3) throw std::invalid_argument("origin: 3 components");
    std::vector<VdbGrid> out;
    for (nb::handle item : grids) {
        nb::tuple t = nb::cast<nb::tuple>(item);
        if (t.size() != 4) throw std::invalid_argument("each grid: (name, coords, values, metadata)");
        VdbGrid g;
        g.name = nb::cast<std::string>(t[0]);
        auto coords = nb::cast<In<int32_t>>(t[1]);
        auto values = nb::cast<In<float>>(t[2]);
        require_shape(coords, {-1, 3}, ("grid " + g.name + " coords").c_str());
        require_shape(values, {long(coords.shape(0)), 3}, ("grid " + g.name + " values").c_str());
        const size_t n = coords.shape(0);
        g.coords.resize(n);
        g.values.resize(n);
        for (size_t k = 0; k < n; ++k)
            for (int c = 0; c < 3; ++c) {
                g.coords[k][c] = coords.data()[3 * k + c];
                g.values[k][c] = values.data()[3 * k + c];
            }
        g.metadata = nb::cast<Metadata>(t[3]);
        g.voxel_size = voxel_size;
        g.origin = {origin[0], origin[1], origin[2]};
        out.push_back(std::move(g));
    }
    nb::gil_scoped_release release;
    write_vdb(path, out, file_metadata);
}

// {"metadata": {key: text}, "grids": {name: {"coords", "values", "voxel_size", "origin", "metadata"}}}
nb::dict read_vdb_py(const std::string& path) {
    Metadata file_meta;
    std::vector<VdbGrid> grids;
    {
        nb::gil_scoped_release release;
        grids = read_vdb(path, file_meta);
    }
    nb::dict d, gd, fm;
    for (auto& [k, v] : file_meta) fm[k.c_str()] = v;
    for (VdbGrid& g : grids) {
        const size_t n = g.coords.size();
        std::vector<int32_t> c(n * 3);
        std::vector<float> v(n * 3);
        for (size_t k = 0; k < n; ++k)
            for (int a = 0; a < 3; ++a) { c[3 * k + a] = g.coords[k][a]; v[3 * k + a] = g.values[k][a]; }
        nb::dict e, meta;
        e["coords"] = to_numpy(std::move(c), {n, 3});
        e["values"] = to_numpy(std::move(v), {n, 3});
        e["voxel_size"] = g.voxel_size;
        e["origin"] = std::vector<double>{g.origin[0], g.origin[1], g.origin[2]};
        for (auto& [k, val] : g.metadata) meta[k.c_str()] = val;
        e["metadata"] = meta;
        gd[g.name.c_str()] = e;
    }
    d["metadata"] = fm;
    d["grids"] = gd;
    return d;
}

}  // namespace

void bind_formats(nb::module_& m) {
    m.def("write_exr", &write_exr, "path"_a, "rgb"_a, "metadata"_a,
          "Writes an (h, w, 3) float32 image as an RGB EXR with string metadata [(key, value)].");
    m.def("read_exr", &read_exr, "path"_a, "An RGB EXR as (h, w, 3) float32.");
    m.def("write_vdb", &write_vdb_py, "path"_a, "grids"_a, "voxel_size"_a, "origin"_a, "metadata"_a,
          "Writes Vec3f grids [(name, coords int32 (n, 3), values float32 (n, 3), [(key, value)])] to an OpenVDB "
          "file; voxel_size in m, origin (3) the world position of voxel (0, 0, 0).");
    m.def("read_vdb", &read_vdb_py, "path"_a,
          "An OpenVDB file written by write_vdb: {'metadata': {...}, 'grids': {name: {'coords', 'values', "
          "'voxel_size', 'origin', 'metadata'}}}.");
}

}  // namespace hirad::py
