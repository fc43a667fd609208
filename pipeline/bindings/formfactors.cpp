// Closed-form form factors (pipeline/geometry/formfactors.h), the oracles of the tests, and the
// engine's thread cap.
#include <nanobind/stl/vector.h>

#include "pipeline/bindings/common.h"
#include "pipeline/engine/engine.h"
#include "pipeline/geometry/formfactors.h"

namespace hirad::py {

using namespace nb::literals;

namespace {

double point_polygon(const std::vector<double>& x, const std::vector<double>& n, In<double> poly) {
    if (x.size() != 3 || n.size() != 3) throw std::invalid_argument("x and normal: 3 components");
    require_shape(poly, {-1, 3}, "polygon");
    const int nv = static_cast<int>(poly.shape(0));
    if (nv < 3 || nv > 4) throw std::invalid_argument("polygon: 3 or 4 corners");
    Vec3 p[4];
    for (int k = 0; k < nv; ++k) p[k] = {poly.data()[3 * k], poly.data()[3 * k + 1], poly.data()[3 * k + 2]};
    Vec3 pn;
    for (int k = 0; k < nv; ++k) pn += cross(p[k], p[(k + 1) % nv]);
    return point_polygon_form_factor({x[0], x[1], x[2]}, normalize({n[0], n[1], n[2]}), p, nv, normalize(pn));
}

}  // namespace

void bind_formfactors(nb::module_& m) {
    m.def("set_threads", &set_threads, "threads"_a, "Caps the engine's TBB threads (0 = all cores).");
    m.def("parallel_rectangles_form_factor", &parallel_rectangles_form_factor, "a"_a, "b"_a, "c"_a,
          "F between two directly opposed a x b rectangles at distance c (closed form).");
    m.def("perpendicular_rectangles_form_factor", &perpendicular_rectangles_form_factor, "l"_a, "h"_a, "w"_a,
          "F from a w x l rectangle to an h x l one, perpendicular, sharing the edge of length l (closed form).");
    m.def("point_polygon_form_factor", &point_polygon, "x"_a, "normal"_a, "polygon"_a,
          "Differential point-to-polygon form factor at x with normal (Lambert's formula); polygon (3 or 4, 3), "
          "only the part above the point's plane counts.");
}

}  // namespace hirad::py
