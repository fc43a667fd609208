// hirad._engine.DisplayMesh: the welded display mesh of the patches (pipeline/outputs/
// reconstruct.h), and Engine.display_arrays, its arrays without an intermediate copy.
#include "pipeline/bindings/common.h"
#include "pipeline/engine/engine.h"
#include "pipeline/outputs/reconstruct.h"

namespace hirad::py {

using namespace nb::literals;

namespace {

// A vector of unsigned indices as int32 (numpy's usual index type).
template <class C, class U>
auto int32s(std::vector<U> C::*p) {
    return [p](const C& c) {
        std::vector<int32_t> v((c.*p).begin(), (c.*p).end());
        return to_numpy(std::move(v), {(c.*p).size()});
    };
}

}  // namespace

void bind_display(nb::module_& m) {
    nb::class_<DisplayMesh>(m, "DisplayMesh", "Welded display mesh of the patches (reconstruct.h).")
        .def_prop_ro("points", vec3s(&DisplayMesh::points), kOwned, "(points, 3) m.")
        .def_prop_ro("point_mesh", int32s(&DisplayMesh::point_mesh), kOwned, "(points) input mesh of each point.")
        .def_prop_ro("corners", quads<int32_t>(&DisplayMesh::corners), kOwned,
                     "(patches, 4) each patch's corner points.")
        .def_prop_ro("boundary", arr(&DisplayMesh::boundary), kOwned, "(points) 1 on a boundary.")
        .def_prop_ro("faces", quads<int32_t>(&DisplayMesh::faces), kOwned, "(faces, 4) display faces' points.")
        .def_prop_ro("face_nv", arr(&DisplayMesh::face_nv), kOwned, "(faces) 3 or 4.")
        .def_prop_ro("face_patch", int32s(&DisplayMesh::face_patch), kOwned, "(faces) the patch each face belongs to.")
        .def_prop_ro("face_code", quads<uint8_t>(&DisplayMesh::face_code), kOwned,
                     "(faces, 4) corner codes (reconstruct.h).")
        .def_prop_ro("anchored", [](const DisplayMesh& d) {
            std::vector<uint8_t> v(d.anchors.size());
            for (size_t i = 0; i < v.size(); ++i) v[i] = !d.anchors[i].empty();
            return to_numpy(std::move(v), {v.size()});
        }, kOwned, "(points) 1 for T-vertices and fan centres (weighted sums of other points).");
    // Engine.display_arrays: each array copied once from the engine's own mesh (display_mesh
    // would first copy the whole DisplayMesh, its anchors' lists too, into a Python object).
    nb::object engine = nb::borrow(nb::type<Engine>());
    engine.attr("display_arrays") = nb::cpp_function(
        [](Engine& e, double crease) {
            nb::object view = nb::cast(&e.display_mesh(crease), nb::rv_policy::reference);
            nb::dict out;
            for (const char* k : {"points", "point_mesh", "corners", "boundary", "faces", "face_nv", "face_patch",
                                  "face_code", "anchored"})
                out[k] = view.attr(k);  // copies (kOwned), taken while the engine's mesh is there
            return out;
        },
        nb::is_method(), nb::scope(engine), nb::name("display_arrays"), "crease_angle"_a,
        "The display mesh display_mesh makes and keeps, as a dict of its DisplayMesh arrays.");
}

}  // namespace hirad::py
