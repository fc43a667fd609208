// hirad._engine.Luminaire: a light source that is not a Lambertian surface
// (pipeline/geometry/luminaire.h): emitting points over its opening and a candela table.
#include <nanobind/stl/optional.h>
#include <nanobind/stl/string.h>

#include "pipeline/bindings/common.h"
#include "pipeline/geometry/luminaire.h"

namespace hirad::py {

using namespace nb::literals;

void bind_luminaires(nb::module_& m) {
    nb::class_<Luminaire>(m, "Luminaire",
                          "A luminaire (luminaire.h): points over its luminous opening with weights, its frame and a "
                          "candela table I(C, gamma), gamma 0 = local -Z, C0 = +X, C90 = +Y, bilinear between nodes.")
        .def("__init__",
             [](Luminaire* self, const std::string& name, In<double> points, In<double> weights, In<double> frame,
                In<double> candela, In<double> colour) {
                 Luminaire l;
                 l.name = name;
                 l.points = vec3_rows(points, "points");
                 require_shape(weights, {long(l.points.size())}, "weights");
                 l.weights.assign(weights.data(), weights.data() + weights.shape(0));
                 const std::vector<Vec3> axes = vec3_rows(frame, "frame", 3);
                 for (int a = 0; a < 3; ++a) l.axis[a] = axes[a];
                 require_shape(candela, {-1, -1}, "candela");
                 l.nc = int(candela.shape(0));
                 l.ng = int(candela.shape(1));
                 l.candela.assign(candela.data(), candela.data() + candela.shape(0) * candela.shape(1));
                 const std::vector<Vec3> c = vec3_rows(colour, "colour", 1);
                 l.colour = c[0];
                 l.validate();
                 new (self) Luminaire(std::move(l));
             },
             "name"_a, "points"_a, "weights"_a, "frame"_a, "candela"_a, "colour"_a,
             "points (k, 3) m in world space, weights (k) summing to 1, frame (3, 3) whose rows are the local X, Y, "
             "Z axes in world space, candela (nc, ng) at C_i = 360 i / nc degrees and gamma_j = 180 j / (ng - 1) "
             "degrees, colour (1, 3): channel c emits candela x colour[c]. Invalid data: ValueError.")
        .def_static("distant",
                    [](const std::string& name, In<double> directions, In<double> weights, double illuminance,
                       In<double> colour, std::optional<In<double>> tints, bool interleave) {
                        std::vector<Vec3> d = vec3_rows(directions, "directions");
                        const long k = long(d.size());
                        require_shape(weights, {k}, "weights");
                        std::vector<double> w(weights.data(), weights.data() + weights.shape(0));
                        std::vector<RGB> t;
                        if (tints) t = vec3_rows(*tints, "tints", k);
                        Luminaire l = distant_light(name, std::move(d), std::move(w), illuminance,
                                                    vec3_rows(colour, "colour", 1)[0], std::move(t));
                        l.interleave = interleave;
                        return l;
                    },
                    "name"_a, "directions"_a, "weights"_a, "illuminance"_a, "colour"_a, "tints"_a.none() = nb::none(),
                    "interleave"_a = false,
                    "A distant light (luminaire.h): the sun or sky patches. directions (k, 3) towards the light "
                    "(normalised), weights (k) summing to 1, illuminance E_perp per unit colour (lux or W/m^2) on a "
                    "surface facing it, colour (1, 3); tints (k, 3), optional: per direction a colour factor (a sky "
                    "of varying colour as one light). interleave: one part of a sky cut into many lights (daylight "
                    "coefficients' patch groups): on elements, interleaved with the other such lights as one sky "
                    "(luminaire.h). Invalid data: ValueError.")
        .def_ro("name", &Luminaire::name)
        .def_ro("is_distant", &Luminaire::distant, "True for a distant light (points are directions).")
        .def_ro("interleave", &Luminaire::interleave, "Distant: part of a sky interleaved over elements' points.")
        .def_ro("illuminance", &Luminaire::illuminance, "Distant: E_perp per unit colour, lux (or W/m^2).")
        .def_prop_ro("points", [](const Luminaire& l) { return rows3(l.points); }, kOwned, "(k, 3) m.")
        .def_prop_ro("weights", [](const Luminaire& l) { return to_numpy(l.weights, {l.weights.size()}); }, kOwned,
                     "(k) summing to 1.")
        .def_prop_ro("frame", [](const Luminaire& l) { return rows3({l.axis[0], l.axis[1], l.axis[2]}); }, kOwned,
                     "(3, 3) rows: local X, Y, Z in world space.")
        .def_prop_ro("candela", [](const Luminaire& l) { return to_numpy(l.candela, {size_t(l.nc), size_t(l.ng)}); },
                     kOwned, "(nc, ng) cd (or W/sr).")
        .def_prop_ro("colour", [](const Luminaire& l) { return rows3({l.colour}); }, kOwned, "(1, 3).")
        .def_prop_ro("flux", [](const Luminaire& l) { return rows3({l.flux()}); }, kOwned,
                     "(1, 3) the exact integral of the bilinear table times colour over the sphere, lm (or W).")
        .def_prop_ro("table_flux", &Luminaire::table_flux, "The table's exact flux per unit colour, lm (or W).")
        .def("intensity",
             [](const Luminaire& l, In<double> d) {
                 const std::vector<Vec3> dirs = vec3_rows(d, "directions");
                 std::vector<Vec3> out(dirs.size());
                 for (size_t q = 0; q < dirs.size(); ++q) out[q] = l.colour * l.intensity(dirs[q]);
                 return rows3(out);
             },
             "directions"_a, "Intensity (n, 3) toward world directions (n, 3), per channel, cd (or W/sr).")
        .def("irradiance",
             [](const Luminaire& l, In<double> p, In<double> n) {
                 const std::vector<Vec3> pts = vec3_rows(p, "points");
                 std::vector<Vec3> nor = vec3_rows(n, "normals", long(pts.size()));
                 for (Vec3& v : nor) v = normalize(v);
                 std::vector<RGB> out(pts.size());
                 luminaire_irradiance({l}, nullptr, pts.data(), nor.data(), pts.size(), out.data(), 0.0);
                 return rows3(out);
             },
             "points"_a, "normals"_a, "Unoccluded direct irradiance (n, 3) at points facing normals, lux (or W/m^2).");
}

}  // namespace hirad::py
