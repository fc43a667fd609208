// hirad._engine.Engine: the engine (pipeline/engine/engine.h) bound. Arrays in are numpy
// (checked for shape here), results are the engine's result structs (results.cpp). Long calls
// run on a worker thread; `progress` callables are called with the GIL held, about every 100 ms.
#include <nanobind/stl/function.h>
#include <nanobind/stl/optional.h>
#include <nanobind/stl/string.h>
#include <nanobind/stl/vector.h>

#include <algorithm>
#include <mutex>
#include <optional>

#include "pipeline/bindings/common.h"
#include "pipeline/engine/engine.h"

namespace hirad::py {

using namespace nb::literals;
namespace {

SceneInput scene_input(In<double> points, In<int32_t> counts, In<int32_t> indices, In<int32_t> face_mesh,
                                    In<int32_t> face_source, In<double> reflectance, In<double> emission,
                       std::optional<In<double>> corner_uv, std::optional<In<double>> transmittance = std::nullopt) {
    require_shape(points, {-1, 3}, "points");
    require_shape(counts, {-1}, "face_vertex_counts");
    const long nf = long(counts.shape(0));
    require_shape(indices, {-1}, "face_vertex_indices");
    require_shape(face_mesh, {nf}, "face_mesh");
    require_shape(face_source, {nf}, "face_source");
    require_shape(reflectance, {nf, 3}, "reflectance");
    require_shape(emission, {nf, 3}, "emission");
    SceneInput in;
    in.points = points.data(), in.num_points = points.shape(0);
    in.face_vertex_counts = counts.data(), in.num_faces = counts.shape(0);
    in.face_vertex_indices = indices.data(), in.face_mesh = face_mesh.data(), in.face_source = face_source.data();
    in.face_reflectance = reflectance.data(), in.face_emission = emission.data();
    if (corner_uv) {
        require_shape(*corner_uv, {long(indices.shape(0)), 2}, "corner_uv");
        in.corner_uv = corner_uv->data();
    }
    if (transmittance) {
        require_shape(*transmittance, {nf}, "transmittance");
        in.face_transmittance = transmittance->data();
    }
    return in;
}

void compute_links(Engine& e, const FormFactorOptions& o, nb::object progress) {
    std::atomic<uint64_t> done{0};
    run_reporting([&] { e.compute_links(o, [&](uint64_t d) {
                      uint64_t seen = done.load();
                      while (seen < d && !done.compare_exchange_weak(seen, d)) {}
                  }); },
                  [&] { if (!progress.is_none()) progress(done.load()); });
}

FlatSolveResult solve(Engine& e, const SolveOptions& o, const FormFactorOptions& ff, nb::object snapshot,
                      nb::object progress) {
    std::atomic<uint64_t> iteration{0};
    std::atomic<double> residual{1.0};
    std::mutex mutex;
    std::vector<std::pair<uint64_t, std::vector<RGB>>> snaps;
    SnapshotFn on_snapshot;
    if (!snapshot.is_none())
        on_snapshot = [&](uint64_t shot, const std::vector<RGB>& display) {
            std::lock_guard<std::mutex> lock(mutex);
            snaps.emplace_back(shot, display);
        };
    FlatSolveResult r;
    FlatProgressFn on_progress = [&](uint64_t it, double res) { iteration = it; residual = res; };
    run_reporting([&] { r = e.solve(o, ff, on_snapshot, on_progress); },
                  [&] {
                      std::vector<std::pair<uint64_t, std::vector<RGB>>> pending;
                      {
                          std::lock_guard<std::mutex> lock(mutex);
                          pending.swap(snaps);
                      }
                      for (auto& [shot, display] : pending) snapshot(shot, rows3(display));
                      if (!progress.is_none()) progress(iteration.load(), residual.load());
                  });
    return r;
}

// Progress of the hierarchical solves: progress(round, links, iteration, residual,
// groups_linked, groups) (RoundProgress); `serve` is ticked too (RemoteCall).
template <typename Call, typename Serve = void (*)()>
HierarchicalResult solve_rounds(nb::object progress, Call&& call, Serve serve = [] {}) {
    std::atomic<uint64_t> round{0}, links{0}, iteration{0}, linked{0}, groups{0};
    std::atomic<double> residual{1.0};
    RoundProgressFn fn = [&](const RoundProgress& p) {
        round = uint64_t(p.round); links = p.links; iteration = p.iteration; residual = p.residual;
        linked = p.groups_linked; groups = p.groups;
    };
    HierarchicalResult r;
    run_reporting([&] { r = call(fn); }, [&] {
        if (!progress.is_none())
            progress(round.load(), links.load(), iteration.load(), residual.load(), linked.load(), groups.load());
        serve();
    });
    return r;
}

std::vector<RGB> rgb_rows(const In<double>& a, size_t n, const char* what) { return vec3_rows(a, what, long(n)); }

}  // namespace

void bind_engine(nb::module_& m) {
    nb::class_<Engine>(m, "Engine",
                       "One scene through the pipeline: scene -> patches -> links -> solution (flat or hierarchical).")
        .def("__init__",
             [](Engine* self, In<double> p, In<int32_t> c, In<int32_t> i, In<int32_t> fm, In<int32_t> fs,
                In<double> rho, In<double> emit, std::optional<In<double>> uv, std::optional<In<double>> tau,
                std::optional<In<double>> angular) {
                 new (self) Engine(scene_input(p, c, i, fm, fs, rho, emit, uv, tau), i.shape(0));
                 if (angular) {
                     require_shape(*angular, {-1}, "glass_angular");
                     self->set_glass_angular(std::vector<double>(angular->data(), angular->data() + angular->shape(0)));
                 }
             },
             "points"_a, "face_vertex_counts"_a, "face_vertex_indices"_a, "face_mesh"_a, "face_source"_a,
             "reflectance"_a, "emission"_a, "corner_uv"_a.none() = nb::none(), "transmittance"_a.none() = nb::none(),
             "glass_angular"_a.none() = nb::none(),
             "The scene as flat arrays in metres: points (P, 3), counts (F), indices (sum of counts), per face "
             "mesh, authored face, reflectance (F, 3), emission (F, 3) W/m^2, optional corner_uv (sum of counts, 2); "
             "glazing: optional transmittance (F) of direct light at normal incidence (0 opaque, reflectance + "
             "transmittance <= 1) and glass_angular, the relative transmittance at evenly spaced cosines 0 .. 1 "
             "(visibility.h).")
        .def("stats", &Engine::stats, "Counts of the scene and of what is built (Stats).")
        .def("set_luminaires", &Engine::set_luminaires, "luminaires"_a,
             "Luminaires (list of Luminaire) whose light reaches the surfaces as an exact first bounce (their "
             "direct irradiance, re-emitted as rho x direct); replaces earlier ones; lights the flat patches now, a "
             "hierarchical solve from its start.")
        .def_prop_ro("luminaire_flux", [](const Engine& e) { return rows3({e.luminaire_flux()}); }, kOwned,
                     "(1, 3) the luminaires' total exact flux, lm (or W).")
        .def("set_light_groups",
             [](Engine& e, const std::vector<std::vector<uint32_t>>& meshes,
                const std::vector<std::vector<Luminaire>>& luminaires) {
                 if (meshes.size() != luminaires.size())
                     throw nb::value_error("light groups: one list of meshes and one of luminaires per group");
                 std::vector<LightGroup> g(meshes.size());
                 for (size_t k = 0; k < g.size(); ++k) g[k] = LightGroup{meshes[k], luminaires[k]};
                 e.set_light_groups(std::move(g));
             },
             "meshes"_a, "luminaires"_a,
             "Light groups (per group: the input meshes whose faces' emission it holds, and its luminaires); "
             "replaces earlier ones. Each group is then solved alone on the shared links: solve_groups (flat), "
             "HierarchicalResult.groups (hierarchical, in memory and out of core).")
        .def_prop_ro("num_light_groups", &Engine::num_light_groups)
        .def("solve_groups",
             [](Engine& e, const SolveOptions& o, const FormFactorOptions& ff) {
                 std::vector<GroupSolution> r;
                 run_released([&] { r = e.solve_groups(o, ff); });
                 return r;
             },
             "options"_a, "form_factors"_a = FormFactorOptions{},
             "Flat: each light group solved alone on the links (list of GroupSolution, per patch).")
        .def("mesh", &Engine::mesh, "options"_a, "Flat meshing: cuts every face into patches (MeshOptions).")
        .def_prop_ro("num_patches", &Engine::num_patches)
        .def("patch_arrays", &Engine::patch_arrays, "The current patches (PatchArrays).")
        .def("compute_links", &compute_links, "options"_a, "progress"_a.none() = nb::none(),
             "Flat links between every pair of patches that exchange light; progress(rows_done).")
        .def("solve", &solve, "options"_a, "form_factors"_a = FormFactorOptions{}, "snapshot"_a.none() = nb::none(),
             "progress"_a.none() = nb::none(),
             "Flat solve (FlatSolveResult); progressive solves sample rows with form_factors' samples and seed "
             "and call snapshot(shot, displayed radiosity (n, 3)); progress(iteration, residual).")
        .def("transport",
             [](const Engine& e, In<double> b, const FormFactorOptions& ff) {
                 std::vector<RGB> v = rgb_rows(b, e.num_patches(), "radiosity");
                 Transport t;
                 run_released([&] { t = e.transport(v, ff); });
                 return t;
             },
             "radiosity"_a, "form_factors"_a = FormFactorOptions{},
             "Irradiance H = F B and escaped power per patch (Transport); without links the couplings are sampled.")
        .def("residual_of",
             [](const Engine& e, In<double> b) { return e.residual_of(rgb_rows(b, e.num_patches(), "radiosity")); },
             "radiosity"_a, "Relative residual ||E - M B|| / ||E|| of B over the flat links.")
        .def("form_factor", &Engine::form_factor, "i"_a, "j"_a, "samples"_a, "seed"_a, "Ray-cast F_ij.")
        .def("hemicube_row",
             [](const Engine& e, uint32_t i, int res, int pts) {
                 std::vector<double> row = e.hemicube_row(i, res, pts);
                 const size_t n = row.size();
                 return to_numpy(std::move(row), {n});
             },
             "i"_a, "resolution"_a, "points"_a, "Dense hemicube row F_i (n).")
        .def("rays_cast", &Engine::rays_cast)
        .def("solve_hierarchical",
             [](Engine& e, const HierarchyOptions& h, const SolveOptions& s, nb::object progress) {
                 return solve_rounds(progress,
                                     [&](const RoundProgressFn& fn) { return e.solve_hierarchical(h, s, fn); });
             },
             "hierarchy"_a, "solve"_a = SolveOptions{"jacobi"}, "progress"_a.none() = nb::none(),
             "Refine -> solve rounds in memory (HierarchicalResult); progress(round, links, iteration, residual, "
             "groups_linked, groups) (groups 0). The patches stay as they were until use_leaves_as_patches().")
        .def("solve_out_of_core",
             [](Engine& e, const HierarchyOptions& h, const SolveOptions& s, const OutOfCoreOptions& c,
                nb::object progress, nb::object refine_groups) {
                 if (refine_groups.is_none())
                     return solve_rounds(progress,
                                         [&](const RoundProgressFn& fn) { return e.solve_out_of_core(h, s, c, fn); });
                 RemoteCall call;
                 RemoteRefineFn remote = [&](int round, uint32_t groups) { call.run(round, groups); };
                 return solve_rounds(
                     progress, [&](const RoundProgressFn& fn) { return e.solve_out_of_core(h, s, c, fn, remote); },
                     [&] { call.serve(refine_groups); });
             },
             "hierarchy"_a, "solve"_a = SolveOptions{}, "out_of_core"_a = OutOfCoreOptions{},
             "progress"_a.none() = nb::none(), "refine_groups"_a.none() = nb::none(),
             "Refine -> solve rounds streamed through a link store, each solved by streaming block Southwell "
             "(HierarchicalResult); resumable. The patches stay as they were until use_leaves_as_patches(). "
             "progress(round, links, iteration, residual, groups_linked, groups): while a round is linked, the "
             "source groups done and in all and the links kept so far; groups 0 while solving. refine_groups(round, "
             "groups): distributed link generation; called (with the GIL) for every "
             "refinement, it has workers run refine_groups on ranges covering [0, groups) and returns when all are "
             "complete; the result is the same bits as without.")
        .def("refine_groups",
             [](Engine& e, const HierarchyOptions& h, const OutOfCoreOptions& c, int round, uint32_t begin,
                uint32_t end) {
                 SpillLog log;
                 run_released([&] { log = e.refine_groups(h, c, round, begin, end); });
                 return log;
             },
             "hierarchy"_a, "out_of_core"_a, "round"_a, "begin"_a, "end"_a,
             "A worker's share of a distributed out-of-core bake: round `round`'s refinement of source groups "
             "[begin, end) from the link store's state, written to its spill directory (SpillLog). The scene, "
             "luminaires and options must be the driver's.")
        .def("use_leaves_as_patches", &Engine::use_leaves_as_patches, "release_hierarchy"_a = false,
             "Makes the last hierarchical solve's leaves the patches, in the order of its per-leaf arrays (engine.h).")
        .def_prop_ro("leaves_are_patches", &Engine::leaves_are_patches)
        .def("leaf_arrays", &Engine::leaf_arrays, "The last hierarchical solve's leaves' meshes and areas (LeafArrays).")
        .def("release_hierarchy", &Engine::release_hierarchy, "Lets go of the solved hierarchy (engine.h).")
        .def_prop_ro("has_hierarchy", &Engine::has_hierarchy)
        .def("release_scene", &Engine::release_scene, "Lets go of the input faces (engine.h).")
        .def("release_patches", &Engine::release_patches, "Lets go of the patches, their BVH, the display mesh.")
        .def("display_mesh", [](Engine& e, double crease) { return e.display_mesh(crease); }, "crease_angle"_a,
             "Welded display mesh of the patches (DisplayMesh), kept for vertex_values.")
        .def("vertex_values",
             [](const Engine& e, In<double> v) {
                 return rows3(e.vertex_values(rgb_rows(v, e.num_patches(), "patch_values")));
             },
             "patch_values"_a, "Per-patch values (n, 3) reconstructed at the display mesh's points (points, 3).")
        .def("gather",
             [](Engine& e, In<double> p, In<double> n, const GatherOptions& o, double max_distance, int group) {
                 auto pts = vec3_rows(p, "points");
                 auto nrm = vec3_rows(n, "normals", long(pts.size()));
                 nb::gil_scoped_release release;
                 return e.gather(pts, nrm, o, max_distance, group);
             },
             "points"_a, "normals"_a, "options"_a = GatherOptions{}, "max_distance"_a = 1e30, "group"_a = -1,
             "Final gather after a hierarchical solve (PointValues); needs use_leaves_as_patches(). group >= 0: "
             "that light group's solution alone.")
        .def("lift_samples", &lift_samples_of<Engine>, "points"_a, "normals"_a, "epsilon"_a, "reach"_a,
             "anchors"_a.none() = nb::none(),
             "SurfaceField.lift_samples against the current patches and their BVH (LiftResult).")
        .def("ray_cast", &ray_cast_of<Engine>, "origins"_a, "directions"_a, "First hits of rays (RayCastResult).")
        .def("direct_transmittance", &direct_transmittance_of<Engine>, "points"_a, "normals"_a, "directions"_a,
             "(P, D) float32: max(0, n . d) x the transmittance of the ray from each point towards each unit "
             "direction out of the scene (0 blocked; glass factors), over the current patches.")
        .def("gather_flat",
             [](const Engine& e, In<double> p, In<double> n, In<double> b, int rays, uint64_t seed) {
                 auto pts = vec3_rows(p, "points");
                 auto nrm = vec3_rows(n, "normals", long(pts.size()));
                 auto rad = rgb_rows(b, e.num_patches(), "radiosity");
                 nb::gil_scoped_release release;
                 return e.gather_flat(pts, nrm, rad, rays, seed);
             },
             "points"_a, "normals"_a, "radiosity"_a, "rays"_a = 4, "seed"_a = 1,
             "Final gather from a flat solution B (PointValues): every patch, O(patches) a point.")
        .def("reference",
             [](const Engine& e, In<int32_t> patch, In<double> st, const ReferenceOptions& o) {
                 require_shape(patch, {-1}, "patch");
                 require_shape(st, {long(patch.shape(0)), 2}, "st");
                 std::vector<uint32_t> ids(patch.shape(0));
                 std::vector<Vec2> coords(ids.size());
                 for (size_t q = 0; q < ids.size(); ++q) {
                     if (patch.data()[q] < 0) throw nb::index_error("patch index out of range");
                     ids[q] = uint32_t(patch.data()[q]);
                     coords[q] = {st.data()[2 * q], st.data()[2 * q + 1]};
                 }
                 ReferenceResult r;
                 run_released([&] { r = e.reference(ids, coords, o); });
                 return r;
             },
             "patch"_a, "st"_a, "options"_a = ReferenceOptions{},
             "Monte Carlo exitant radiance at (s, t) of the given patches (ReferenceResult).")
        .def("reference_at",
             [](const Engine& e, In<double> p, In<double> n, const ReferenceOptions& o, double max_distance) {
                 auto pts = vec3_rows(p, "points");
                 auto nrm = vec3_rows(n, "normals", long(pts.size()));
                 ReferenceResult r;
                 run_released([&] { r = e.reference_at(pts, nrm, o, max_distance); });
                 return r;
             },
             "points"_a, "normals"_a, "options"_a = ReferenceOptions{}, "max_distance"_a = 1e30,
             "The reference at surface points, each on the closest patch facing along its normal within "
             "max_distance (ValueError otherwise).");
    bind_display(m);
}

}  // namespace hirad::py
