// The engine's option structs (pipeline/engine/engine.h), each constructible with keywords:
// MeshOptions(max_patch_area=0.0009, max_edge_length=0.038). Fields are read-write.
#include <nanobind/stl/string.h>

#include "pipeline/bindings/common.h"
#include "pipeline/engine/engine.h"

namespace hirad::py {

using namespace nb::literals;

void bind_options(nb::module_& m) {
    const MeshOptions mesh;
    nb::class_<MeshOptions>(m, "MeshOptions", "Flat meshing: every face is cut into patches no larger than these.")
        .def("__init__", [](MeshOptions* o, double a, double e, uint64_t n) { new (o) MeshOptions{a, e, n}; },
             "max_patch_area"_a = mesh.max_patch_area, "max_edge_length"_a = mesh.max_edge_length,
             "max_patches"_a = mesh.max_patches)
        .def_rw("max_patch_area", &MeshOptions::max_patch_area, "Largest patch area, m^2.")
        .def_rw("max_edge_length", &MeshOptions::max_edge_length, "Longest patch edge, m.")
        .def_rw("max_patches", &MeshOptions::max_patches,
                "The most patches meshing may make; more is refused (ValueError) before anything is built.");

    const FormFactorOptions ff;
    nb::class_<FormFactorOptions>(m, "FormFactorOptions", "Form factors of the flat method.")
        .def("__init__",
             [](FormFactorOptions* o, std::string method, int samples, int res, int pts, uint64_t seed) {
                 new (o) FormFactorOptions{std::move(method), samples, res, pts, seed};
             },
             "method"_a = ff.method, "samples"_a = ff.samples, "hemicube_resolution"_a = ff.hemicube_resolution,
             "hemicube_points"_a = ff.hemicube_points, "seed"_a = ff.seed)
        .def_rw("method", &FormFactorOptions::method,
                "'raycast' (stratified area sampling, Embree visibility) or 'hemicube' (rasterised hemicubes, "
                "rows made reciprocal: G_ij = (A_i F_ij + A_j F_ji) / 2).")
        .def_rw("samples", &FormFactorOptions::samples,
                "Raycast: stratified points per patch (also the progressive solver's row samples).")
        .def_rw("hemicube_resolution", &FormFactorOptions::hemicube_resolution,
                "Hemicube: pixels along the top face (even).")
        .def_rw("hemicube_points", &FormFactorOptions::hemicube_points, "Hemicube: hemicubes averaged per patch.")
        .def_rw("seed", &FormFactorOptions::seed, "Equal seeds give equal bits, whatever the thread count.");

    const SolveOptions so;
    nb::class_<SolveOptions>(m, "SolveOptions", "The solve of B = E + rho F B, or of a hierarchy's links.")
        .def("__init__",
             [](SolveOptions* o, std::string method, double tol, uint64_t maxit, uint64_t snap) {
                 new (o) SolveOptions{std::move(method), tol, maxit, snap};
             },
             "method"_a = so.method, "tolerance"_a = so.tolerance, "max_iterations"_a = so.max_iterations,
             "snapshot_every"_a = so.snapshot_every)
        .def_rw("method", &SolveOptions::method,
                "Flat: 'direct', 'jacobi', 'gauss_seidel', 'southwell', 'progressive'. Hierarchical in memory: "
                "'jacobi', 'gauss_seidel', 'southwell' (push-pull). Out of core: ignored (streaming block Southwell).")
        .def_rw("tolerance", &SolveOptions::tolerance, "Relative residual ||E - M B|| / ||E|| to stop at.")
        .def_rw("max_iterations", &SolveOptions::max_iterations, "Sweeps, or shots for shooting methods.")
        .def_rw("snapshot_every", &SolveOptions::snapshot_every,
                "Progressive only: a snapshot every this many shots (0: none).");

    const HierarchyOptions ho;
    nb::class_<HierarchyOptions>(m, "HierarchyOptions", "Hierarchical radiosity with clustering.")
        .def("__init__",
             [](HierarchyOptions* o, double eps, double min_area, int samples, uint64_t seed, int rounds,
                double relative, double spread, bool cluster_receivers, double closure_reflectance) {
                 new (o) HierarchyOptions{eps,      min_area, samples,           seed,
                                          rounds,   relative, spread,            cluster_receivers,
                                          closure_reflectance};
             },
             "epsilon"_a = ho.epsilon, "min_area"_a = ho.min_area, "samples"_a = ho.samples, "seed"_a = ho.seed,
             "max_rounds"_a = ho.max_rounds, "relative"_a = ho.relative, "spread"_a = ho.spread,
             "cluster_receivers"_a = ho.cluster_receivers, "closure_reflectance"_a = ho.closure_reflectance)
        .def_rw("epsilon", &HierarchyOptions::epsilon,
                "A link may carry at most epsilon x the scene's emitted power (W) before it is split.")
        .def_rw("min_area", &HierarchyOptions::min_area, "Elements are not split below this area, m^2.")
        .def_rw("samples", &HierarchyOptions::samples, "Point pairs per link estimate.")
        .def_rw("seed", &HierarchyOptions::seed, "Random seed of the link estimates.")
        .def_rw("max_rounds", &HierarchyOptions::max_rounds, "Refine -> solve rounds at most (>= 1).")
        .def_rw("relative", &HierarchyOptions::relative,
                "After round 1, links are also split above this fraction of their receiver's light (0: off).")
        .def_rw("spread", &HierarchyOptions::spread,
                "Close or partly visible links whose source's radiosity range could bias them by more than "
                "spread x epsilon's power are split at the source (0: off).")
        .def_rw("release_scene", &HierarchyOptions::release_scene,
                "Let the input faces go once the hierarchy holds its copy (a bake that will not mesh or solve "
                "again); what the patch arrays and light groups read of them is kept.")
        .def_rw("closure_reflectance", &HierarchyOptions::closure_reflectance,
                "Leaves of at least this reflectance have their form factors (what they inherit from their "
                "ancestors' links) normalised to their closure, the share of their hemisphere that meets a "
                "surface (Hierarchy::closure); 1: none.")
        .def_rw("cluster_receivers", &HierarchyOptions::cluster_receivers,
                "Clusters receive as well as send: faces of one orientation share a link's light as an "
                "element's children do; clusters of several orientations where every face sees the source "
                "from its front, by orientation (Hierarchy::reception); any cluster while the link carries "
                "little (its power bound, times the share its sharing may misplace, within kSlight of epsilon), "
                "then evenly if its faces face several ways. Links grow with the lighting, not with the faces; "
                "the face-by-face solvers (gauss_seidel, southwell) refuse such links.");

    const OutOfCoreOptions oc;
    nb::class_<OutOfCoreOptions>(m, "OutOfCoreOptions",
                                 "The hierarchical method with links streamed through a link store.")
        .def("__init__",
             [](OutOfCoreOptions* o, std::string store, uint64_t budget, uint32_t groups, double ckpt, bool resume,
                bool reuse) { new (o) OutOfCoreOptions{std::move(store), budget, groups, ckpt, resume, reuse}; },
             "store"_a = oc.store, "memory_budget"_a = oc.memory_budget, "group_faces"_a = oc.group_faces,
             "checkpoint_seconds"_a = oc.checkpoint_seconds, "resume"_a = oc.resume, "reuse_links"_a = oc.reuse_links)
        .def_rw("store", &OutOfCoreOptions::store, "The link store's directory; empty: links in memory.")
        .def_rw("memory_budget", &OutOfCoreOptions::memory_budget,
                "Bytes for the solver state and decoded chunks; 0: unlimited. The result does not depend on it.")
        .def_rw("group_faces", &OutOfCoreOptions::group_faces, "Input faces per source group (one chunk each).")
        .def_rw("checkpoint_seconds", &OutOfCoreOptions::checkpoint_seconds,
                "Write the running solve's state this often (0: never).")
        .def_rw("resume", &OutOfCoreOptions::resume, "Continue what a killed bake with the same inputs left.")
        .def_rw("reuse_links", &OutOfCoreOptions::reuse_links,
                "Solve on the store's final links (same geometry and settings, other materials).");

    const GatherOptions go;
    nb::class_<GatherOptions>(m, "GatherOptions", "The final gather at points after a hierarchical solve.")
        .def("__init__",
             [](GatherOptions* o, int rays, int cs, uint64_t seed, bool directional, double importance, double sb) {
                 new (o) GatherOptions{rays, cs, seed, directional, importance, sb};
             },
             "rays"_a = go.rays, "cluster_samples"_a = go.cluster_samples, "seed"_a = go.seed,
             "directional"_a = go.directional, "importance"_a = go.importance, "second_bounce"_a = go.second_bounce)
        .def_rw("rays", &GatherOptions::rays,
                "Visibility rays per partly visible element source (an emitting one: always 16, traced "
                "whatever its estimate saw).")
        .def_rw("cluster_samples", &GatherOptions::cluster_samples, "Faces drawn per cluster source.")
        .def_rw("seed", &GatherOptions::seed, "Seeds each point's samples with its index.")
        .def_rw("directional", &GatherOptions::directional,
                "Also PointValues.l0 and l1, the moments of the arriving radiance (the irradiance is unchanged).")
        .def_rw("importance", &GatherOptions::importance,
                "0: every link of a point's chain at the point; else the weakest links, together at most this share "
                "of a leaf's light, at their mean over the receiver (not emitters, not close sources; gather.h).")
        .def_rw("second_bounce", &GatherOptions::second_bounce,
                "0: off; else leaf sources nearer than this times their diagonal have their radiosity gathered at "
                "kernel-drawn points (gather.h: contacts).");

    const ReferenceOptions ro;
    nb::class_<ReferenceOptions>(m, "ReferenceOptions", "The Monte Carlo path-traced reference.")
        .def("__init__",
             [](ReferenceOptions* o, int paths, int mb, uint64_t seed) { new (o) ReferenceOptions{paths, mb, seed}; },
             "paths"_a = ro.paths, "min_bounces"_a = ro.min_bounces, "seed"_a = ro.seed)
        .def_rw("paths", &ReferenceOptions::paths, "Paths per point.")
        .def_rw("min_bounces", &ReferenceOptions::min_bounces, "Russian roulette starts after this many bounces.")
        .def_rw("seed", &ReferenceOptions::seed, "Random seed.");
}

}  // namespace hirad::py
