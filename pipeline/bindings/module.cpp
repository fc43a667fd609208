// The Python face of the engine (module hirad._engine). Arrays cross as numpy arrays; long
// stages run on a worker thread while the calling thread, holding the GIL, reports progress
// and lets Ctrl-C through.
#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>
#include <nanobind/stl/function.h>
#include <nanobind/stl/optional.h>
#include <nanobind/stl/pair.h>
#include <nanobind/stl/string.h>
#include <nanobind/stl/vector.h>

#include <tbb/global_control.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cstring>
#include <optional>

#include <atomic>
#include <chrono>
#include <memory>
#include <mutex>
#include <thread>

#include "formats/exr.h"
#include "pipeline/geometry/formfactors.h"
#include "pipeline/geometry/hemicube.h"
#include "pipeline/hierarchy/gather.h"
#include "pipeline/hierarchy/hierarchical_solver.h"
#include "pipeline/hierarchy/hierarchy.h"
#include "pipeline/flat/links.h"
#include "pipeline/outofcore/outofcore.h"
#include "pipeline/geometry/patches.h"
#include "pipeline/outputs/reconstruct.h"
#include "pipeline/reference/reference.h"
#include "pipeline/hierarchy/refine.h"
#include "pipeline/outputs/render.h"
#include "pipeline/geometry/scene.h"
#include "pipeline/flat/solvers.h"
#include "pipeline/geometry/visibility.h"

namespace nb = nanobind;
using namespace nb::literals;
using namespace hirad;

namespace {

template <typename T>
using In = nb::ndarray<const T, nb::c_contig, nb::device::cpu>;
using Out = nb::ndarray<nb::numpy, double>;

template <typename T>
nb::ndarray<nb::numpy, T> to_numpy(std::vector<T>&& v, std::initializer_list<size_t> shape) {
    auto* data = new std::vector<T>(std::move(v));
    nb::capsule owner(data, [](void* p) noexcept { delete static_cast<std::vector<T>*>(p); });
    return nb::ndarray<nb::numpy, T>(data->data(), shape.size(), shape.begin(), owner);
}

Out rgb_array(const std::vector<RGB>& v) {
    std::vector<double> flat(v.size() * 3);
    for (size_t i = 0; i < v.size(); ++i)
        for (int c = 0; c < 3; ++c) flat[3 * i + c] = v[i][c];
    return to_numpy(std::move(flat), {v.size(), 3});
}

std::vector<RGB> rgb_vector(const In<double>& a, size_t n, const char* what) {
    if (a.ndim() != 2 || a.shape(0) != n || a.shape(1) != 3)
        throw std::invalid_argument(std::string(what) + ": expected shape (" + std::to_string(n) + ", 3)");
    std::vector<RGB> v(n);
    for (size_t i = 0; i < n; ++i) v[i] = {a.data()[3 * i], a.data()[3 * i + 1], a.data()[3 * i + 2]};
    return v;
}

std::unique_ptr<tbb::global_control> g_threads;

void set_threads(int threads) {
    g_threads.reset();
    if (threads > 0) g_threads = std::make_unique<tbb::global_control>(tbb::global_control::max_allowed_parallelism, threads);
}

// Runs `work` on a worker thread; meanwhile calls `tick()` (with the GIL) every 100 ms and
// checks for Ctrl-C. Exceptions from the work are rethrown here.
template <typename Work, typename Tick>
void run_reporting(Work&& work, Tick&& tick) {
    std::exception_ptr error;
    std::atomic<bool> finished{false};
    std::thread worker([&] {
        try { work(); } catch (...) { error = std::current_exception(); }
        finished = true;
    });
    while (!finished) {
        {
            nb::gil_scoped_release release;
            for (int k = 0; k < 10 && !finished; ++k) std::this_thread::sleep_for(std::chrono::milliseconds(10));
        }
        try {
            tick();
            if (PyErr_CheckSignals() != 0) throw nb::python_error();
        } catch (...) {
            // The engine can't be interrupted mid-stage: wait for it, then report.
            nb::gil_scoped_release release;
            worker.join();
            throw;
        }
    }
    worker.join();
    if (error) std::rethrow_exception(error);
    tick();
}

std::vector<Patch> patches_from_arrays(const In<double>& corners, const In<int32_t>& nv) {
    const size_t n = nv.shape(0);
    if (corners.ndim() != 3 || corners.shape(0) != n || corners.shape(1) != 4 || corners.shape(2) != 3)
        throw std::invalid_argument("corners: expected shape (n, 4, 3)");
    std::vector<Patch> patches(n);
    for (size_t i = 0; i < n; ++i) {
        Patch& p = patches[i];
        p.nv = nv.data()[i];
        if (p.nv != 3 && p.nv != 4) throw std::invalid_argument("nv: every patch has 3 or 4 corners");
        for (int k = 0; k < 4; ++k) {
            const double* c = corners.data() + (i * 4 + k) * 3;
            p.p[k] = {c[0], c[1], c[2]};
        }
        if (p.nv == 3) p.p[3] = p.p[2];
        Vec3 nn;
        for (int k = 0; k < p.nv; ++k) nn += cross(p.p[k], p.p[(k + 1) % p.nv]);
        p.area = 0.5 * length(nn);
        p.normal = normalize(nn);
        p.centroid = p.p[0];
    }
    return patches;
}

std::vector<std::array<RGB, 4>> corner_values(const In<double>& a, size_t n, const char* what) {
    if (a.ndim() != 3 || a.shape(0) != n || a.shape(1) != 4 || a.shape(2) != 3)
        throw std::invalid_argument(std::string(what) + ": expected shape (n, 4, 3)");
    std::vector<std::array<RGB, 4>> v(n);
    for (size_t i = 0; i < n; ++i)
        for (int k = 0; k < 4; ++k) {
            const double* c = a.data() + (i * 4 + k) * 3;
            v[i][k] = {c[0], c[1], c[2]};
        }
    return v;
}

// The whole flat pipeline for one scene: scene -> patches -> links -> solution.
class Model {
public:
    Model(In<double> points, In<int32_t> counts, In<int32_t> indices, In<int32_t> face_mesh, In<int32_t> face_source,
          In<double> reflectance, In<double> emission, std::optional<In<double>> corner_uv) {
        SceneInput in;
        in.points = points.data();
        in.num_points = points.shape(0);
        in.face_vertex_counts = counts.data();
        in.num_faces = counts.shape(0);
        size_t corners = 0;
        for (size_t f = 0; f < in.num_faces; ++f) {
            if (counts.data()[f] < 0) throw std::invalid_argument("face_vertex_counts: negative count");
            corners += counts.data()[f];
        }
        if (indices.shape(0) != corners) throw std::invalid_argument("face_vertex_indices: length != sum of counts");
        if (face_mesh.shape(0) != in.num_faces || face_source.shape(0) != in.num_faces ||
            reflectance.shape(0) != in.num_faces || emission.shape(0) != in.num_faces)
            throw std::invalid_argument("per-face arrays must have one row per face");
        in.face_vertex_indices = indices.data();
        in.face_mesh = face_mesh.data();
        in.face_source = face_source.data();
        in.face_reflectance = reflectance.data();
        in.face_emission = emission.data();
        if (corner_uv) {
            if (corner_uv->shape(0) != corners) throw std::invalid_argument("corner_uv: one row per face corner");
            in.corner_uv = corner_uv->data();
        }
        scene_ = Scene::build(in);
    }

    nb::dict stats() const {
        nb::dict d;
        d["input_faces"] = scene_.stats.input_faces;
        d["faces"] = scene_.faces.size();
        d["degenerate_faces"] = scene_.stats.degenerate_faces;
        d["nonfinite_faces"] = scene_.stats.nonfinite_faces;
        d["triangulated_faces"] = scene_.stats.triangulated_faces;
        d["nonmanifold_edges"] = scene_.stats.nonmanifold_edges;
        d["patches"] = patches_.patches.size();
        d["links"] = links_ ? links_->link_count() : 0;
        d["link_bytes"] = links_ ? links_->bytes() : 0;
        d["rays"] = visibility_ ? visibility_->rays_cast() : 0;
        return d;
    }

    void mesh(double max_area, double max_edge) {
        if (!(max_area > 0) || !(max_edge > 0)) throw std::invalid_argument("meshing limits must be positive");
        if (scene_.faces.empty()) throw std::invalid_argument("the scene has no usable faces");
        links_.reset();
        visibility_.reset();
        patches_ = mesh_patches(scene_, {max_area, max_edge});
        visibility_ = std::make_unique<Visibility>(patches_.patches);
    }

    size_t num_patches() const { return patches_.patches.size(); }

    nb::dict patch_arrays() const {
        const auto& P = patches_.patches;
        const size_t n = P.size();
        std::vector<double> corners(n * 12), uv(n * 8), area(n), normal(n * 3), centroid(n * 3), rho(n * 3), emit(n * 3);
        std::vector<int32_t> nv(n), mesh(n), face(n), source(n);
        for (size_t i = 0; i < n; ++i) {
            const Patch& p = P[i];
            for (int k = 0; k < 4; ++k) {
                for (int a = 0; a < 3; ++a) corners[i * 12 + k * 3 + a] = p.p[k][a];
                uv[i * 8 + k * 2] = p.uv[k].u;
                uv[i * 8 + k * 2 + 1] = p.uv[k].v;
            }
            for (int a = 0; a < 3; ++a) {
                normal[i * 3 + a] = p.normal[a];
                centroid[i * 3 + a] = p.centroid[a];
                rho[i * 3 + a] = p.reflectance[a];
                emit[i * 3 + a] = p.emission[a];
            }
            area[i] = p.area;
            nv[i] = p.nv;
            mesh[i] = static_cast<int32_t>(p.mesh);
            face[i] = static_cast<int32_t>(p.face);
            source[i] = static_cast<int32_t>(scene_.faces[p.face].source_face);
        }
        nb::dict d;
        d["corners"] = to_numpy(std::move(corners), {n, 4, 3});
        d["uv"] = to_numpy(std::move(uv), {n, 4, 2});
        d["area"] = to_numpy(std::move(area), {n});
        d["normal"] = to_numpy(std::move(normal), {n, 3});
        d["centroid"] = to_numpy(std::move(centroid), {n, 3});
        d["reflectance"] = to_numpy(std::move(rho), {n, 3});
        d["emission"] = to_numpy(std::move(emit), {n, 3});
        d["nv"] = to_numpy(std::move(nv), {n});
        d["mesh"] = to_numpy(std::move(mesh), {n});
        d["face"] = to_numpy(std::move(face), {n});
        d["source_face"] = to_numpy(std::move(source), {n});
        return d;
    }

    // Link generation for the flat method; `progress(done_rows)` is called periodically.
    void compute_links(const std::string& method, int samples, int hemicube_resolution, int hemicube_points,
                       uint64_t seed, nb::object progress) {
        require_mesh();
        const uint32_t n = static_cast<uint32_t>(patches_.patches.size());
        std::atomic<uint32_t> done{0};
        std::unique_ptr<LinkMatrix> result;
        auto tick = [&] { if (!progress.is_none()) progress(done.load()); };
        if (method == "raycast") {
            RayCastFormFactors ff(patches_.patches, *visibility_, {samples, seed});
            run_reporting([&] {
                result = std::make_unique<LinkMatrix>(LinkMatrix::build(
                    n, [&](uint32_t i, auto& out) { ff.upper_couplings_of(i, out); },
                    [&](uint32_t d) { done = std::max(done.load(), d); }));
            }, tick);
        } else if (method == "hemicube") {
            Hemicube hc(patches_.patches, {hemicube_resolution, hemicube_points});
            run_reporting([&] { result = std::make_unique<LinkMatrix>(hemicube_links(hc, done)); }, tick);
        } else {
            throw std::invalid_argument("unknown form factor method '" + method + "'");
        }
        links_ = std::move(result);
    }

    nb::dict solve(const std::string& method, double tolerance, uint64_t max_iterations, int samples, uint64_t seed,
                   uint64_t snapshot_every, nb::object snapshot, nb::object progress) {
        require_mesh();
        RadiositySystem sys = system();
        std::atomic<uint64_t> iteration{0};
        std::atomic<double> residual{1.0};
        std::mutex snap_mutex;
        std::vector<std::pair<uint64_t, std::vector<RGB>>> snaps;
        SolverOptions base;
        base.tolerance = tolerance;
        base.max_iterations = max_iterations;
        base.on_iteration = [&](const IterationReport& r) {
            iteration = r.iteration;
            residual = r.residual;
            return true;
        };
        auto tick = [&] {
            std::vector<std::pair<uint64_t, std::vector<RGB>>> pending;
            {
                std::lock_guard<std::mutex> lock(snap_mutex);
                pending.swap(snaps);
            }
            for (auto& [shot, display] : pending) snapshot(shot, rgb_array(display));
            if (!progress.is_none()) progress(iteration.load(), residual.load());
        };
        Solution sol;
        uint64_t rows = 0;
        if (method == "progressive") {
            ProgressiveOptions opt;
            static_cast<SolverOptions&>(opt) = base;
            opt.snapshot_every = snapshot.is_none() ? 0 : snapshot_every;
            opt.snapshot = [&](uint64_t shot, const std::vector<RGB>& display) {
                std::lock_guard<std::mutex> lock(snap_mutex);
                snaps.emplace_back(shot, display);
            };
            auto ff = std::make_shared<RayCastFormFactors>(patches_.patches, *visibility_, RayCastOptions{samples, seed});
            run_reporting([&] {
                sol = solve_progressive(sys, [&](uint32_t i, auto& out) { ff->couplings_of(i, out); }, opt, &rows);
            }, tick);
        } else {
            if (!links_) throw std::invalid_argument("solver '" + method + "' needs links: compute_links first");
            run_reporting([&] {
                if (method == "direct") sol = solve_direct(sys);
                else if (method == "jacobi") sol = solve_jacobi(sys, base);
                else if (method == "gauss_seidel") sol = solve_gauss_seidel(sys, base);
                else if (method == "southwell") sol = solve_southwell(sys, base);
                else throw std::invalid_argument("unknown solver '" + method + "'");
            }, tick);
        }
        nb::dict d;
        d["radiosity"] = rgb_array(sol.radiosity);
        d["iterations"] = sol.iterations;
        d["residual"] = sol.residual;
        d["converged"] = sol.converged;
        d["residual_history"] = sol.residual_history;
        d["rows_computed"] = rows;
        return d;
    }

    // Irradiance H = F B (W/m^2) and, per patch, the power that leaves it and reaches no
    // patch (A_i - sum_j G_ij) B_i: the two terms of the energy balance.
    nb::dict transport(In<double> radiosity, int samples, uint64_t seed) {
        require_mesh();
        const uint32_t n = static_cast<uint32_t>(patches_.patches.size());
        std::vector<RGB> b = rgb_vector(radiosity, n, "radiosity");
        std::vector<RGB> h(n), escaped(n);
        std::unique_ptr<RayCastFormFactors> ff;
        if (!links_) ff = std::make_unique<RayCastFormFactors>(patches_.patches, *visibility_, RayCastOptions{samples, seed});
        run_reporting([&] {
            tbb::parallel_for(uint32_t(0), n, [&](uint32_t i) {
                std::vector<std::pair<uint32_t, float>> row;
                if (links_) {
                    for (uint64_t k = links_->offsets[i]; k < links_->offsets[i + 1]; ++k)
                        row.emplace_back(links_->columns[k], links_->coupling[k]);
                } else {
                    ff->couplings_of(i, row);
                }
                RGB acc;
                double g_sum = 0;
                for (const auto& [j, g] : row) { acc += b[j] * double(g); g_sum += g; }
                const double a = patches_.patches[i].area;
                h[i] = acc / a;
                // Not clamped: sampling makes some rows sum a little above 1, others below, and
                // only the signed values add up to the power that really leaves the scene.
                escaped[i] = b[i] * (a - g_sum);
            });
        }, [] {});
        nb::dict d;
        d["irradiance"] = rgb_array(h);
        d["escaped"] = rgb_array(escaped);
        return d;
    }

    double residual_of(In<double> radiosity) const {
        if (!links_) throw std::invalid_argument("residual_of needs links");
        RadiositySystem sys = system();
        return relative_residual(sys, rgb_vector(radiosity, sys.size(), "radiosity"));
    }

    nb::dict display_mesh(double crease_angle) {
        require_mesh();
        display_ = build_display_mesh(patches_, crease_angle);
        const size_t np = display_.points.size(), n = display_.corners.size();
        std::vector<double> pts(np * 3);
        std::vector<int32_t> pm(np), corners(n * 4);
        std::vector<uint8_t> boundary(display_.boundary);
        for (size_t v = 0; v < np; ++v) {
            for (int a = 0; a < 3; ++a) pts[3 * v + a] = display_.points[v][a];
            pm[v] = static_cast<int32_t>(display_.point_mesh[v]);
        }
        for (size_t i = 0; i < n; ++i)
            for (int k = 0; k < 4; ++k) corners[4 * i + k] = static_cast<int32_t>(display_.corners[i][k]);
        const size_t nf = display_.faces.size();
        std::vector<int32_t> faces(nf * 4), face_patch(nf);
        std::vector<uint8_t> face_nv(display_.face_nv), codes(nf * 4);
        for (size_t f = 0; f < nf; ++f) {
            for (int k = 0; k < 4; ++k) {
                faces[4 * f + k] = static_cast<int32_t>(display_.faces[f][k]);
                codes[4 * f + k] = display_.face_code[f][k];
            }
            face_patch[f] = static_cast<int32_t>(display_.face_patch[f]);
        }
        std::vector<uint8_t> anchored(np);
        for (size_t v = 0; v < np; ++v) anchored[v] = !display_.anchors[v].empty();
        nb::dict d;
        d["points"] = to_numpy(std::move(pts), {np, 3});
        d["point_mesh"] = to_numpy(std::move(pm), {np});
        d["corners"] = to_numpy(std::move(corners), {n, 4});
        d["boundary"] = to_numpy(std::move(boundary), {np});
        d["faces"] = to_numpy(std::move(faces), {nf, 4});
        d["face_nv"] = to_numpy(std::move(face_nv), {nf});
        d["face_patch"] = to_numpy(std::move(face_patch), {nf});
        d["face_code"] = to_numpy(std::move(codes), {nf, 4});
        d["anchored"] = to_numpy(std::move(anchored), {np});
        return d;
    }

    Out vertex_values_of(In<double> patch_values) const {
        if (display_.corners.size() != patches_.patches.size()) throw std::invalid_argument("call display_mesh first");
        return rgb_array(vertex_values(patches_, display_, rgb_vector(patch_values, patches_.patches.size(), "values")));
    }

    double form_factor(uint32_t i, uint32_t j, int samples, uint64_t seed) const {
        require_index(i);
        require_index(j);
        RayCastFormFactors ff(patches_.patches, *visibility_, {samples, seed});
        return ff.form_factor(i, j);
    }

    Out hemicube_row(uint32_t i, int resolution, int points) const {
        require_index(i);
        Hemicube hc(patches_.patches, {resolution, points});
        std::vector<std::pair<uint32_t, double>> row;
        hc.row(i, row);
        std::vector<double> dense(patches_.patches.size(), 0.0);
        for (const auto& [j, f] : row) dense[j] = f;
        return to_numpy(std::move(dense), {patches_.patches.size()});
    }

    uint64_t rays_cast() const { return visibility_ ? visibility_->rays_cast() : 0; }

    // Final gather from a flat solution (gather.h: gather_flat) at points on the patches'
    // surfaces: irradiance and radiance per point, the point's patch found as for probes.
    nb::dict gather_flat(In<double> points, In<double> normals, In<double> radiosity, int rays, uint64_t seed) const {
        const size_t n = points.shape(0), np = patches_.patches.size();
        if (!visibility_ || np == 0) throw std::invalid_argument("gather_flat needs a meshed, solved model");
        if (points.ndim() != 2 || points.shape(1) != 3 || normals.ndim() != 2 || normals.shape(0) != n)
            throw std::invalid_argument("points and normals: shape (n, 3)");
        const std::vector<RGB> b = rgb_vector(radiosity, np, "radiosity");
        std::vector<Vec3> x(n), nn(n);
        std::vector<int32_t> patch(n);
        std::vector<RGB> e(n);
        std::vector<double> irr(3 * n, 0.0), rad(3 * n, 0.0);
        {
            nb::gil_scoped_release release;
            for (size_t q = 0; q < n; ++q) {
                const double* p = points.data() + 3 * q;
                const double* m = normals.data() + 3 * q;
                const RayHit hit = visibility_->closest_point({p[0], p[1], p[2]}, {m[0], m[1], m[2]}, 1e30);
                patch[q] = hit.patch;
                const Patch& s = patches_.patches[std::max(0, hit.patch)];
                nn[q] = s.normal;
                x[q] = Vec3{p[0], p[1], p[2]} - s.normal * dot(Vec3{p[0], p[1], p[2]} - s.p[0], s.normal);
            }
            hirad::gather_flat(patches_.patches, b, *visibility_, x.data(), nn.data(), n, rays, seed, e.data());
            for (size_t q = 0; q < n; ++q) {
                if (patch[q] < 0) continue;
                const Patch& s = patches_.patches[patch[q]];
                const RGB l = (s.emission + mul(s.reflectance, e[q])) / kPi;
                for (int c = 0; c < 3; ++c) { irr[3 * q + c] = e[q][c]; rad[3 * q + c] = l[c]; }
            }
        }
        nb::dict d;
        d["patch"] = to_numpy(std::move(patch), {n});
        d["irradiance"] = to_numpy(std::move(irr), {n, 3});
        d["radiance"] = to_numpy(std::move(rad), {n, 3});
        return d;
    }

    // Hierarchical radiosity with clustering: refine (from the root's self-link), solve with
    // push-pull, refine again with the new radiosity, until no link splits or max_rounds. The
    // leaves then replace the patches, so outputs and display work as for the flat method.
    nb::dict solve_hierarchical(double epsilon, double min_area, int samples, uint64_t seed, double tolerance,
                                uint64_t max_iterations, int max_rounds, nb::object progress, const std::string& solver) {
        using HSolver = HierarchicalSolution (*)(const Hierarchy&, const std::vector<Link>&, const std::vector<RGB>&,
                                                 const SolverOptions&);
        HSolver solve_fn = solver == "jacobi" ? &solve_push_pull
                           : solver == "gauss_seidel" ? &solve_gauss_seidel_push_pull
                           : solver == "southwell" ? &solve_southwell_push_pull
                                                   : nullptr;
        if (!solve_fn) throw std::invalid_argument("hierarchical solver must be jacobi, gauss_seidel or southwell, not '" + solver + "'");
        double emitted = 0;
        auto state = fresh_hierarchy(epsilon, min_area, emitted);
        Hierarchy& h = state->hierarchy;
        Visibility* vis = state->visibility.get();
        RefineOptions ropt{epsilon * emitted, min_area, samples, seed};
        Refiner refiner(h, *vis, ropt);
        std::atomic<int> round{0};
        std::atomic<uint64_t> link_count{0};
        std::atomic<uint64_t> iteration{0};
        std::atomic<double> residual{1.0};
        HierarchicalSolution sol;
        std::vector<Link> links;
        std::vector<uint64_t> links_per_round, splits_per_round;
        std::vector<double> refine_seconds, solve_seconds;
        RefineStats stats;
        uint64_t total_iterations = 0;
        std::vector<double> history;
        bool settled = false;
        run_reporting([&] {
            auto now = [] { return std::chrono::steady_clock::now(); };
            auto t0 = now();
            links = refiner.initial_links(node_emission(h), stats);
            refine_seconds.push_back(std::chrono::duration<double>(now() - t0).count());
            std::vector<RGB> b = node_emission(h);
            for (int r = 1;; ++r) {
                round = r;
                sort_links(links);
                links_per_round.push_back(links.size());
                link_count = links.size();
                SolverOptions so;
                so.tolerance = tolerance;
                so.max_iterations = max_iterations;
                so.on_iteration = [&](const IterationReport& rep) { iteration = rep.iteration; residual = rep.residual; return true; };
                t0 = now();
                // Start from the previous round's solution, extended to new nodes by their parents.
                std::vector<RGB> start = b;
                for (size_t i = start.size(); i < h.nodes.size(); ++i) start.push_back(start[h.nodes[i].parent]);
                sol = solve_fn(h, links, start, so);
                solve_seconds.push_back(std::chrono::duration<double>(now() - t0).count());
                total_iterations += sol.iterations;
                history.insert(history.end(), sol.residual_history.begin(), sol.residual_history.end());
                b = sol.radiosity;
                if (r >= max_rounds) break;
                t0 = now();
                const uint64_t before = stats.split;
                std::vector<Link> refined = refiner.refine(links, b, stats);
                refine_seconds.push_back(std::chrono::duration<double>(now() - t0).count());
                splits_per_round.push_back(stats.split - before);
                if (stats.split == before) { settled = true; break; }
                links.swap(refined);
            }
        }, [&] {
            if (!progress.is_none()) progress(round.load(), link_count.load(), iteration.load(), residual.load());
        });

        state->links = std::move(links);
        nb::dict d = publish(std::move(state), std::move(sol));
        d["iterations"] = total_iterations;
        d["residual_history"] = history;
        d["rounds"] = round.load();
        d["settled"] = settled;
        d["links_per_round"] = links_per_round;
        d["splits_per_round"] = splits_per_round;
        d["refine_seconds"] = refine_seconds;
        d["solve_seconds"] = solve_seconds;
        d["link_estimates"] = stats.evaluated;
        d["rays"] = vis->rays_cast();
        d["epsilon_watts"] = ropt.epsilon;
        return d;
    }

    // Hierarchical radiosity out of core (outofcore.h): refinement rounds through the link
    // store in `store` (in memory when empty), each solved by streaming block Southwell
    // within `memory_budget` bytes (0: unlimited), checkpointed every `checkpoint_seconds`.
    nb::dict solve_out_of_core(double epsilon, double min_area, int samples, uint64_t seed, double tolerance,
                               uint64_t max_iterations, int max_rounds, nb::object progress, const std::string& store,
                               uint64_t memory_budget, uint32_t group_faces, double checkpoint_seconds, bool resume,
                               bool reuse_links) {
        double emitted = 0;
        auto state = fresh_hierarchy(epsilon, min_area, emitted);
        Hierarchy& h = state->hierarchy;
        OutOfCoreOptions opt;
        opt.refine = {epsilon * emitted, min_area, samples, seed};
        opt.max_rounds = max_rounds;
        opt.group_faces = group_faces;
        opt.store = store;
        opt.solve.tolerance = tolerance;
        opt.solve.max_rounds = max_iterations;
        opt.solve.memory_budget = memory_budget;
        opt.solve.checkpoint_seconds = checkpoint_seconds;
        opt.resume = resume;
        opt.reuse_links = reuse_links;
        // Fingerprints: geometry (what the links depend on), the refinement settings, and the
        // materials (what the oracle's radiosity, hence the refinement, also depends on).
        uint64_t geo = 0x6E0ull, mat = 0x3A7ull;
        auto bits = [](double x) { uint64_t u; std::memcpy(&u, &x, 8); return u; };
        for (const Face& f : scene_.faces) {
            geo = hash_pair(geo, (uint64_t(f.nv) << 32) | f.mesh, 1);
            for (int k = 0; k < f.nv; ++k)
                for (int a = 0; a < 3; ++a) geo = hash_pair(geo, bits(f.p[k][a]), 2);
            for (int a = 0; a < 3; ++a) mat = hash_pair(hash_pair(mat, bits(f.reflectance[a]), 3), bits(f.emission[a]), 4);
        }
        uint64_t settings = 0x5E7ull;
        for (uint64_t v : {bits(epsilon), bits(min_area), uint64_t(samples), seed, uint64_t(max_rounds), uint64_t(group_faces)})
            settings = hash_pair(settings, v, 5);
        opt.geometry_fingerprint = geo;
        opt.settings_fingerprint = settings;
        opt.materials_fingerprint = mat;
        std::atomic<int> round{0};
        std::atomic<uint64_t> link_count{0}, shots{0};
        std::atomic<double> residual{1.0};
        opt.progress = [&](int r, uint64_t links, uint64_t it, double res) {
            round = r; link_count = links; shots = it; residual = res;
        };
        OutOfCoreReport rep;
        run_reporting([&] { rep = run_out_of_core(h, *state->visibility, opt); }, [&] {
            if (!progress.is_none()) progress(round.load(), link_count.load(), shots.load(), residual.load());
        });
        state->links = std::move(rep.memory_links);
        state->store_round = rep.final_round_dir;
        state->groups = SourceGroups::cut(h, group_faces).count();
        const StreamingStats st = rep.last_solve;
        const uint64_t links = rep.links;
        const uint64_t iterations = rep.solution.iterations;
        const std::vector<double> history = rep.solution.residual_history;
        nb::dict d = publish(std::move(state), std::move(rep.solution));
        d["links"] = links;
        d["iterations"] = iterations;
        d["residual_history"] = history;
        d["rounds"] = rep.rounds;
        d["settled"] = rep.settled;
        d["links_per_round"] = rep.links_per_round;
        d["splits_per_round"] = rep.splits_per_round;
        d["refine_seconds"] = rep.refine_seconds;
        d["solve_seconds"] = rep.solve_seconds;
        d["link_estimates"] = rep.refine_stats.evaluated;
        d["rays"] = solved_->visibility->rays_cast();
        d["epsilon_watts"] = opt.refine.epsilon;
        d["reused_links"] = rep.reused;
        d["resumed_from_round"] = rep.resumed_from_round;
        d["store_bytes"] = rep.store_bytes;
        d["transport_bytes"] = rep.transport_bytes;
        d["peak_refine_links"] = rep.peak_refine_links;
        d["source_groups"] = solved_->groups;
        nb::dict s;
        s["rounds"] = st.rounds;
        s["groups_shot"] = st.groups_shot;
        s["links_shot"] = st.links_shot;
        s["chunk_reads"] = st.chunk_reads;
        s["chunk_hits"] = st.chunk_hits;
        s["resident_bytes_peak"] = st.resident_bytes_peak;
        s["state_bytes"] = st.state_bytes;
        s["largest_chunk_bytes"] = st.largest_chunk_bytes;
        s["chunks_in_flight"] = st.chunks_in_flight;
        s["minimum_budget"] = st.minimum_budget;
        s["decoded_bytes"] = st.decoded_bytes;
        s["checkpoints"] = st.checkpoints;
        s["resumed"] = st.resumed;
        s["read_wait_seconds"] = st.read_wait_seconds;
        s["shoot_seconds"] = st.shoot_seconds;
        d["streaming"] = s;
        return d;
    }

    // Final gather at surface points after a hierarchical solve (see gather.h): each point
    // is matched to the nearest leaf facing along its normal, then every link reaching that
    // leaf is re-evaluated at the point. Returns leaf (-1 if none within max_distance),
    // irradiance and radiance.
    nb::dict gather(In<double> points, In<double> normals, int rays, int cluster_samples, uint64_t seed,
                    double max_distance) {
        if (!solved_) throw std::invalid_argument("gather needs a hierarchical solve first");
        // Links of an out-of-core solve are read from its store on the first gather.
        if (solved_->links.empty() && !solved_->store_round.empty())
            solved_->links = load_links(solved_->store_round, solved_->groups);
        const size_t n = points.shape(0);
        if (points.ndim() != 2 || points.shape(1) != 3 || normals.ndim() != 2 || normals.shape(0) != n ||
            normals.shape(1) != 3)
            throw std::invalid_argument("points and normals: shape (n, 3)");
        std::vector<int32_t> patch(n, -1);
        std::vector<double> irr(n * 3, 0.0), rad(n * 3, 0.0);
        {
            nb::gil_scoped_release release;
            std::vector<uint32_t> leaf;
            std::vector<Vec3> x;
            std::vector<uint64_t> key;
            std::vector<size_t> slot;
            std::vector<RayHit> hits(n);
            tbb::parallel_for(size_t(0), n, [&](size_t q) {
                const double* p = points.data() + 3 * q;
                const double* m = normals.data() + 3 * q;
                hits[q] = visibility_->closest_point({p[0], p[1], p[2]}, {m[0], m[1], m[2]}, max_distance);
            });
            for (size_t q = 0; q < n; ++q) {
                if (hits[q].patch < 0) continue;
                patch[q] = hits[q].patch;
                const double* p = points.data() + 3 * q;
                leaf.push_back(solved_->leaves[hits[q].patch]);
                x.push_back({p[0], p[1], p[2]});
                key.push_back(q);
                slot.push_back(q);
            }
            GatherOptions go{rays, cluster_samples, seed};
            Gatherer g(solved_->hierarchy, solved_->links, solved_->radiosity, *solved_->visibility, go);
            std::vector<RGB> e(leaf.size()), l(leaf.size());
            g.irradiance(leaf.data(), x.data(), key.data(), leaf.size(), e.data());
            for (size_t k = 0; k < leaf.size(); ++k) {
                const Patch& s = solved_->hierarchy.nodes[leaf[k]].shape;
                l[k] = (s.emission + mul(s.reflectance, e[k])) / kPi;
                for (int c = 0; c < 3; ++c) { irr[3 * slot[k] + c] = e[k][c]; rad[3 * slot[k] + c] = l[k][c]; }
            }
        }
        nb::dict d;
        d["patch"] = to_numpy(std::move(patch), {n});
        d["irradiance"] = to_numpy(std::move(irr), {n, 3});
        d["radiance"] = to_numpy(std::move(rad), {n, 3});
        return d;
    }

    // Monte Carlo reference: exitant radiance at (s, t) on the given patches, with its
    // standard error; independent of links and of the solution.
    nb::dict reference(In<int32_t> patch, In<double> st, int paths, int min_bounces, uint64_t seed) const {
        require_mesh();
        const size_t n = patch.shape(0);
        if (st.ndim() != 2 || st.shape(0) != n || st.shape(1) != 2) throw std::invalid_argument("st: shape (n, 2)");
        std::vector<uint32_t> ids(n);
        std::vector<Vec2> coords(n);
        for (size_t q = 0; q < n; ++q) {
            if (patch.data()[q] < 0 || size_t(patch.data()[q]) >= patches_.patches.size())
                throw nb::index_error("patch index out of range");
            ids[q] = static_cast<uint32_t>(patch.data()[q]);
            coords[q] = {st.data()[2 * q], st.data()[2 * q + 1]};
        }
        std::vector<ReferenceEstimate> est;
        run_reporting([&] { est = reference_radiance(patches_.patches, *visibility_, ids, coords, {paths, min_bounces, seed}); },
                      [] {});
        std::vector<RGB> l(n), e(n);
        for (size_t q = 0; q < n; ++q) { l[q] = est[q].radiance; e[q] = est[q].standard_error; }
        nb::dict d;
        d["radiance"] = rgb_array(l);
        d["standard_error"] = rgb_array(e);
        return d;
    }

    // The reference at arbitrary surface points: each point goes to the closest patch facing
    // along its normal (any, when the normal is zero) within max_distance.
    nb::dict reference_at(In<double> points, In<double> normals, int paths, int min_bounces, uint64_t seed,
                          double max_distance) const {
        require_mesh();
        const size_t n = points.shape(0);
        if (points.ndim() != 2 || points.shape(1) != 3 || normals.ndim() != 2 || normals.shape(0) != n)
            throw std::invalid_argument("points and normals: shape (n, 3)");
        std::vector<int32_t> ids(n);
        std::vector<double> st(2 * n);
        for (size_t q = 0; q < n; ++q) {
            const double* p = points.data() + 3 * q;
            const double* m = normals.data() + 3 * q;
            RayHit hit = visibility_->closest_point({p[0], p[1], p[2]}, {m[0], m[1], m[2]}, max_distance);
            if (hit.patch < 0)
                throw std::invalid_argument("point " + std::to_string(q) + ": no surface within " +
                                            std::to_string(max_distance) + " m");
            ids[q] = hit.patch;
            // The closest point's (s, t) in the patch's own parametrisation (Patch::point).
            st[2 * q] = hit.u;
            st[2 * q + 1] = hit.v;
        }
        size_t shape_ids[1] = {n};
        size_t shape_st[2] = {n, 2};
        In<int32_t> ids_view(ids.data(), 1, shape_ids, nb::handle());
        In<double> st_view(st.data(), 2, shape_st, nb::handle());
        return reference(ids_view, st_view, paths, min_bounces, seed);
    }

private:
    void require_mesh() const {
        if (!visibility_) throw std::invalid_argument("call mesh() first");
    }
    void require_index(uint32_t i) const {
        require_mesh();
        if (i >= patches_.patches.size()) throw nb::index_error("patch index out of range");
    }

    RadiositySystem system() const {
        RadiositySystem sys;
        sys.links = links_.get();
        for (const Patch& p : patches_.patches) {
            sys.area.push_back(p.area);
            sys.reflectance.push_back(p.reflectance);
            sys.emission.push_back(p.emission);
        }
        return sys;
    }

    // Hemicube rows are not reciprocal on their own; the stored coupling is the mean of the
    // two directions, G_ij = (A_i F_ij + A_j F_ji) / 2.
    LinkMatrix hemicube_links(const Hemicube& hc, std::atomic<uint32_t>& done) const {
        const uint32_t n = static_cast<uint32_t>(patches_.patches.size());
        std::vector<std::vector<std::pair<uint32_t, double>>> rows(n);
        tbb::parallel_for(uint32_t(0), n, [&](uint32_t i) {
            hc.row(i, rows[i]);
            ++done;
        });
        std::vector<std::vector<std::pair<uint32_t, float>>> upper(n);
        auto find = [&](uint32_t i, uint32_t j) {
            auto it = std::lower_bound(rows[i].begin(), rows[i].end(), std::make_pair(j, -1.0));
            return (it != rows[i].end() && it->first == j) ? it->second : 0.0;
        };
        tbb::parallel_for(uint32_t(0), n, [&](uint32_t i) {
            const double ai = patches_.patches[i].area;
            // Pairs seen from either side: walk row i (j > i) and pick up j's view of i.
            for (const auto& [j, f] : rows[i])
                if (j > i) upper[i].emplace_back(j, static_cast<float>(0.5 * (ai * f + patches_.patches[j].area * find(j, i))));
        });
        // Pairs that only j saw (j < i would be in row j; j > i only in row j): add them.
        for (uint32_t j = 0; j < n; ++j)
            for (const auto& [i, f] : rows[j])
                if (i < j && find(i, j) == 0.0)
                    upper[i].emplace_back(j, static_cast<float>(0.5 * patches_.patches[j].area * f));
        for (auto& u : upper) std::sort(u.begin(), u.end());
        return LinkMatrix::from_upper(n, upper);
    }

    // What a hierarchical solve leaves behind for the final gather.
    struct SolvedHierarchy {
        explicit SolvedHierarchy(const Scene& scene) : hierarchy(scene) {}
        Hierarchy hierarchy;
        std::unique_ptr<Visibility> visibility;  // over hierarchy.faces
        std::vector<Link> links;                 // sorted by receiver
        std::vector<RGB> radiosity;              // per node
        std::vector<uint32_t> leaves;            // node of each patch
        std::string store_round;                 // out of core: the final links' store
        size_t groups = 0;                       // and its number of source groups
    };

    // A new hierarchy over the scene (replacing any earlier solve) with Embree over its faces;
    // `emitted` receives the scene's emitted power (luminance), what epsilon is relative to.
    std::unique_ptr<SolvedHierarchy> fresh_hierarchy(double epsilon, double min_area, double& emitted) {
        if (scene_.faces.empty()) throw std::invalid_argument("the scene has no usable faces");
        if (!(epsilon >= 0) || !(min_area > 0)) throw std::invalid_argument("epsilon >= 0 and min_area > 0 required");
        links_.reset();
        solved_.reset();
        auto state = std::make_unique<SolvedHierarchy>(scene_);
        state->visibility = std::make_unique<Visibility>(state->hierarchy.faces);
        emitted = 0;
        for (const Patch& f : state->hierarchy.faces) emitted += luminance(f.emission) * f.area;
        return state;
    }

    // Balances a solved hierarchy 2:1 for a display without cracks (new leaves carry their
    // parent's values), makes its leaves the model's patches and keeps it for the final
    // gather. Returns what every hierarchical solve reports.
    nb::dict publish(std::unique_ptr<SolvedHierarchy> state, HierarchicalSolution sol) {
        Hierarchy& h = state->hierarchy;
        const std::vector<Link>& links = state->links;
        const uint64_t balanced = h.balance();
        for (size_t i = sol.radiosity.size(); i < h.nodes.size(); ++i) {
            const uint32_t parent = h.nodes[i].parent;
            sol.radiosity.push_back(sol.radiosity[parent]);
            sol.irradiance.push_back(sol.irradiance[parent]);
            sol.outgoing.push_back(sol.outgoing[parent]);
        }
        // Leaves become the patches of the model.
        std::vector<uint32_t> leaves = h.leaves();
        std::vector<Patch> leaf_patches;
        leaf_patches.reserve(leaves.size());
        std::vector<RGB> b(leaves.size()), irr(leaves.size()), escaped(leaves.size());
        for (size_t k = 0; k < leaves.size(); ++k) {
            const Node& node = h.nodes[leaves[k]];
            leaf_patches.push_back(node.shape);
            b[k] = sol.radiosity[leaves[k]];
            irr[k] = sol.irradiance[leaves[k]];
            // Signed, as for the flat method: the per-leaf shares only add up unclamped.
            escaped[k] = b[k] * (node.area * (1.0 - sol.outgoing[leaves[k]]));
        }
        patches_ = weld_patches(std::move(leaf_patches));
        visibility_ = std::make_unique<Visibility>(patches_.patches);
        uint64_t clusters = 0;
        for (const Node& node : h.nodes) clusters += node.cluster;
        nb::dict d;
        d["radiosity"] = rgb_array(b);
        d["irradiance"] = rgb_array(irr);
        d["escaped"] = rgb_array(escaped);
        d["residual"] = sol.residual;
        d["converged"] = sol.converged;
        d["links"] = links.size();
        d["elements"] = leaves.size();
        d["nodes"] = h.nodes.size();
        d["clusters"] = clusters;
        d["balance_splits"] = balanced;
        // The hierarchy and its links as plain arrays (for tests and inspection).
        std::vector<int32_t> lr(links.size()), ls(links.size()), parent(h.nodes.size()), leaf_node(leaves.size());
        std::vector<double> lg(links.size()), lu(links.size()), node_area(h.nodes.size());
        std::vector<uint8_t> node_cluster(h.nodes.size());
        for (size_t k = 0; k < links.size(); ++k) {
            lr[k] = links[k].receiver;
            ls[k] = links[k].source;
            lg[k] = links[k].coupling;
            lu[k] = links[k].unoccluded;
        }
        for (size_t i = 0; i < h.nodes.size(); ++i) {
            parent[i] = h.nodes[i].parent == kNoNode ? -1 : static_cast<int32_t>(h.nodes[i].parent);
            node_area[i] = h.nodes[i].area;
            node_cluster[i] = h.nodes[i].cluster;
        }
        for (size_t k = 0; k < leaves.size(); ++k) leaf_node[k] = static_cast<int32_t>(leaves[k]);
        d["link_receiver"] = to_numpy(std::move(lr), {links.size()});
        d["link_source"] = to_numpy(std::move(ls), {links.size()});
        d["link_coupling"] = to_numpy(std::move(lg), {links.size()});
        d["link_unoccluded"] = to_numpy(std::move(lu), {links.size()});
        d["node_parent"] = to_numpy(std::move(parent), {h.nodes.size()});
        d["node_area"] = to_numpy(std::move(node_area), {h.nodes.size()});
        d["node_cluster"] = to_numpy(std::move(node_cluster), {h.nodes.size()});
        d["leaf_node"] = to_numpy(std::move(leaf_node), {leaves.size()});
        state->radiosity = std::move(sol.radiosity);
        state->leaves = std::move(leaves);
        solved_ = std::move(state);
        return d;
    }

    Scene scene_;
    PatchSet patches_;
    std::unique_ptr<Visibility> visibility_;
    std::unique_ptr<LinkMatrix> links_;
    std::unique_ptr<SolvedHierarchy> solved_;
    DisplayMesh display_;
};

// A stored solution as a queryable surface: what `hirad render` and `hirad probe` use.
class SurfaceField {
public:
    SurfaceField(In<double> corners, In<int32_t> nv, In<double> corner_radiance, In<double> corner_irradiance)
        : patches_(patches_from_arrays(corners, nv)),
          radiance_(corner_values(corner_radiance, patches_.size(), "corner_radiance")),
          irradiance_(corner_values(corner_irradiance, patches_.size(), "corner_irradiance")),
          visibility_(patches_) {}

    nb::ndarray<nb::numpy, float> render(const std::vector<double>& position, const std::vector<double>& forward,
                                         const std::vector<double>& up, double fov, int width, int height, int samples) {
        if (position.size() != 3 || forward.size() != 3 || up.size() != 3)
            throw std::invalid_argument("camera vectors need 3 components");
        if (width <= 0 || height <= 0) throw std::invalid_argument("image size must be positive");
        Camera cam;
        cam.position = {position[0], position[1], position[2]};
        cam.forward = {forward[0], forward[1], forward[2]};
        cam.up = {up[0], up[1], up[2]};
        cam.vertical_fov_degrees = fov;
        cam.width = width;
        cam.height = height;
        std::vector<float> img;
        {
            nb::gil_scoped_release release;
            img = render_radiance(patches_, visibility_, radiance_, cam, samples);
        }
        return to_numpy(std::move(img), {size_t(height), size_t(width), 3});
    }

    // Closest surface point to each query point (optionally facing along its normal):
    // (patch index or -1, distance, irradiance (n,3), radiance (n,3)).
    nb::dict probe(In<double> points, In<double> normals, double max_distance) {
        const size_t n = points.shape(0);
        if (points.ndim() != 2 || points.shape(1) != 3 || normals.ndim() != 2 || normals.shape(0) != n)
            throw std::invalid_argument("points and normals: shape (n, 3)");
        std::vector<int32_t> patch(n);
        std::vector<double> distance(n), irr(n * 3), rad(n * 3);
        {
            nb::gil_scoped_release release;
            tbb::parallel_for(size_t(0), n, [&](size_t q) {
                const double* p = points.data() + 3 * q;
                const double* m = normals.data() + 3 * q;
                RayHit hit = visibility_.closest_point({p[0], p[1], p[2]}, {m[0], m[1], m[2]}, max_distance);
                patch[q] = hit.patch;
                distance[q] = hit.patch >= 0 ? hit.t : -1;
                if (hit.patch < 0) return;
                const int nv = patches_[hit.patch].nv;
                RGB e = interpolate_corners(nv, irradiance_[hit.patch], hit.u, hit.v);
                RGB l = interpolate_corners(nv, radiance_[hit.patch], hit.u, hit.v);
                for (int c = 0; c < 3; ++c) { irr[3 * q + c] = e[c]; rad[3 * q + c] = l[c]; }
            });
        }
        nb::dict d;
        d["patch"] = to_numpy(std::move(patch), {n});
        d["distance"] = to_numpy(std::move(distance), {n});
        d["irradiance"] = to_numpy(std::move(irr), {n, 3});
        d["radiance"] = to_numpy(std::move(rad), {n, 3});
        return d;
    }

private:
    std::vector<Patch> patches_;
    std::vector<std::array<RGB, 4>> radiance_, irradiance_;
    Visibility visibility_;
};

void write_exr_py(const std::string& path, In<float> rgb, const std::vector<std::pair<std::string, std::string>>& meta) {
    if (rgb.ndim() != 3 || rgb.shape(2) != 3) throw std::invalid_argument("rgb: expected shape (h, w, 3)");
    write_exr_rgb(path, static_cast<int>(rgb.shape(1)), static_cast<int>(rgb.shape(0)), rgb.data(), meta);
}

nb::ndarray<nb::numpy, float> read_exr_py(const std::string& path) {
    int w = 0, h = 0;
    std::vector<float> rgb = read_exr_rgb(path, w, h);
    return to_numpy(std::move(rgb), {size_t(h), size_t(w), 3});
}

double point_polygon_py(const std::vector<double>& x, const std::vector<double>& n, In<double> poly) {
    const int nv = static_cast<int>(poly.shape(0));
    if (nv < 3 || nv > 4) throw std::invalid_argument("polygon: 3 or 4 corners");
    Vec3 p[4];
    for (int k = 0; k < nv; ++k) p[k] = {poly.data()[3 * k], poly.data()[3 * k + 1], poly.data()[3 * k + 2]};
    Vec3 pn;
    for (int k = 0; k < nv; ++k) pn += cross(p[k], p[(k + 1) % nv]);
    return point_polygon_form_factor({x[0], x[1], x[2]}, normalize({n[0], n[1], n[2]}), p, nv, normalize(pn));
}

}  // namespace

// ---- irradiance volume, lightmap sample lifting, OpenVDB (free functions; see volume.h, vdb.h)
#include "formats/vdb.h"
#include "pipeline/outputs/volume.h"

namespace {

std::vector<Vec3> vec3_rows(const In<double>& a, const char* what) {
    if (a.ndim() != 2 || a.shape(1) != 3) throw std::invalid_argument(std::string(what) + ": shape (n, 3)");
    std::vector<Vec3> v(a.shape(0));
    for (size_t i = 0; i < v.size(); ++i) v[i] = {a.data()[3 * i], a.data()[3 * i + 1], a.data()[3 * i + 2]};
    return v;
}

// Full-sphere radiance moments at points in empty space, from a surface field's arrays.
nb::dict volume_probes_py(In<double> corners, In<int32_t> nv, In<double> corner_radiance, In<double> points,
                          int rays, uint64_t seed) {
    std::vector<Patch> patches = patches_from_arrays(corners, nv);
    auto radiance = corner_values(corner_radiance, patches.size(), "corner_radiance");
    std::vector<Vec3> pts = vec3_rows(points, "points");
    std::vector<ProbeMoments> m;
    {
        nb::gil_scoped_release release;
        Visibility vis(patches);
        m = probe_moments(patches, vis, radiance, pts, rays, seed);
    }
    const size_t n = m.size();
    std::vector<double> s0(n * 3), s1(n * 9), back(n), hit(n), nearest(n);
    for (size_t q = 0; q < n; ++q) {
        for (int c = 0; c < 3; ++c) {
            s0[3 * q + c] = m[q].s0[c];
            for (int a = 0; a < 3; ++a) s1[9 * q + 3 * a + c] = m[q].s1[a][c];
        }
        back[q] = m[q].back_fraction;
        hit[q] = m[q].hit_fraction;
        nearest[q] = m[q].nearest;
    }
    nb::dict d;
    d["s0"] = to_numpy(std::move(s0), {n, 3});
    d["s1"] = to_numpy(std::move(s1), {n, 3, 3});
    d["back_fraction"] = to_numpy(std::move(back), {n});
    d["hit_fraction"] = to_numpy(std::move(hit), {n});
    d["nearest"] = to_numpy(std::move(nearest), {n});
    return d;
}

nb::dict lift_samples_py(In<double> corners, In<int32_t> nv, In<double> points, In<double> normals, double epsilon,
                         double reach, std::optional<In<double>> anchors) {
    std::vector<Patch> patches = patches_from_arrays(corners, nv);
    std::vector<Vec3> pts = vec3_rows(points, "points"), nrm = vec3_rows(normals, "normals");
    if (nrm.size() != pts.size()) throw std::invalid_argument("points and normals differ in length");
    std::vector<Vec3> anc;
    if (anchors) {
        anc = vec3_rows(*anchors, "anchors");
        if (anc.size() != pts.size()) throw std::invalid_argument("points and anchors differ in length");
    }
    std::vector<uint8_t> moved;
    {
        nb::gil_scoped_release release;
        Visibility vis(patches);
        lift_samples(patches, vis, pts, nrm, epsilon, reach, moved, anchors ? &anc : nullptr);
    }
    std::vector<double> flat(pts.size() * 3);
    for (size_t q = 0; q < pts.size(); ++q)
        for (int c = 0; c < 3; ++c) flat[3 * q + c] = pts[q][c];
    nb::dict d;
    d["points"] = to_numpy(std::move(flat), {pts.size(), 3});
    d["moved"] = to_numpy(std::move(moved), {pts.size()});
    return d;
}

// First hits of rays against a surface field's patches: patch (-1 if none), t, point, and
// whether the hit face is a back face.
nb::dict ray_cast_py(In<double> corners, In<int32_t> nv, In<double> origins, In<double> directions) {
    std::vector<Patch> patches = patches_from_arrays(corners, nv);
    std::vector<Vec3> o = vec3_rows(origins, "origins"), d = vec3_rows(directions, "directions");
    if (o.size() != d.size()) throw std::invalid_argument("origins and directions differ in length");
    const size_t n = o.size();
    std::vector<int32_t> patch(n, -1);
    std::vector<double> t(n, -1), pts(n * 3, 0), nrm(n * 3, 0);
    std::vector<uint8_t> back(n, 0);
    {
        nb::gil_scoped_release release;
        Visibility vis(patches);
        tbb::parallel_for(size_t(0), n, [&](size_t q) {
            const Vec3 dir = normalize(d[q]);
            RayHit h = vis.intersect(o[q], dir);
            if (h.patch < 0) return;
            patch[q] = h.patch;
            t[q] = h.t;
            const Vec3 x = o[q] + dir * h.t;
            const Vec3& m = patches[h.patch].normal;
            for (int c = 0; c < 3; ++c) { pts[3 * q + c] = x[c]; nrm[3 * q + c] = m[c]; }
            back[q] = dot(m, dir) >= 0;
        });
    }
    nb::dict r;
    r["patch"] = to_numpy(std::move(patch), {n});
    r["t"] = to_numpy(std::move(t), {n});
    r["points"] = to_numpy(std::move(pts), {n, 3});
    r["normals"] = to_numpy(std::move(nrm), {n, 3});
    r["back"] = to_numpy(std::move(back), {n});
    return r;
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
        if (coords.ndim() != 2 || coords.shape(1) != 3 || values.ndim() != 2 || values.shape(1) != 3 ||
            coords.shape(0) != values.shape(0))
            throw std::invalid_argument("grid " + g.name + ": coords and values of shape (n, 3)");
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

NB_MODULE(_engine, m) {
    m.doc() = "hirad's C++ engine: meshing, form factors, solvers, reconstruction, rendering, EXR";
    m.def("set_threads", &set_threads, "threads"_a, "Caps the engine's TBB threads (0 = all cores).");
    m.def("parallel_rectangles_form_factor", &parallel_rectangles_form_factor, "a"_a, "b"_a, "c"_a);
    m.def("perpendicular_rectangles_form_factor", &perpendicular_rectangles_form_factor, "l"_a, "h"_a, "w"_a);
    m.def("point_polygon_form_factor", &point_polygon_py, "x"_a, "normal"_a, "polygon"_a);
    m.def("write_exr", &write_exr_py, "path"_a, "rgb"_a, "metadata"_a);
    m.def("read_exr", &read_exr_py, "path"_a);

    nb::class_<Model>(m, "Model")
        .def(nb::init<In<double>, In<int32_t>, In<int32_t>, In<int32_t>, In<int32_t>, In<double>, In<double>,
                      std::optional<In<double>>>(),
             "points"_a, "face_vertex_counts"_a, "face_vertex_indices"_a, "face_mesh"_a, "face_source"_a,
             "reflectance"_a, "emission"_a, "corner_uv"_a.none())
        .def("stats", &Model::stats)
        .def("mesh", &Model::mesh, "max_area"_a, "max_edge_length"_a)
        .def_prop_ro("num_patches", &Model::num_patches)
        .def("patch_arrays", &Model::patch_arrays)
        .def("compute_links", &Model::compute_links, "method"_a, "samples"_a, "hemicube_resolution"_a,
             "hemicube_points"_a, "seed"_a, "progress"_a.none())
        .def("solve", &Model::solve, "method"_a, "tolerance"_a, "max_iterations"_a, "samples"_a, "seed"_a,
             "snapshot_every"_a, "snapshot"_a.none(), "progress"_a.none())
        .def("transport", &Model::transport, "radiosity"_a, "samples"_a, "seed"_a)
        .def("residual_of", &Model::residual_of, "radiosity"_a)
        .def("display_mesh", &Model::display_mesh, "crease_angle"_a)
        .def("vertex_values", &Model::vertex_values_of, "patch_values"_a)
        .def("form_factor", &Model::form_factor, "i"_a, "j"_a, "samples"_a, "seed"_a)
        .def("hemicube_row", &Model::hemicube_row, "i"_a, "resolution"_a, "points"_a)
        .def("rays_cast", &Model::rays_cast)
        .def("gather", &Model::gather, "points"_a, "normals"_a, "rays"_a = 4, "cluster_samples"_a = 8, "seed"_a = 1,
             "max_distance"_a = 1e30)
        .def("gather_flat", &Model::gather_flat, "points"_a, "normals"_a, "radiosity"_a, "rays"_a = 4, "seed"_a = 1)
        .def("solve_out_of_core", &Model::solve_out_of_core, "epsilon"_a, "min_area"_a, "samples"_a, "seed"_a,
             "tolerance"_a, "max_iterations"_a, "max_rounds"_a, "progress"_a = nb::none(), "store"_a = "",
             "memory_budget"_a = 0, "group_faces"_a = 1024, "checkpoint_seconds"_a = 0.0, "resume"_a = false,
             "reuse_links"_a = false)
        .def("solve_hierarchical", &Model::solve_hierarchical, "epsilon"_a, "min_area"_a, "samples"_a, "seed"_a,
             "tolerance"_a, "max_iterations"_a, "max_rounds"_a, "progress"_a.none() = nb::none(), "solver"_a = "jacobi")
        .def("reference_at", &Model::reference_at, "points"_a, "normals"_a, "paths"_a, "min_bounces"_a, "seed"_a,
             "max_distance"_a)
        .def("reference", &Model::reference, "patch"_a, "st"_a, "paths"_a, "min_bounces"_a, "seed"_a);

    nb::class_<SurfaceField>(m, "SurfaceField")
        .def(nb::init<In<double>, In<int32_t>, In<double>, In<double>>(), "corners"_a, "nv"_a, "corner_radiance"_a,
             "corner_irradiance"_a)
        .def("render", &SurfaceField::render, "position"_a, "forward"_a, "up"_a, "vertical_fov"_a, "width"_a,
             "height"_a, "samples"_a)
        .def("probe", &SurfaceField::probe, "points"_a, "normals"_a, "max_distance"_a);

    m.def("volume_probes", &volume_probes_py, "corners"_a, "nv"_a, "corner_radiance"_a, "points"_a, "rays"_a = 256,
          "seed"_a = 1, "Full-sphere radiance moments s0 = integral L dw (n,3) and s1[a] = integral L w_a dw (n,3,3) "
          "at points in empty space; back_fraction, hit_fraction and nearest hit distance per point.");
    m.def("lift_samples", &lift_samples_py, "corners"_a, "nv"_a, "points"_a, "normals"_a, "epsilon"_a, "reach"_a,
          "anchors"_a.none() = nb::none(),
          "Lightmap sample points lifted along their normals and moved out of geometry: points, moved.");
    m.def("ray_cast", &ray_cast_py, "corners"_a, "nv"_a, "origins"_a, "directions"_a,
          "First hits of rays against patches: patch, t, points, normals, back.");
    m.def("write_vdb", &write_vdb_py, "path"_a, "grids"_a, "voxel_size"_a, "origin"_a, "metadata"_a);
    m.def("read_vdb", &read_vdb_py, "path"_a);
}
