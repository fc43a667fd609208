// The engine's result structs, read-only: scalars and lists as they are, per-row values as
// numpy arrays (a fresh copy on every access; keep the array, not the attribute, in loops).
#include <nanobind/stl/vector.h>

#include "pipeline/bindings/common.h"
#include "pipeline/engine/engine.h"

namespace hirad::py {

template <class C>
auto rgb(std::vector<RGB> C::*p) {
    return [p](const C& c) { return rows3(c.*p); };
}
template <class C>
auto rgb1(RGB C::*p) {
    return [p](const C& c) {
        const RGB& v = c.*p;
        return to_numpy(std::vector<double>{v.x, v.y, v.z}, {3});
    };
}
template <class C, class T>
auto rows(std::vector<T> C::*p, size_t C::*count, std::initializer_list<size_t> tail_dims) {
    std::vector<size_t> tail(tail_dims);  // an initializer_list's array would not outlive this call
    return [p, count, tail](const C& c) {
        std::vector<size_t> shape{c.*count};
        shape.insert(shape.end(), tail.begin(), tail.end());
        auto* data = new std::vector<T>(c.*p);
        nb::capsule owner(data, [](void* q) noexcept { delete static_cast<std::vector<T>*>(q); });
        return Array<T>(data->data(), shape.size(), shape.data(), owner);
    };
}

// A vector moved into a numpy array (the struct's is left empty): large results held once.
template <class T>
Array<T> moved(std::vector<T>& v, std::vector<size_t> shape) {
    auto* data = new std::vector<T>(std::move(v));
    v = {};
    nb::capsule owner(data, [](void* q) noexcept { delete static_cast<std::vector<T>*>(q); });
    return Array<T>(data->data(), shape.size(), shape.data(), owner);
}

void bind_results(nb::module_& m) {
    nb::class_<Stats>(m, "Stats", "Counts of the scene and of what has been built from it so far.")
        .def_ro("input_faces", &Stats::input_faces, "Polygons given.")
        .def_ro("faces", &Stats::faces, "Usable faces after triangulation and cleaning.")
        .def_ro("degenerate_faces", &Stats::degenerate_faces, "Dropped: zero area.")
        .def_ro("nonfinite_faces", &Stats::nonfinite_faces, "Dropped: a NaN or infinite corner.")
        .def_ro("self_intersecting_faces", &Stats::self_intersecting_faces,
                "Dropped: polygons whose edges cross in their plane (bow ties, pentagrams).")
        .def_ro("triangulated_faces", &Stats::triangulated_faces, "Non-quads and non-planar or concave quads split.")
        .def_ro("nonmanifold_edges", &Stats::nonmanifold_edges, "Edges of more than two faces (kept, counted).")
        .def_ro("patches", &Stats::patches, "Current patches (flat patches, or published leaves).")
        .def_ro("links", &Stats::links, "Flat links stored.")
        .def_ro("link_bytes", &Stats::link_bytes, "Their memory, bytes.")
        .def_ro("rays", &Stats::rays, "Rays cast against the current patches.");

    nb::class_<LeafArrays>(m, "LeafArrays", "A hierarchical solve's leaves, published or not; row k is leaf k.")
        .def_prop_ro("mesh", arr(&LeafArrays::mesh), kOwned, "(n) input mesh index.")
        .def_prop_ro("area", arr(&LeafArrays::area), kOwned, "(n) m^2.");
    nb::class_<PatchArrays>(m, "PatchArrays", "The current patches as arrays; row k is patch k.")
        .def_ro("count", &PatchArrays::count)
        .def_prop_ro("corners", rows(&PatchArrays::corners, &PatchArrays::count, {4, 3}), kOwned,
                     "(n, 4, 3) m; triangles repeat corner 2 as corner 3.")
        .def_prop_ro("uv", rows(&PatchArrays::uv, &PatchArrays::count, {4, 2}), kOwned,
                     "(n, 4, 2) texture coordinates.")
        .def_prop_ro("area", arr(&PatchArrays::area), kOwned, "(n) m^2.")
        .def_prop_ro("normal", rows(&PatchArrays::normal, &PatchArrays::count, {3}), kOwned, "(n, 3) unit normals.")
        .def_prop_ro("centroid", rows(&PatchArrays::centroid, &PatchArrays::count, {3}), kOwned, "(n, 3) m.")
        .def_prop_ro("reflectance", rows(&PatchArrays::reflectance, &PatchArrays::count, {3}), kOwned, "(n, 3).")
        .def_prop_ro("emission", rows(&PatchArrays::emission, &PatchArrays::count, {3}), kOwned,
                     "(n, 3) self-emitted exitance, W/m^2.")
        .def_prop_ro("direct", rows(&PatchArrays::direct, &PatchArrays::count, {3}), kOwned,
                     "(n, 3) the luminaires' irradiance, mean over the patch, W/m^2 (the solvers' source term is "
                     "emission + reflectance x direct).")
        .def_prop_ro("nv", arr(&PatchArrays::nv), kOwned, "(n) 3 or 4 corners.")
        .def_prop_ro("mesh", arr(&PatchArrays::mesh), kOwned, "(n) input mesh index.")
        .def_prop_ro("face", arr(&PatchArrays::face), kOwned, "(n) engine face (after triangulation).")
        .def_prop_ro("source_face", arr(&PatchArrays::source_face), kOwned, "(n) authored face within its mesh.")
        .def_prop_ro("transmittance", arr(&PatchArrays::transmittance), kOwned,
                     "(n) glazing: the normal transmittance of direct light (0: opaque).")
        .def("take", [](PatchArrays& a) {
            const size_t n = a.count;
            nb::dict d;
            d["corners"] = moved(a.corners, {n, 4, 3}), d["uv"] = moved(a.uv, {n, 4, 2});
            d["area"] = moved(a.area, {n}), d["normal"] = moved(a.normal, {n, 3});
            d["centroid"] = moved(a.centroid, {n, 3}), d["reflectance"] = moved(a.reflectance, {n, 3});
            d["emission"] = moved(a.emission, {n, 3}), d["direct"] = moved(a.direct, {n, 3});
            d["nv"] = moved(a.nv, {n}), d["mesh"] = moved(a.mesh, {n}), d["face"] = moved(a.face, {n});
            d["source_face"] = moved(a.source_face, {n}), d["transmittance"] = moved(a.transmittance, {n});
            a.count = 0;
            return d;
        }, "Every field as {name: array}, moved out (the struct is left with none): the patches held once, "
           "not twice (hirad.engine.patch_dict).");

    nb::class_<FlatSolveResult>(m, "FlatSolveResult", "A flat solve.")
        .def_prop_ro("radiosity", rgb(&FlatSolveResult::radiosity), kOwned, "(n, 3) B per patch, W/m^2.")
        .def_ro("iterations", &FlatSolveResult::iterations, "Sweeps, or shots.")
        .def_ro("residual", &FlatSolveResult::residual, "Final relative residual.")
        .def_ro("converged", &FlatSolveResult::converged)
        .def_ro("residual_history", &FlatSolveResult::residual_history, "Residual after each iteration.")
        .def_ro("rows_computed", &FlatSolveResult::rows_computed, "Progressive: coupling rows computed on the fly.");

    nb::class_<Transport>(m, "Transport", "The two terms of the flat energy balance, per patch.")
        .def_prop_ro("irradiance", rgb(&Transport::irradiance), kOwned, "(n, 3) H = F B, W/m^2.")
        .def_prop_ro("escaped", rgb(&Transport::escaped), kOwned,
                     "(n, 3) (A_i - sum_j G_ij) B_i, W: power that leaves and reaches no patch (signed).");

    nb::class_<SpillLog>(m, "SpillLog", "What a worker of a distributed refinement made of its source groups.")
        .def_ro("begin", &SpillLog::begin)
        .def_ro("end", &SpillLog::end)
        .def_ro("nodes", &SpillLog::nodes, "Nodes of the hierarchy the worker started from.")
        .def_prop_ro("subdivisions", [](const SpillLog& s) { return s.log.size(); }, "Elements it subdivided.")
        .def_prop_ro("link_estimates", [](const SpillLog& s) { return s.stats.evaluated; })
        .def_prop_ro("splits", [](const SpillLog& s) { return s.stats.split; })
        .def_prop_ro("rays", [](const SpillLog& s) { return s.stats.rays; })
        .def_ro("held", &SpillLog::held, "The most links it held at once.")
        .def_ro("group_seconds", &SpillLog::group_seconds, "Per group: wall time of its refinement, s.")
        .def_ro("group_links", &SpillLog::group_links, "Per group: links kept.");

    nb::class_<StreamingStats>(m, "StreamingStats", "The last streaming (out-of-core) solve.")
        .def_ro("rounds", &StreamingStats::rounds)
        .def_ro("groups_shot", &StreamingStats::groups_shot)
        .def_ro("links_shot", &StreamingStats::links_shot)
        .def_ro("chunk_reads", &StreamingStats::chunk_reads, "Chunks read and decoded.")
        .def_ro("chunk_hits", &StreamingStats::chunk_hits, "Chunks shot from memory.")
        .def_ro("resident_bytes_peak", &StreamingStats::resident_bytes_peak)
        .def_ro("state_bytes", &StreamingStats::state_bytes)
        .def_ro("largest_chunk_bytes", &StreamingStats::largest_chunk_bytes)
        .def_ro("chunks_in_flight", &StreamingStats::chunks_in_flight)
        .def_ro("minimum_budget", &StreamingStats::minimum_budget, "The smallest memory budget taken, bytes.")
        .def_ro("decoded_bytes", &StreamingStats::decoded_bytes)
        .def_ro("checkpoints", &StreamingStats::checkpoints)
        .def_ro("resumed", &StreamingStats::resumed)
        .def_ro("read_wait_seconds", &StreamingStats::read_wait_seconds)
        .def_ro("shoot_seconds", &StreamingStats::shoot_seconds)
        .def_ro("checkpoint_write_seconds", &StreamingStats::checkpoint_write_seconds,
                "Time spent writing checkpoints, s.");

    nb::class_<GroupSolution>(m, "GroupSolution",
                              "One light group solved alone on the shared links, per patch or leaf.")
        .def_prop_ro("radiosity", rgb(&GroupSolution::radiosity), kOwned, "(n, 3) B_g, W/m^2.")
        .def_prop_ro("irradiance", rgb(&GroupSolution::irradiance), kOwned,
                     "(n, 3) irradiance from the surfaces, W/m^2 (add `direct` for the total).")
        .def_prop_ro("direct", rgb(&GroupSolution::direct), kOwned, "(n, 3) the group's luminaires' irradiance, W/m^2.")
        .def_ro("iterations", &GroupSolution::iterations)
        .def_ro("residual", &GroupSolution::residual)
        .def_ro("converged", &GroupSolution::converged)
        .def_ro("seconds", &GroupSolution::seconds, "Wall time of its solve (with its direct light), s.");

    using H = HierarchicalResult;
    nb::class_<H>(m, "HierarchicalResult",
                  "A hierarchical solve. Per-leaf arrays follow the leaves that use_leaves_as_patches() makes the "
                  "engine's patches.")
        .def_prop_ro("radiosity", rgb(&H::radiosity), kOwned, "(leaves, 3) B, W/m^2.")
        .def_prop_ro("irradiance", rgb(&H::irradiance), kOwned, "(leaves, 3) H, W/m^2.")
        .def_prop_ro("escaped", rgb(&H::escaped), kOwned, "(leaves, 3) B A (open - outgoing fraction), W, signed.")
        .def_prop_ro("open", arr(&H::open), kOwned,
                     "(leaves,) the share of each leaf's area not inside other geometry; its B, H and direct light are "
                     "that part's (power: times open x area).")
        .def_ro("residual", &H::residual)
        .def_ro("converged", &H::converged)
        .def_ro("iterations", &H::iterations, "All rounds.")
        .def_ro("residual_history", &H::residual_history, "In memory: all rounds; out of core: the last solve.")
        .def_ro("links", &H::links, "Final links.")
        .def_ro("groups", &H::groups, "One GroupSolution per light group (Engine.set_light_groups), per leaf.")
        .def_ro("elements", &H::elements, "Leaves.")
        .def_ro("nodes", &H::nodes)
        .def_ro("clusters", &H::clusters)
        .def_ro("links_on_clusters", &H::links_on_clusters,
                "Final links that end on a cluster (hierarchy.cluster_receivers); -1 out of core (not counted).")
        .def_ro("balance_splits", &H::balance_splits, "Leaves split for the 2:1 balance of the display.")
        .def_ro("limited_leaves", &H::limited_leaves,
                "Leaves whose gathered light the last solve scaled to rho F = 0.999 (their link estimates summed "
                "above the hemisphere with a reflectance near 1; hierarchical_solver.h gain limit).")
        .def_ro("normalised_leaves", &H::normalised_leaves,
                "Leaves of a reflectance near 1 whose inherited light the last solve scaled so that their form factors "
                "sum to their measured closure (hierarchy.h Hierarchy::closure).")
        .def_ro("rounds", &H::rounds, "The final round.")
        .def_ro("settled", &H::settled, "Refinement stopped splitting (else max_rounds ended it).")
        .def_ro("face_bytes", &H::face_bytes, "Bytes of the hierarchy's input faces (FaceTable).")
        .def_ro("bvh_bytes", &H::bvh_bytes, "Bytes Embree holds for its scene over the faces, after the build.")
        .def_ro("bvh_peak_bytes", &H::bvh_peak_bytes, "The most bytes Embree held while building it.")
        .def_ro("links_per_round", &H::links_per_round)
        .def_ro("splits_per_round", &H::splits_per_round,
                "In memory: each refinement after the first (a last 0 when settled); out of core: each pass that "
                "made a round, the first included.")
        .def_ro("refine_seconds", &H::refine_seconds)
        .def_ro("solve_seconds", &H::solve_seconds)
        .def_ro("link_estimates", &H::link_estimates, "Form factor estimates made by refinement.")
        .def_ro("rays", &H::rays, "Rays cast over the hierarchy's faces.")
        .def_ro("epsilon_watts", &H::epsilon_watts, "The split threshold, W.")
        .def_ro("out_of_core", &H::out_of_core)
        .def_ro("reused_links", &H::reused_links)
        .def_ro("resumed_from_round", &H::resumed_from_round, "0: started fresh.")
        .def_ro("store_bytes", &H::store_bytes, "Compressed link payload of the final round.")
        .def_ro("transport_bytes", &H::transport_bytes)
        .def_ro("peak_refine_links", &H::peak_refine_links)
        .def_ro("source_groups", &H::source_groups)
        .def_ro("streaming", &H::streaming, "The last streaming solve (out of core).")
        .def_prop_ro("glass_back_entered", rgb1(&H::glass_back_entered), kOwned,
                     "(3,) the backs of glazed faces (unpublished): the direct light they reflect, rho D A, W.")
        .def_prop_ro("glass_back_absorbed", rgb1(&H::glass_back_absorbed), kOwned,
                     "(3,) the backs of glazed faces: what they take of the interreflected light (absorbed or let "
                     "through), (1 - rho) H A, W.")
        .def_prop_ro("glass_back_escaped", rgb1(&H::glass_back_escaped), kOwned,
                     "(3,) the backs of glazed faces: their light that reaches no surface, W, signed.")
        .def_ro("merge_seconds", &H::merge_seconds,
                "Distributed: per refinement done by workers, the driver's merge of their spills, s.")
        .def_prop_ro("link_receiver", arr(&H::link_receiver), kOwned)
        .def_prop_ro("link_source", arr(&H::link_source), kOwned)
        .def_prop_ro("link_coupling", arr(&H::link_coupling), kOwned, "G, m^2.")
        .def_prop_ro("link_unoccluded", arr(&H::link_unoccluded), kOwned, "G without visibility, m^2.")
        .def_prop_ro("node_parent", arr(&H::node_parent), kOwned, "-1 at the root.")
        .def_prop_ro("node_area", arr(&H::node_area), kOwned)
        .def_prop_ro("node_cluster", arr(&H::node_cluster), kOwned)
        .def_prop_ro("leaf_node", arr(&H::leaf_node), kOwned);

    nb::class_<PointValues>(m, "PointValues", "Values at query points on the surfaces.")
        .def_prop_ro("patch", arr(&PointValues::patch), kOwned, "(n) the patch of each point (-1: none within reach).")
        .def_prop_ro("irradiance", rgb(&PointValues::irradiance), kOwned, "(n, 3) W/m^2.")
        .def_prop_ro("radiance", rgb(&PointValues::radiance), kOwned, "(n, 3) exitant, W/(m^2 sr).")
        .def_prop_ro("l0", rgb(&PointValues::l0), kOwned,
                     "(n, 3) with GatherOptions(directional=True), else (0, 3): integral of the arriving radiance "
                     "over the hemisphere, W/m^2 per channel.")
        .def_prop_ro("l1", [](const PointValues& v) {
            std::vector<double> flat(v.l1.size() * 9);
            for (size_t q = 0; q < v.l1.size(); ++q)
                for (int c = 0; c < 3; ++c)
                    for (int a = 0; a < 3; ++a) flat[9 * q + 3 * c + a] = v.l1[q][a][c];
            return to_numpy(std::move(flat), {v.l1.size(), 3, 3});
        }, kOwned, "(n, 3, 3) [q, channel, axis] with GatherOptions(directional=True), else (0, 3, 3): integral of "
                   "the arriving radiance times the unit direction w (world axes), W/m^2; normal . l1 = irradiance (a little "
                   "above it where a partly visible source straddles the point's horizon: gather.h).");

    nb::class_<ReferenceResult>(m, "ReferenceResult", "The Monte Carlo reference at points.")
        .def_prop_ro("radiance", rgb(&ReferenceResult::radiance), kOwned, "(n, 3) exitant, W/(m^2 sr).")
        .def_prop_ro("standard_error", rgb(&ReferenceResult::standard_error), kOwned, "(n, 3) of radiance.");
}

}  // namespace hirad::py
