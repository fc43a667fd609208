// hirad._engine.SurfaceField: a solved surface as one ray-tracing scene built once
// (pipeline/engine/ray_scene.h), queried many times.
#include <nanobind/stl/optional.h>
#include <nanobind/stl/vector.h>

#include <optional>

#include "pipeline/bindings/common.h"
#include "pipeline/engine/ray_scene.h"

namespace hirad::py {

using namespace nb::literals;

namespace {

Vec3 vec3(const std::vector<double>& v, const char* what) {
    if (v.size() != 3) throw std::invalid_argument(std::string(what) + ": 3 components");
    return {v[0], v[1], v[2]};
}

// The glazing of n patches from SurfaceField's optional arrays (visibility.h).
Glazing glazing_of(long n, const std::optional<In<double>>& tau, const std::optional<In<double>>& angular) {
    Glazing glazing;
    if (tau) {
        require_shape(*tau, {n}, "transmittance");
        glazing.face_transmittance.assign(tau->data(), tau->data() + n);
    }
    if (angular) {
        require_shape(*angular, {-1}, "glass_angular");
        glazing.angular.assign(angular->data(), angular->data() + angular->shape(0));
    }
    return glazing;
}

// The pinhole camera of a render or camera_rays call.
Camera camera_of(const std::vector<double>& pos, const std::vector<double>& fwd, const std::vector<double>& up,
                 double fov, int width, int height) {
    Camera cam;
    cam.position = vec3(pos, "position");
    cam.forward = vec3(fwd, "forward");
    cam.up = vec3(up, "up");
    cam.vertical_fov_degrees = fov;
    cam.width = width;
    cam.height = height;
    return cam;
}

}  // namespace

void bind_fields(nb::module_& m) {
    nb::class_<ProbeResult>(m, "ProbeResult", "The closest surface point to each query point.")
        .def_prop_ro("patch", arr(&ProbeResult::patch), kOwned, "(n) patch (-1: none within max_distance).")
        .def_prop_ro("distance", arr(&ProbeResult::distance), kOwned, "(n) m (-1: none).")
        .def_prop_ro("irradiance", vec3s(&ProbeResult::irradiance), kOwned, "(n, 3) W/m^2.")
        .def_prop_ro("radiance", vec3s(&ProbeResult::radiance), kOwned, "(n, 3) W/(m^2 sr).");
    nb::class_<RayCastResult>(m, "RayCastResult", "First hits of rays.")
        .def_prop_ro("patch", arr(&RayCastResult::patch), kOwned, "(n) patch hit (-1: escaped).")
        .def_prop_ro("t", arr(&RayCastResult::t), kOwned, "(n) distance along the normalised direction (-1: none).")
        .def_prop_ro("points", vec3s(&RayCastResult::points), kOwned, "(n, 3) hit points.")
        .def_prop_ro("normals", vec3s(&RayCastResult::normals), kOwned, "(n, 3) the hit patch's normal.")
        .def_prop_ro("back", arr(&RayCastResult::back), kOwned, "(n) 1 where a back face was hit.")
        .def_prop_ro("u", arr(&RayCastResult::u), kOwned, "(n) the hit's first coordinate on its patch.")
        .def_prop_ro("v", arr(&RayCastResult::v), kOwned, "(n) the hit's second coordinate on its patch.");
    nb::class_<LiftResult>(m, "LiftResult", "Lightmap sample points lifted off their surface.")
        .def_prop_ro("points", vec3s(&LiftResult::points), kOwned, "(n, 3) m.")
        .def_prop_ro("moved", arr(&LiftResult::moved), kOwned, "(n) 1 where a point was moved out of geometry.");
    nb::class_<VolumeProbes>(m, "VolumeProbes", "Full-sphere radiance moments at points in empty space.")
        .def_prop_ro("s0", vec3s(&VolumeProbes::s0), kOwned, "(n, 3) integral of L over the sphere.")
        .def_prop_ro("s1", [](const VolumeProbes& v) {
            std::vector<double> flat(v.s1.size() * 9);
            for (size_t q = 0; q < v.s1.size(); ++q)
                for (int a = 0; a < 3; ++a)
                    for (int c = 0; c < 3; ++c) flat[9 * q + 3 * a + c] = v.s1[q][a][c];
            return to_numpy(std::move(flat), {v.s1.size(), 3, 3});
        }, kOwned, "(n, 3, 3) [q, a, c]: integral of L w_a in channel c.")
        .def_prop_ro("sh2", [](const VolumeProbes& v) {
            std::vector<double> flat(v.sh2.size() * 27);
            for (size_t q = 0; q < v.sh2.size(); ++q)
                for (int k = 0; k < 9; ++k)
                    for (int c = 0; c < 3; ++c) flat[27 * q + 3 * k + c] = v.sh2[q][k][c];
            return to_numpy(std::move(flat), {v.sh2.size(), 9, 3});
        }, kOwned,
                     "(n, 9, 3) [q, k, c]: integral of L Y_k in channel c, Y_k the real orthonormal L2 "
                     "spherical harmonics (Ramamoorthi & Hanrahan 2001 order and signs: 1, y, z, x, xy, yz, "
                     "3z^2-1, xz, x^2-y^2 times 0.282095, 0.488603 (x3), 1.092548, 1.092548, 0.315392, "
                     "1.092548, 0.546274), world axes.")
        .def_prop_ro("back_fraction", arr(&VolumeProbes::back_fraction), kOwned, "(n) rays that hit a back face.")
        .def_prop_ro("hit_fraction", arr(&VolumeProbes::hit_fraction), kOwned, "(n) rays that hit anything.")
        .def_prop_ro("nearest", arr(&VolumeProbes::nearest), kOwned, "(n) closest hit, m (-1: none).");

    nb::class_<Illuminance>(m, "Illuminance",
                            "Illuminance at sensors, W/m^2 per RGB channel (lux when photometric).")
        .def_prop_ro("direct", vec3s(&Illuminance::direct), kOwned,
                     "(n, 3) from the emitter patches (exact contour integrals, shadowed per piece) and the "
                     "luminaires (exact, one shadow ray per luminaire point).")
        .def_prop_ro("indirect", vec3s(&Illuminance::indirect), kOwned,
                     "(n, 3) gathered by hemisphere rays from every surface's exitant radiance less its emission.");

    nb::class_<RayScene>(m, "SurfaceField",
                         "A solved surface as one Embree scene, built once: render, probe, lift_samples, "
                         "volume_probes and ray_cast query it.")
        .def("__init__",
             [](RayScene* self, In<double> corners, In<int32_t> nv, std::optional<In<double>> rad,
                std::optional<In<double>> irr, std::optional<In<double>> tau, std::optional<In<double>> angular) {
                 require_shape(nv, {-1}, "nv");
                 const long n = long(nv.shape(0));
                 require_shape(corners, {n, 4, 3}, "corners");
                 if (rad) require_shape(*rad, {n, 4, 3}, "corner_radiance");
                 if (irr) require_shape(*irr, {n, 4, 3}, "corner_irradiance");
                 const Glazing glazing = glazing_of(n, tau, angular);
                 new (self) RayScene(corners.data(), nv.data(), size_t(n), rad ? rad->data() : nullptr,
                                     irr ? irr->data() : nullptr, tau ? &glazing : nullptr);
             },
             "corners"_a, "nv"_a, "corner_radiance"_a.none() = nb::none(), "corner_irradiance"_a.none() = nb::none(),
             "transmittance"_a.none() = nb::none(), "glass_angular"_a.none() = nb::none(),
             "Patches (n, 4, 3) with nv (n) of 3 or 4; radiance W/(m^2 sr) and irradiance W/m^2 per corner "
             "(n, 4, 3), optional (zero without); glazing: transmittance (n) per patch and glass_angular "
             "(visibility.h), so that the luminaires' and distant lights' direct light passes windows.")
        .def("__init__",
             [](RayScene* self, In<double> points, In<int32_t> faces, In<int32_t> nv, std::optional<In<double>> rad,
                std::optional<In<double>> irr, std::optional<In<double>> tau, std::optional<In<double>> angular) {
                 require_shape(nv, {-1}, "nv");
                 const long n = long(nv.shape(0));
                 require_shape(points, {-1, 3}, "points");
                 const long m = long(points.shape(0));
                 require_shape(faces, {n, 4}, "faces");
                 if (rad) require_shape(*rad, {m, 3}, "point_radiance");
                 if (irr) require_shape(*irr, {m, 3}, "point_irradiance");
                 const Glazing glazing = glazing_of(n, tau, angular);
                 new (self) RayScene(points.data(), size_t(m), faces.data(), nv.data(), size_t(n),
                                     rad ? rad->data() : nullptr, irr ? irr->data() : nullptr,
                                     tau ? &glazing : nullptr);
             },
             nb::kw_only(), "points"_a, "faces"_a, "nv"_a, "point_radiance"_a.none() = nb::none(),
             "point_irradiance"_a.none() = nb::none(), "transmittance"_a.none() = nb::none(),
             "glass_angular"_a.none() = nb::none(),
             "The same from an indexed mesh (ray_scene.h): points (m, 3), faces (n, 4) of point indices with "
             "nv (n), radiance and irradiance per point (m, 3); the same patches and values, to the bit, as "
             "from points[faces] and the values at points[faces].")
        .def("__len__", &RayScene::size)
        .def("hemisphere_hits",
             [](const RayScene& s, In<double> p, In<double> n, int rays, uint64_t seed) {
                 auto pts = vec3_rows(p, "points");
                 auto nrm = vec3_rows(n, "normals", long(pts.size()));
                 HemisphereHits h;
                 {
                     nb::gil_scoped_release release;
                     h = s.hemisphere_hits(pts, nrm, rays, seed);
                 }
                 const size_t m = h.sensor.size();
                 return nb::make_tuple(to_numpy(std::move(h.sensor), {m}), to_numpy(std::move(h.patch), {m}),
                                       to_numpy(std::move(h.u), {m}), to_numpy(std::move(h.v), {m}),
                                       to_numpy(std::move(h.weight), {m}), h.rays);
             },
             "points"_a, "normals"_a, "rays"_a, "seed"_a = 1,
             "The rays of illuminance's indirect part (the same for the same rays and seed), traced once: (sensor, "
             "patch, u, v, weight, rays): per entry a front-facing surface a ray of that sensor reads (through clear "
             "glass: the panes met from the front and the surface past them; weight the glass passed before it, 1 "
             "without), sensor by sensor; rays = k*k a sensor. The indirect illuminance of corner radiance L is "
             "pi / rays x the sum of weight x L interpolated at a sensor's entries.")
        .def("direct_transmittance", &direct_transmittance_of<RayScene>,
             "points"_a, "normals"_a, "directions"_a,
             "(sensors, D) float32: max(0, n . d) x the transmittance of the ray from each sensor towards each "
             "direction out of the scene (0 blocked; glass factors), as illuminance's luminaires see it.")
        .def("set_luminaires", &RayScene::set_luminaires, "luminaires"_a,
             "Luminaires (list of Luminaire) that illuminance (in `direct`) and volume_probes add, exactly at "
             "their points; render does not show them.")
        .def("render",
             [](const RayScene& s, const std::vector<double>& pos, const std::vector<double>& fwd,
                const std::vector<double>& up, double fov, int width, int height, int samples) {
                 const Camera cam = camera_of(pos, fwd, up, fov, width, height);
                 std::vector<float> img;
                 {
                     nb::gil_scoped_release release;
                     img = s.render(cam, samples);
                 }
                 return to_numpy(std::move(img), {size_t(height), size_t(width), 3});
             },
             "position"_a, "forward"_a, "up"_a, "vertical_fov"_a, "width"_a, "height"_a, "samples"_a,
             "Pinhole render of exitant radiance (height, width, 3) float32; vertical_fov in degrees.")
        .def("probe",
             [](const RayScene& s, In<double> p, In<double> n, double max_distance) {
                 auto pts = vec3_rows(p, "points");
                 auto nrm = vec3_rows(n, "normals", long(pts.size()));
                 nb::gil_scoped_release release;
                 return s.probe(pts, nrm, max_distance);
             },
             "points"_a, "normals"_a, "max_distance"_a = 1e30,
             "Closest surface point within max_distance, facing along the normal when it is non-zero (ProbeResult).")
        .def("lift_samples", &lift_samples_of<RayScene>,
             "points"_a, "normals"_a, "epsilon"_a, "reach"_a, "anchors"_a.none() = nb::none(),
             "Lightmap sample points lifted epsilon (m) along their normals and moved out of geometry within "
             "reach (m) (LiftResult).")
        .def("volume_probes",
             [](const RayScene& s, In<double> p, int rays, uint64_t seed) {
                 auto pts = vec3_rows(p, "points");
                 nb::gil_scoped_release release;
                 return s.volume_probes(pts, rays, seed);
             },
             "points"_a, "rays"_a = 256, "seed"_a = 1,
             "Full-sphere radiance moments at points in empty space (VolumeProbes).")
        .def("illuminance",
             [](const RayScene& s, In<double> p, In<double> nrm, In<double> emitted, int rays, uint64_t seed,
                int emitter_samples) {
                 auto pts = vec3_rows(p, "points");
                 auto nor = vec3_rows(nrm, "normals", long(pts.size()));
                 auto le = vec3_rows(emitted, "emitted_radiance", long(s.size()));
                 nb::gil_scoped_release release;
                 return s.illuminance(pts, nor, le, IlluminanceOptions{rays, emitter_samples, seed});
             },
             "points"_a, "normals"_a, "emitted_radiance"_a, "rays"_a = 512, "seed"_a = 1, "emitter_samples"_a = 4,
             "Illuminance on small planes at points (n, 3) facing unit normals (n, 3), anywhere: the direct light "
             "of the patches whose emitted_radiance (patches, 3) W/(m^2 sr) is positive, exact where unoccluded, "
             "plus the indirect light of the rest by `rays` cosine-distributed hemisphere rays (Illuminance).")
        .def("ray_cast", &ray_cast_of<RayScene>, "origins"_a, "directions"_a, "First hits of rays (RayCastResult).")
        .def("camera_rays",
             [](const RayScene& s, const std::vector<double>& pos, const std::vector<double>& fwd,
                const std::vector<double>& up, double fov, int width, int height) {
                 const Camera cam = camera_of(pos, fwd, up, fov, width, height);
                 nb::gil_scoped_release release;
                 return s.camera_rays(cam);
             },
             "position"_a, "forward"_a, "up"_a, "vertical_fov"_a, "width"_a, "height"_a,
             "First hits of one ray through each pixel centre of the pinhole camera render uses, row 0 at the top "
             "(RayCastResult, height * width rows).");
    m.def("interpolate_corners",
          [](In<int32_t> nv, In<double> values, In<double> u, In<double> v) {
              const size_t n = nv.shape(0);
              if (values.ndim() != 3 || values.shape(0) != n || values.shape(1) != 4 || values.shape(2) != 3 ||
                  u.shape(0) != n || v.shape(0) != n)
                  throw std::invalid_argument("interpolate_corners: nv (n), values (n, 4, 3), u and v (n)");
              std::vector<double> out(n * 3);
              for (size_t i = 0; i < n; ++i) {
                  std::array<RGB, 4> c;
                  for (int k = 0; k < 4; ++k)
                      c[k] = RGB{values.data()[(i * 4 + k) * 3], values.data()[(i * 4 + k) * 3 + 1],
                                 values.data()[(i * 4 + k) * 3 + 2]};
                  const RGB r = interpolate_corners(nv.data()[i], c, u.data()[i], v.data()[i]);
                  out[i * 3] = r.x; out[i * 3 + 1] = r.y; out[i * 3 + 2] = r.z;
              }
              return to_numpy(std::move(out), {n, 3});
          },
          "nv"_a, "values"_a, "u"_a, "v"_a,
          "Values (n, 4, 3) at patch corners read at patch coordinates (u, v) by the render's rule: bilinear on "
          "quads, barycentric on triangles (nv 3 or 4 per row).");
}

}  // namespace hirad::py
