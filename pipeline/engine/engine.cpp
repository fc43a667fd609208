#include "pipeline/engine/engine.h"

#include <tbb/blocked_range.h>
#include <tbb/global_control.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cstring>
#include <atomic>
#include <chrono>
#include <mutex>
#include <stdexcept>
#include <utility>

#include "pipeline/geometry/formfactors.h"
#include "pipeline/geometry/hemicube.h"
#include "pipeline/hierarchy/hierarchical_solver.h"
#include "pipeline/outofcore/outofcore.h"
#include "pipeline/outofcore/run_store.h"
#include "pipeline/engine/ray_scene.h"
#include "pipeline/outputs/volume.h"

namespace hirad {

namespace {

std::unique_ptr<tbb::global_control> g_threads;

// Elements whose patches are made from the hierarchy at once where a stage needs whole
// patches of all of them (lighting, distant lights' power): 65,536 patches, 21 MB.
constexpr size_t kMadeBlock = 65536;

// Calls each(b, e, made, shapes) for every block [b, e) of [0, count), kMadeBlock at a time,
// with made[k - b] = make(k) and shapes[k - b] = &made[k - b].
template <class Make, class Each>
void in_made_blocks(size_t count, Make&& make, Each&& each) {
    std::vector<Patch> made;
    std::vector<Patch*> shapes;
    for (size_t b = 0; b < count; b += kMadeBlock) {
        const size_t e = std::min(count, b + kMadeBlock);
        made.resize(e - b);
        shapes.resize(e - b);
        for (size_t k = b; k < e; ++k) {
            made[k - b] = make(k);
            shapes[k - b] = &made[k - b];
        }
        each(b, e, made, shapes);
    }
}

// Hemicube rows are not reciprocal on their own; the stored coupling is the mean of the two
// directions, G_ij = (A_i F_ij + A_j F_ji) / 2.
LinkMatrix symmetric_hemicube_links(const std::vector<Patch>& patches, const Hemicube& hc, const DoneFn& done) {
    const uint32_t n = static_cast<uint32_t>(patches.size());
    std::vector<std::vector<std::pair<uint32_t, double>>> rows(n);
    std::atomic<uint64_t> finished{0};
    tbb::parallel_for(uint32_t(0), n, [&](uint32_t i) {
        hc.row(i, rows[i]);
        const uint64_t d = ++finished;
        if (done) done(d);
    });
    std::vector<std::vector<std::pair<uint32_t, float>>> upper(n);
    auto find = [&](uint32_t i, uint32_t j) {
        auto it = std::lower_bound(rows[i].begin(), rows[i].end(), std::make_pair(j, -1.0));
        return (it != rows[i].end() && it->first == j) ? it->second : 0.0;
    };
    tbb::parallel_for(uint32_t(0), n, [&](uint32_t i) {
        const double ai = patches[i].area;
        // Pairs seen from either side: walk row i (j > i) and pick up j's view of i.
        for (const auto& [j, f] : rows[i])
            if (j > i) upper[i].emplace_back(j, static_cast<float>(0.5 * (ai * f + patches[j].area * find(j, i))));
    });
    // Pairs that only j saw (j < i would be in row j; j > i only in row j): add them.
    for (uint32_t j = 0; j < n; ++j)
        for (const auto& [i, f] : rows[j])
            if (i < j && find(i, j) == 0.0) upper[i].emplace_back(j, static_cast<float>(0.5 * patches[j].area * f));
    for (auto& u : upper) std::sort(u.begin(), u.end());
    return LinkMatrix::from_upper(n, upper);
}

// Exitant radiance of a surface with irradiance e (from the surfaces and the luminaires):
// (E_self + rho H) / pi, E_self its emission without the luminaires' part rho x direct.
RGB exitant(const Patch& s, const RGB& e) { return (s.self_emission() + mul(s.reflectance, e)) / kPi; }

// Element samples per side for the luminaires' light over a patch or element (g x g points).
constexpr int kLuminaireSamples = 3;

void require_points(const std::vector<Vec3>& points, const std::vector<Vec3>& normals) {
    if (normals.size() != points.size()) throw std::invalid_argument("points and normals differ in length");
}

}  // namespace

void set_threads(int threads) {
    g_threads.reset();
    if (threads > 0) g_threads = std::make_unique<tbb::global_control>(tbb::global_control::max_allowed_parallelism, threads);
}

// What a hierarchical solve leaves behind for publishing and the final gather.
struct Engine::Solved {
    explicit Solved(const Scene& scene) : hierarchy(scene) {}
    Hierarchy hierarchy;
    std::unique_ptr<Visibility> visibility;  // over hierarchy.faces
    std::vector<Link> links;                 // sorted by receiver (in memory; let go for gather_table)
    std::unique_ptr<GatherLinks> gather_table;  // what the gathers read, made by the first
    std::vector<RGB> radiosity;              // per node
    std::vector<uint32_t> leaves;            // node of each leaf (of each published patch)
    std::vector<uint32_t> leaf_index;        // per node, its place in `leaves` (gathers before publishing)
    uint64_t rays_at_solve = 0;              // its BVH's rays at the solve's end (the solve's own)
    std::vector<std::vector<RGB>> group_radiosity;  // per light group, per node
    std::string store_round;                 // out of core: the final links' store
    size_t groups = 0;                       // and its number of source groups
    // The last gather's Gatherer, kept for the next gather with the same options and light
    // group: its cell cache (GatherOptions::second_bounce) and descent steps then serve every
    // call of a lightmap bake (one a page, or one a level of hirad.atlas.evaluate_adaptive),
    // not one call each. A cell's value depends on its key alone, so keeping it changes no
    // bits. Gathers on one engine take turns (the cache is cleared between blocks).
    std::unique_ptr<Gatherer> gatherer;
    GatherOptions gatherer_options;
    int gatherer_group = -2;
    std::mutex gather_mutex;
};

Engine::Engine(const SceneInput& in, size_t num_indices) {
    size_t corners = 0;
    for (size_t f = 0; f < in.num_faces; ++f) {
        if (in.face_vertex_counts[f] < 0) throw std::invalid_argument("face_vertex_counts: negative count");
        corners += in.face_vertex_counts[f];
    }
    if (num_indices != corners) throw std::invalid_argument("face_vertex_indices: length != sum of counts");
    scene_ = Scene::build(in);
    glazing_.face_transmittance.resize(scene_.faces.size());
    for (size_t f = 0; f < scene_.faces.size(); ++f) glazing_.face_transmittance[f] = scene_.faces[f].transmittance;
    glazing_.validate();
}

void Engine::set_glass_angular(std::vector<double> relative) {
    Glazing g = glazing_;
    g.angular = std::move(relative);
    g.validate();
    glazing_ = std::move(g);
    if (visibility_) visibility_ = std::make_unique<Visibility>(patch_view(), &glazing_);
}

Engine::~Engine() = default;

Stats Engine::stats() const {
    Stats s;
    s.input_faces = scene_.stats.input_faces;
    s.faces = scene_released_ ? scene_faces_ : scene_.faces.size();
    s.degenerate_faces = scene_.stats.degenerate_faces;
    s.nonfinite_faces = scene_.stats.nonfinite_faces;
    s.self_intersecting_faces = scene_.stats.self_intersecting_faces;
    s.triangulated_faces = scene_.stats.triangulated_faces;
    s.nonmanifold_edges = scene_.stats.nonmanifold_edges;
    s.patches = num_patches();
    s.links = links_ ? links_->link_count() : 0;
    s.link_bytes = links_ ? links_->bytes() : 0;
    s.rays = rays_cast();
    return s;
}

void Engine::require_scene(const char* what) const {
    if (scene_released_)
        throw std::invalid_argument(std::string(what) + ": the input faces were let go (release_scene)");
}

void Engine::require_mesh() const {
    if (!visibility_ && patches_released_)
        throw std::invalid_argument("the patches were let go once every output was made (release_patches)");
    if (!visibility_) throw std::invalid_argument("no patches yet: call mesh() (or use_leaves_as_patches()) first");
}

void Engine::require_index(uint32_t i) const {
    require_mesh();
    if (i >= num_patches()) throw std::out_of_range("patch index out of range");
}

void Engine::require_flat(const char* what) const {
    if (!leaves_.empty())
        throw std::invalid_argument(std::string(what) + " is the flat method's: the patches are a hierarchical solve's "
                                    "leaves");
}

std::vector<Patch> Engine::patch_vector() const {
    if (leaves_.empty()) return patches_.patches;
    std::vector<Patch> out(leaves_.size());
    for (size_t i = 0; i < out.size(); ++i) leaves_.get(i, out[i]);
    return out;
}

void Engine::replace_patches(PatchSet patches) {
    links_.reset();
    visibility_.reset();  // it refers to the old patches
    display_ = DisplayMesh{};
    patches_ = std::move(patches);
    leaves_ = FaceTable(PatchCentroid::CornerMean, Welding::ByMesh);
    visibility_ = std::make_unique<Visibility>(patches_.patches, &glazing_);
}

void Engine::mesh(const MeshOptions& o) {
    require_scene("mesh");
    if (!(o.max_patch_area > 0) || !(o.max_edge_length > 0)) throw std::invalid_argument("meshing limits must be positive");
    if (scene_.faces.empty()) throw std::invalid_argument("the scene has no usable faces");
    leaves_published_ = false;
    replace_patches(mesh_patches(scene_, {o.max_patch_area, o.max_edge_length, o.max_patches}));
    if (!luminaires_.empty()) {
        std::vector<Patch*> all;
        for (Patch& p : patches_.patches) all.push_back(&p);
        light_patches(all, *visibility_, nullptr);
    }
}

void Engine::set_luminaires(std::vector<Luminaire> luminaires) {
    for (const Luminaire& l : luminaires) l.validate();
    luminaires_ = std::move(luminaires);
    if (visibility_ && !leaves_published_) {
        std::vector<Patch*> all;
        for (Patch& p : patches_.patches) all.push_back(&p);
        light_patches(all, *visibility_, nullptr);
    }
}

RGB Engine::luminaire_flux() const {
    RGB f{};
    for (const Luminaire& l : luminaires_) f += l.flux();
    return f;
}

void Engine::set_light_groups(std::vector<LightGroup> groups) {
    require_scene("set_light_groups");
    uint32_t meshes = 0;
    for (const Face& f : scene_.faces) meshes = std::max(meshes, f.mesh + 1);
    std::vector<std::vector<uint8_t>> in(groups.size());
    for (size_t k = 0; k < groups.size(); ++k) {
        for (const Luminaire& l : groups[k].luminaires) l.validate();
        in[k].assign(meshes, 0);
        for (uint32_t m : groups[k].meshes) {
            if (m > (1u << 30)) throw std::invalid_argument("light group " + std::to_string(k) + ": mesh index out of range");
            if (m < meshes) in[k][m] = 1;  // a mesh with no usable face: nothing to emit
        }
    }
    groups_ = std::move(groups);
    group_mesh_ = std::move(in);
}

RGB Engine::group_emission(const LightGroup& g, uint32_t face) const {
    const size_t k = static_cast<size_t>(&g - groups_.data());
    const FaceRecord f = face_record(face);
    return (f.mesh < group_mesh_[k].size() && group_mesh_[k][f.mesh]) ? f.emission : RGB{};
}

std::vector<RGB> Engine::groups_direct(size_t begin, size_t end, const Visibility& vis,
                                      const std::vector<Patch*>& shapes) const {
    // The interleaved sky directions of the groups before `begin` (their numbering goes on).
    size_t sky_start = 0;
    for (size_t q = 0; q < begin; ++q)
        for (const Luminaire& l : groups_[q].luminaires)
            if (l.distant && l.interleave) sky_start += l.points.size();
    std::vector<Luminaire> lights;
    std::vector<uint32_t> owner;
    for (size_t q = begin; q < end; ++q)
        for (const Luminaire& l : groups_[q].luminaires) {
            lights.push_back(l);
            owner.push_back(uint32_t(q - begin));
        }
    std::vector<RGB> out;
    if (lights.empty() || shapes.empty()) {
        out.assign((end - begin) * shapes.size(), RGB{});
        return out;
    }
    element_group_irradiance(lights, owner, end - begin, vis, shapes.data(), shapes.size(), kLuminaireSamples, out,
                             sky_start);
    return out;
}

namespace {

// The groups' direct light (groups_direct's layout: group-major over `ids`) of the elements'
// open parts, as light_new_elements gives the total's (Hierarchy::open).
void to_open_parts(const Hierarchy& h, const std::vector<uint32_t>& ids, std::vector<RGB>& lit) {
    if (ids.empty()) return;
    for (size_t k = 0; k < lit.size(); ++k) {
        const double open = h.open_share(ids[k % ids.size()]);
        if (open > 0 && open < 1) lit[k] = lit[k] / open;
    }
}

}  // namespace

size_t Engine::group_batch(size_t elements) const {
    // Groups lit together: their direct light held for every element, at most ~256 MB of it.
    const size_t per_group = std::max<size_t>(1, elements) * sizeof(RGB);
    return std::clamp<size_t>((size_t(256) << 20) / per_group, 1, 64);
}

std::vector<HierarchicalSolution> Engine::solve_groups_on(
    Hierarchy& h, const Visibility& vis,
    const std::function<HierarchicalSolution(const std::vector<RGB>& start)>& solve,
    std::vector<double>* seconds) const {
    std::vector<HierarchicalSolution> out;
    if (groups_.empty()) return out;
    // The elements' patches, made once from the hierarchy (light groups light them per group);
    // what each group gives them is written back to the hierarchy, which the solves read.
    std::vector<Patch> made;
    std::vector<Patch*> shapes;
    std::vector<uint32_t> ids;
    h.measure_open(vis);
    for (uint32_t i = 0; i < h.nodes.size(); ++i)
        if (!h.nodes[i].cluster) {
            made.push_back(h.shape(i));
            ids.push_back(i);
        }
    for (Patch& p : made) shapes.push_back(&p);
    std::vector<RGB> emission(shapes.size()), direct(shapes.size());
    for (size_t k = 0; k < shapes.size(); ++k) {
        emission[k] = shapes[k]->emission;
        direct[k] = shapes[k]->direct;
    }
    const size_t batch = group_batch(shapes.size());
    std::vector<RGB> lit;
    for (size_t q = 0; q < groups_.size(); ++q) {
        const auto t0 = std::chrono::steady_clock::now();
        const size_t first = q - q % batch;
        if (q == first) {
            lit = groups_direct(first, std::min(groups_.size(), first + batch), vis, shapes);
            to_open_parts(h, ids, lit);
        }
        const RGB* d = lit.data() + (q - first) * shapes.size();
        for (size_t k = 0; k < shapes.size(); ++k) {
            Patch& p = *shapes[k];
            p.direct = d[k];
            p.emission = (p.back ? RGB{} : group_emission(groups_[q], p.face)) + mul(p.reflectance, d[k]);
            h.set_light(ids[k], p.direct, p.emission);
        }
        // As every round's solve: from the emission (rounds.cpp).
        std::vector<RGB> start = node_emission(h);
        for (size_t i = start.size(); i < h.nodes.size(); ++i) start.push_back(start[h.nodes[i].parent]);
        out.push_back(solve(start));
        if (seconds)
            seconds->push_back(std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
    }
    for (size_t k = 0; k < shapes.size(); ++k) h.set_light(ids[k], direct[k], emission[k]);
    return out;
}

void Engine::light_patches(std::vector<Patch*>& patches, const Visibility& vis, std::vector<double>* spread) const {
    std::vector<RGB> mean;
    std::vector<double> sp;
    if (luminaires_.empty()) {
        mean.assign(patches.size(), RGB{});
        sp.assign(patches.size(), 0.0);
    } else {
        element_luminaire_irradiance(luminaires_, vis, patches.data(), patches.size(), kLuminaireSamples, mean, sp);
    }
    for (size_t k = 0; k < patches.size(); ++k) {
        Patch& p = *patches[k];
        p.direct = mean[k];
        p.emission = (p.back ? RGB{} : face_record(p.face).emission) + mul(p.reflectance, mean[k]);
    }
    if (spread) *spread = std::move(sp);
}

void Engine::light_new_elements(Hierarchy& h, const Visibility& vis, std::vector<uint32_t>* fresh,
                                std::vector<double>* spread) const {
    std::vector<uint32_t> ids;
    for (uint32_t i = 0; i < h.nodes.size(); ++i)
        if (!h.nodes[i].cluster && !h.nodes[i].lit) ids.push_back(i);
    // The elements' patches made kMadeBlock at a time (the hierarchy keeps its faces compact),
    // lit, and their light written back.
    if (spread) spread->clear();
    std::vector<double> block_spread;
    in_made_blocks(ids.size(), [&](size_t k) { return h.shape(ids[k]); },
                   [&](size_t b, size_t e, const std::vector<Patch>& made, std::vector<Patch*>& shapes) {
                       light_patches(shapes, vis, spread ? &block_spread : nullptr);
                       for (size_t k = b; k < e; ++k) h.set_light(ids[k], made[k - b].direct, made[k - b].emission);
                       if (spread) spread->insert(spread->end(), block_spread.begin(), block_spread.end());
                   });
    // The direct light of the element's open part (Hierarchy::open), like its links' light.
    h.measure_open(vis);
    for (uint32_t i : ids) {
        h.nodes[i].lit = true;
        const double open = h.open_share(i);
        if (open > 0 && open < 1) {  // the emission the solve starts from holds rho x direct too
            const RGB& rho = h.reflectance(i);
            const RGB own = h.emission(i) - mul(rho, h.direct(i));  // Patch::self_emission
            const RGB direct = h.direct(i) / open;
            h.set_light(i, direct, own + mul(rho, direct));
        }
    }
    if (fresh) *fresh = std::move(ids);
}

void Engine::split_for_luminaires(Hierarchy& h, const Visibility& vis, double epsilon_watts, double min_area) const {
    // Breadth first, in node order: each pass lights the new elements and splits those whose
    // light varies by more than epsilon_watts over their area. The same scene and luminaires
    // give the same splits in the same order (the run store's log replays them).
    for (;;) {
        std::vector<uint32_t> fresh;
        std::vector<double> spread;
        light_new_elements(h, vis, &fresh, &spread);
        if (fresh.empty() || luminaires_.empty()) return;
        bool split = false;
        for (size_t k = 0; k < fresh.size(); ++k) {
            const uint32_t i = fresh[k];
            if (spread[k] * h.nodes[i].area > epsilon_watts && h.can_subdivide(i, min_area)) {
                h.subdivide(i);
                split = true;
            }
        }
        if (!split) return;
    }
}

double Engine::distant_power(const FaceTable& faces, const Visibility& vis) const {
    // Distant lights have no flux of their own: what they deliver to the input faces (their
    // luminance Y, W or lm) takes its place in epsilon x the emitted power. One point a face.
    std::vector<Luminaire> distant;
    for (const Luminaire& l : luminaires_)
        if (l.distant) distant.push_back(l);
    if (distant.empty()) return 0;
    // The faces' patches made kMadeBlock at a time (the table keeps them compact).
    double power = 0;
    std::vector<RGB> mean;
    std::vector<double> spread;
    in_made_blocks(faces.size(), [&](size_t k) { return faces[k]; },
                   [&](size_t b, size_t e, const std::vector<Patch>& made, std::vector<Patch*>& shapes) {
                       element_luminaire_irradiance(distant, vis, shapes.data(), shapes.size(), 1, mean, spread);
                       for (size_t k = b; k < e; ++k) {
                           const Patch& f = made[k - b];
                           // glass: only what it reflects enters the exchange (what it lets
                           // through lands elsewhere)
                           const bool glass = face_record(f.face).transmittance > 0;
                           power += luminance(glass ? mul(f.reflectance, mean[k - b]) : mean[k - b]) * f.area;
                       }
                   });
    return power;
}

std::vector<RGB> Engine::luminaire_light(const std::vector<Vec3>& x, const std::vector<Vec3>& n,
                                         const Visibility& vis) const {
    std::vector<RGB> out(x.size());
    if (luminaires_.empty()) return out;
    luminaire_irradiance(luminaires_, &vis, x.data(), n.data(), x.size(), out.data(), vis.ray_offset());
    return out;
}

PatchArrays Engine::patch_arrays() const {
    if (patches_released_) require_mesh();  // says they were let go
    const PatchView P = patch_view();
    const size_t n = P.size();
    PatchArrays a;
    a.count = n;
    a.corners.resize(n * 12);
    a.uv.resize(n * 8);
    a.area.resize(n);
    a.normal.resize(n * 3);
    a.centroid.resize(n * 3);
    a.reflectance.resize(n * 3);
    a.emission.resize(n * 3);
    a.direct.resize(n * 3);
    a.nv.resize(n);
    a.mesh.resize(n);
    a.face.resize(n);
    a.source_face.resize(n);
    a.transmittance.resize(n);
    Patch scratch;
    for (size_t i = 0; i < n; ++i) {
        const Patch& p = P.get(i, scratch);
        const FaceRecord r = face_record(p.face);
        for (int k = 0; k < 4; ++k) {
            for (int c = 0; c < 3; ++c) a.corners[i * 12 + k * 3 + c] = p.p[k][c];
            a.uv[i * 8 + k * 2] = p.uv[k].u;
            a.uv[i * 8 + k * 2 + 1] = p.uv[k].v;
        }
        for (int c = 0; c < 3; ++c) {
            a.normal[i * 3 + c] = p.normal[c];
            a.centroid[i * 3 + c] = p.centroid[c];
            a.reflectance[i * 3 + c] = p.reflectance[c];
            a.emission[i * 3 + c] = r.emission[c];
            a.direct[i * 3 + c] = p.direct[c];
        }
        a.area[i] = p.area;
        a.nv[i] = p.nv;
        a.mesh[i] = static_cast<int32_t>(p.mesh);
        a.face[i] = static_cast<int32_t>(p.face);
        a.source_face[i] = static_cast<int32_t>(r.source_face);
        a.transmittance[i] = r.transmittance;
    }
    return a;
}

void Engine::compute_links(const FormFactorOptions& o, const DoneFn& done) {
    require_mesh();
    require_flat("compute_links");
    const uint32_t n = static_cast<uint32_t>(patches_.patches.size());
    if (o.method == "raycast") {
        RayCastFormFactors ff(patches_.patches, *visibility_, {o.samples, o.seed});
        links_ = std::make_unique<LinkMatrix>(LinkMatrix::build(
            n, [&](uint32_t i, auto& out) { ff.upper_couplings_of(i, out); },
            [&](uint32_t d) { if (done) done(d); }));
    } else if (o.method == "hemicube") {
        Hemicube hc(patches_.patches, {o.hemicube_resolution, o.hemicube_points});
        links_ = std::make_unique<LinkMatrix>(symmetric_hemicube_links(patches_.patches, hc, done));
    } else {
        throw std::invalid_argument("unknown form factor method '" + o.method + "' (raycast or hemicube)");
    }
}

RadiositySystem Engine::system() const {
    RadiositySystem sys;
    sys.links = links_.get();
    for (const Patch& p : patches_.patches) {
        sys.area.push_back(p.area);
        sys.reflectance.push_back(p.reflectance);
        sys.emission.push_back(p.emission);
    }
    return sys;
}

FlatSolveResult Engine::solve(const SolveOptions& o, const FormFactorOptions& ff, const SnapshotFn& snapshot,
                              const FlatProgressFn& progress) {
    require_mesh();
    require_flat("solve");
    RadiositySystem sys = system();
    SolverOptions base;
    base.tolerance = o.tolerance;
    base.max_iterations = o.max_iterations;
    base.on_iteration = [&](const IterationReport& r) {
        if (progress) progress(r.iteration, r.residual);
        return true;
    };
    Solution sol;
    FlatSolveResult out;
    if (o.method == "progressive") {
        ProgressiveOptions opt;
        static_cast<SolverOptions&>(opt) = base;
        opt.snapshot_every = snapshot ? o.snapshot_every : 0;
        opt.snapshot = snapshot;
        RayCastFormFactors rff(patches_.patches, *visibility_, RayCastOptions{ff.samples, ff.seed});
        sol = solve_progressive(sys, [&](uint32_t i, auto& row) { rff.couplings_of(i, row); }, opt, &out.rows_computed);
    } else {
        if (!links_) throw std::invalid_argument("solver '" + o.method + "' needs links: compute_links first");
        if (o.method == "direct") sol = solve_direct(sys);
        else if (o.method == "jacobi") sol = solve_jacobi(sys, base);
        else if (o.method == "gauss_seidel") sol = solve_gauss_seidel(sys, base);
        else if (o.method == "southwell") sol = solve_southwell(sys, base);
        else throw std::invalid_argument("unknown solver '" + o.method + "'");
    }
    out.radiosity = std::move(sol.radiosity);
    out.iterations = sol.iterations;
    out.residual = sol.residual;
    out.converged = sol.converged;
    out.residual_history = std::move(sol.residual_history);
    return out;
}

Transport Engine::transport(const std::vector<RGB>& b, const FormFactorOptions& o) const {
    require_mesh();
    require_flat("transport");
    const uint32_t n = static_cast<uint32_t>(patches_.patches.size());
    if (b.size() != n) throw std::invalid_argument("radiosity: one row per patch");
    Transport t;
    t.irradiance.resize(n);
    t.escaped.resize(n);
    std::unique_ptr<RayCastFormFactors> ff;
    if (!links_) ff = std::make_unique<RayCastFormFactors>(patches_.patches, *visibility_, RayCastOptions{o.samples, o.seed});
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
        t.irradiance[i] = acc / a;
        // Not clamped: sampling makes some rows sum a little above 1, others below, and only
        // the signed values add up to the power that really leaves the scene.
        t.escaped[i] = b[i] * (a - g_sum);
    });
    return t;
}

std::vector<GroupSolution> Engine::solve_groups(const SolveOptions& o, const FormFactorOptions& ff) {
    require_mesh();
    require_flat("solve_groups");
    std::vector<GroupSolution> out;
    if (groups_.empty()) return out;
    std::vector<Patch>& P = patches_.patches;
    std::vector<Patch*> shapes;
    for (Patch& p : P) shapes.push_back(&p);
    std::vector<RGB> emission(P.size()), direct(P.size());
    for (size_t i = 0; i < P.size(); ++i) {
        emission[i] = P[i].emission;
        direct[i] = P[i].direct;
    }
    struct Restore {
        std::vector<Patch>& P;
        const std::vector<RGB>& e;
        const std::vector<RGB>& d;
        ~Restore() {
            for (size_t i = 0; i < P.size(); ++i) {
                P[i].emission = e[i];
                P[i].direct = d[i];
            }
        }
    } restore{P, emission, direct};
    const size_t batch = group_batch(shapes.size());
    std::vector<RGB> lit;
    for (size_t q = 0; q < groups_.size(); ++q) {
        const auto t0 = std::chrono::steady_clock::now();
        GroupSolution gs;
        const size_t first = q - q % batch;
        if (q == first) lit = groups_direct(first, std::min(groups_.size(), first + batch), *visibility_, shapes);
        gs.direct.assign(lit.begin() + (q - first) * shapes.size(), lit.begin() + (q - first + 1) * shapes.size());
        for (size_t i = 0; i < P.size(); ++i) {
            P[i].direct = gs.direct[i];
            P[i].emission = group_emission(groups_[q], P[i].face) + mul(P[i].reflectance, gs.direct[i]);
        }
        FlatSolveResult r = solve(o, ff);
        gs.irradiance = transport(r.radiosity, ff).irradiance;
        gs.radiosity = std::move(r.radiosity);
        gs.iterations = r.iterations;
        gs.residual = r.residual;
        gs.converged = r.converged;
        gs.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
        out.push_back(std::move(gs));
    }
    return out;
}

double Engine::residual_of(const std::vector<RGB>& b) const {
    if (!links_) throw std::invalid_argument("residual_of needs links: compute_links first");
    RadiositySystem sys = system();
    if (b.size() != sys.size()) throw std::invalid_argument("radiosity: one row per patch");
    return relative_residual(sys, b);
}

double Engine::form_factor(uint32_t i, uint32_t j, int samples, uint64_t seed) const {
    require_flat("form_factor");
    require_index(i);
    require_index(j);
    RayCastFormFactors ff(patches_.patches, *visibility_, {samples, seed});
    return ff.form_factor(i, j);
}

std::vector<double> Engine::hemicube_row(uint32_t i, int resolution, int points) const {
    require_flat("hemicube_row");
    require_index(i);
    Hemicube hc(patches_.patches, {resolution, points});
    std::vector<std::pair<uint32_t, double>> row;
    hc.row(i, row);
    std::vector<double> dense(patches_.patches.size(), 0.0);
    for (const auto& [j, f] : row) dense[j] = f;
    return dense;
}

uint64_t Engine::rays_cast() const {
    // the patches' BVH, the hierarchy's since its solve (its gathers), and those let go
    return (visibility_ ? visibility_->rays_cast() : 0) + rays_let_go_ +
           (solved_ ? solved_->visibility->rays_cast() - solved_->rays_at_solve : 0);
}

// ---- hierarchical ------------------------------------------------------------------------

namespace {
// The refiner's options: epsilon scaled by the emitted power to watts.
RefineOptions refine_options(const HierarchyOptions& o, double emitted) {
    RefineOptions r;
    r.epsilon = o.epsilon * emitted;
    r.min_area = o.min_area;
    r.samples = o.samples;
    r.seed = o.seed;
    r.relative = o.relative;
    r.spread = o.spread * r.epsilon;
    r.cluster_receivers = o.cluster_receivers;
    return r;
}
}  // namespace

std::unique_ptr<Engine::Solved> Engine::fresh_hierarchy(const HierarchyOptions& o, double& emitted) {
    require_scene("a hierarchical solve");
    if (scene_.faces.empty()) throw std::invalid_argument("the scene has no usable faces");
    if (!(o.epsilon >= 0) || !(o.min_area > 0)) throw std::invalid_argument("epsilon >= 0 and min_area > 0 required");
    if (!(o.relative >= 0 && o.relative < 1)) throw std::invalid_argument("relative must be in [0, 1)");
    if (!(o.spread >= 0 && o.spread <= 1)) throw std::invalid_argument("spread must be in [0, 1]");
    if (o.max_rounds < 1) throw std::invalid_argument("max_rounds must be at least 1");
    if (!(o.closure_reflectance >= 0 && o.closure_reflectance <= 1))
        throw std::invalid_argument("closure_reflectance must be in [0, 1]");
    links_.reset();
    solved_.reset();
    hierarchy_released_ = false;
    auto state = std::make_unique<Solved>(scene_);
    // The hierarchy has its copy: the input faces go before its BVH and the luminaires' light
    // are made (a 615k-triangle floor: the heap's peak was here, 136 MB of them held).
    if (o.release_scene) release_scene();
    state->hierarchy.closure_reflectance = o.closure_reflectance;
    state->visibility =
        std::make_unique<Visibility>(state->hierarchy.faces, &glazing_, state->hierarchy.scene_faces);
    emitted = 0;
    const Hierarchy& h = state->hierarchy;
    for (size_t f = 0; f < h.faces.size(); ++f) emitted += luminance(h.faces.emission(f)) * h.nodes[h.face_node[f]].area;
    emitted += luminance(luminaire_flux());
    emitted += distant_power(state->hierarchy.faces, *state->visibility);
    split_for_luminaires(state->hierarchy, *state->visibility, o.epsilon * emitted, o.min_area);
    return state;
}

HierarchicalResult Engine::solve_hierarchical(const HierarchyOptions& o, const SolveOptions& s,
                                              const RoundProgressFn& progress) {
    const PushPull kind = s.method == "jacobi"         ? PushPull::Jacobi
                          : s.method == "gauss_seidel" ? PushPull::GaussSeidel
                          : s.method == "southwell"    ? PushPull::Southwell
                                                       : throw std::invalid_argument(
                                                             "hierarchical solver must be jacobi, gauss_seidel or "
                                                             "southwell, not '" + s.method + "'");
    double emitted = 0;
    auto state = fresh_hierarchy(o, emitted);
    const RefineOptions ropt = refine_options(o, emitted);
    SolverOptions so;
    so.tolerance = s.tolerance;
    so.max_iterations = s.max_iterations;
    Solved* st = state.get();
    RoundsRun run = run_in_memory(state->hierarchy, *state->visibility, ropt, o.max_rounds, kind, so, progress,
                                  [this, st] { light_new_elements(st->hierarchy, *st->visibility, nullptr, nullptr); });
    // Light groups: each solved alone on the final links (the refinement saw every emitter).
    std::vector<double> group_seconds;
    std::vector<HierarchicalSolution> groups = solve_groups_on(
        state->hierarchy, *state->visibility, [&](const std::vector<RGB>& start) {
            SolverOptions go = so;
            go.on_iteration = {};
            switch (kind) {
                case PushPull::Jacobi: return solve_push_pull(st->hierarchy, run.links, start, go);
                case PushPull::GaussSeidel: return solve_gauss_seidel_push_pull(st->hierarchy, run.links, start, go);
                case PushPull::Southwell: break;
            }
            return solve_southwell_push_pull(st->hierarchy, run.links, start, go);
        }, &group_seconds);
    HierarchicalResult r = publish(std::move(state), run, ropt.epsilon, std::move(groups), group_seconds);
    if (run.log.refine_splits.size() > 1)
        r.splits_per_round.assign(run.log.refine_splits.begin() + 1, run.log.refine_splits.end());
    return r;
}

SpillLog Engine::refine_groups(const HierarchyOptions& o, const OutOfCoreOptions& c, int round, uint32_t begin,
                               uint32_t end) {
    double emitted = 0;
    const StoreFingerprints fingerprints = store_fingerprints(o, c);  // of the faces, before they go
    auto state = fresh_hierarchy(o, emitted);
    const RefineOptions ropt = refine_options(o, emitted);
    const SourceGroups groups = SourceGroups::cut(state->hierarchy, c.group_faces);
    const RunStore store(c.store, fingerprints, groups.count());
    if (!store.on_disk()) throw std::invalid_argument("refine_groups: out_of_core.store must name the link store");
    return refine_range(state->hierarchy, *state->visibility, ropt, groups, store, round, begin, end);
}

StoreFingerprints Engine::store_fingerprints(const HierarchyOptions& o, const OutOfCoreOptions& c) const {
    // The light: the luminaires, and the glass's angular transmittance where there is glass.
    uint64_t light = luminaires_.empty() ? 0 : luminaires_fingerprint(luminaires_);
    if (glazing_.any()) {
        light = hash_pair(light, 2, 23);  // glazed faces have backs (Hierarchy::glass): other nodes
    }
    if (glazing_.any())
        for (double r : glazing_.angular) {
            uint64_t b;
            std::memcpy(&b, &r, sizeof b);
            light = hash_pair(light, b, 19);
        }
    require_scene("the link store's fingerprints");
    return StoreFingerprints::of(scene_, o.epsilon, o.min_area, o.samples, o.seed, o.max_rounds, c.group_faces, light,
                                 o.relative, o.spread);
}

HierarchicalResult Engine::solve_out_of_core(const HierarchyOptions& o, const SolveOptions& s,
                                             const OutOfCoreOptions& c, const RoundProgressFn& progress,
                                             const RemoteRefineFn& remote) {
    double emitted = 0;
    const StoreFingerprints fingerprints = store_fingerprints(o, c);  // of the faces, before they go
    auto state = fresh_hierarchy(o, emitted);
    Hierarchy& h = state->hierarchy;
    const RefineOptions ropt = refine_options(o, emitted);
    StreamingOptions so;
    so.tolerance = s.tolerance;
    so.max_rounds = s.max_iterations;
    so.memory_budget = c.memory_budget;
    so.checkpoint_seconds = c.checkpoint_seconds;
    const SourceGroups groups = SourceGroups::cut(h, c.group_faces);
    RunStore store(c.store, fingerprints, groups.count());
    Solved* st = state.get();
    RoundsRun run = run_streamed(h, *state->visibility, ropt, o.max_rounds, groups, so, store, c.resume,
                                 c.reuse_links, progress,
                                 [this, st] { light_new_elements(st->hierarchy, *st->visibility, nullptr, nullptr); },
                                 remote);
    state->store_round = run.store_round;
    state->groups = run.groups;
    std::vector<HierarchicalSolution> light_groups;
    std::vector<double> group_seconds;
    if (!groups_.empty()) {
        // Each light group streamed again over the final round's links, from the store (or the
        // links in memory when the store has no root), with no checkpoints.
        std::unique_ptr<LinkChunks> chunks;
        if (!run.store_round.empty()) {
            chunks = std::make_unique<StoreChunks>(run.store_round, groups.count());
        } else {
            std::vector<std::vector<Link>> by_group(groups.count());
            for (const Link& l : run.links) by_group[groups.of(h, l.source)].push_back(l);
            for (auto& g : by_group) sort_part(g);
            chunks = std::make_unique<MemoryChunks>(std::move(by_group));
        }
        std::vector<uint8_t> is_source(h.nodes.size(), 0);
        std::vector<double> outgoing(h.nodes.size(), 0.0);
        h.measure_open(*state->visibility);
        std::vector<Link> part;
        for (size_t g = 0; g < chunks->groups(); ++g)
            for (size_t p = 0; p < chunks->parts(g); ++p) {
                chunks->read(g, p, part);
                for (const Link& l : part) {
                    is_source[l.source] = 1;
                    outgoing[l.source] += h.sent(l) / h.nodes[l.source].area;
                }
            }
        StreamingOptions gso = so;
        gso.checkpoint_path.clear();
        gso.checkpoint_seconds = 0;
        gso.on_round = {};
        light_groups = solve_groups_on(h, *state->visibility, [&](const std::vector<RGB>& start) {
            StreamingStats stats;
            return solve_streaming(h, groups, *chunks, is_source, outgoing, start, gso, stats);
        }, &group_seconds);
    }
    HierarchicalResult r = publish(std::move(state), run, ropt.epsilon, std::move(light_groups), group_seconds);
    for (size_t k = 0; k < run.log.refine_splits.size(); ++k)
        if (run.log.refine_kept[k]) r.splits_per_round.push_back(run.log.refine_splits[k]);
    r.out_of_core = true;
    r.reused_links = run.state.stop_after_solve;
    r.resumed_from_round = run.resumed_from_round;
    r.store_bytes = run.store_bytes;
    r.transport_bytes = run.transport_bytes;
    r.peak_refine_links = run.peak_refine_links;
    r.source_groups = run.groups;
    r.streaming = run.last_solve;
    r.merge_seconds = run.merge_seconds;
    return r;
}

// The glazing's terms of the energy balance (HierarchicalResult): the backs' share.
void Engine::glazing_balance(const Hierarchy& h, const HierarchicalSolution& sol, const std::vector<uint32_t>& backs,
                             HierarchicalResult& r) const {
    for (uint32_t i : backs) {
        const Node& node = h.nodes[i];
        const Patch& p = h.shape(i);
        const double open_area = node.area * h.open_share(i);  // B, H, D are the open part's
        r.glass_back_entered += mul(p.reflectance, p.direct) * open_area;
        r.glass_back_absorbed += mul(RGB{1, 1, 1} - p.reflectance, sol.irradiance[i]) * open_area;
        r.glass_back_escaped += sol.radiosity[i] * (node.area * (h.open_share(i) - sol.outgoing[i]));
    }
}

// Balances the solved hierarchy 2:1 for a display without cracks (new leaves carry their
// parent's values) and keeps it for publishing and the final gather.
HierarchicalResult Engine::publish(std::unique_ptr<Solved> state, RoundsRun& run, double epsilon_watts,
                                   std::vector<HierarchicalSolution> groups,
                                   const std::vector<double>& group_seconds) {
    const bool with_groups = !groups.empty();
    Hierarchy& h = state->hierarchy;
    HierarchicalSolution& sol = run.solution;
    state->links = std::move(run.links);
    const std::vector<Link>& links = state->links;
    HierarchicalResult r;
    r.balance_splits = h.balance();
    light_new_elements(h, *state->visibility, nullptr, nullptr);
    // The balance's new elements take their parents' values: the arrays grow once, to their
    // size (push_back alone would double them, 56 bytes a node, and hold the spare capacity).
    sol.radiosity.reserve(h.nodes.size());
    sol.irradiance.reserve(h.nodes.size());
    sol.outgoing.reserve(h.nodes.size());
    for (size_t i = sol.radiosity.size(); i < h.nodes.size(); ++i) {
        const uint32_t parent = h.nodes[i].parent;
        sol.radiosity.push_back(sol.radiosity[parent]);
        sol.irradiance.push_back(sol.irradiance[parent]);
        sol.outgoing.push_back(sol.outgoing[parent]);
    }
    for (HierarchicalSolution& g : groups) {
        g.radiosity.reserve(h.nodes.size());
        g.irradiance.reserve(h.nodes.size());
        for (size_t i = g.radiosity.size(); i < h.nodes.size(); ++i) {
            const uint32_t parent = h.nodes[i].parent;
            g.radiosity.push_back(g.radiosity[parent]);
            g.irradiance.push_back(g.irradiance[parent]);
        }
    }
    // The backs of glazed faces are solved with the rest but not published: their light shows
    // in the energy balance's glazing terms.
    std::vector<uint32_t> leaves, backs;
    for (uint32_t i : h.leaves()) (h.back(i) ? backs : leaves).push_back(i);
    if (!groups.empty()) {
        std::vector<Patch> made;  // the leaves' patches, made from the hierarchy
        for (uint32_t i : leaves) made.push_back(h.shape(i));
        std::vector<Patch*> shapes;
        for (Patch& p : made) shapes.push_back(&p);
        const size_t batch = group_batch(shapes.size());
        std::vector<RGB> lit;
        for (size_t k = 0; k < groups.size(); ++k) {
            GroupSolution gs;
            const size_t first = k - k % batch;
            if (k == first) {
                lit = groups_direct(first, std::min(groups.size(), first + batch), *state->visibility, shapes);
                to_open_parts(h, leaves, lit);
            }
            gs.direct.assign(lit.begin() + (k - first) * shapes.size(), lit.begin() + (k - first + 1) * shapes.size());
            gs.radiosity.resize(leaves.size());
            gs.irradiance.resize(leaves.size());
            for (size_t j = 0; j < leaves.size(); ++j) {
                gs.radiosity[j] = groups[k].radiosity[leaves[j]];
                gs.irradiance[j] = groups[k].irradiance[leaves[j]];
            }
            gs.iterations = groups[k].iterations;
            gs.residual = groups[k].residual;
            gs.converged = groups[k].converged;
            gs.seconds = k < group_seconds.size() ? group_seconds[k] : 0.0;
            r.groups.push_back(std::move(gs));
        }
    }
    r.radiosity.resize(leaves.size());
    r.irradiance.resize(leaves.size());
    r.escaped.resize(leaves.size());
    r.open.resize(leaves.size());
    for (size_t k = 0; k < leaves.size(); ++k) {
        const Node& node = h.nodes[leaves[k]];
        r.radiosity[k] = sol.radiosity[leaves[k]];
        r.irradiance[k] = sol.irradiance[leaves[k]];
        // Signed, as for the flat method: the per-leaf shares only add up unclamped.
        // B and H are the open part's (Hierarchy::open): it sends B x open x A.
        r.open[k] = h.open_share(leaves[k]);
        r.escaped[k] = r.radiosity[k] * (node.area * (r.open[k] - sol.outgoing[leaves[k]]));
    }
    glazing_balance(h, sol, backs, r);
    r.residual = sol.residual;
    r.converged = sol.converged;
    r.limited_leaves = sol.limited_leaves;
    r.normalised_leaves = sol.normalised_leaves;
    r.iterations = run.iterations;
    r.residual_history = run.residual_history;
    r.links = run.link_count;
    r.elements = leaves.size();
    r.nodes = h.nodes.size();
    for (const Node& node : h.nodes) r.clusters += node.cluster;
    r.face_bytes = h.faces.bytes();
    r.bvh_bytes = state->visibility->bytes();
    r.bvh_peak_bytes = state->visibility->peak_bytes();
    if (state->links.size() == run.link_count) {
        r.links_on_clusters = 0;
        for (const Link& l : state->links) r.links_on_clusters += h.nodes[l.receiver].cluster;
    }
    r.rounds = run.state.round;
    r.settled = run.state.settled;
    r.links_per_round = run.links_per_round;
    r.refine_seconds = run.log.refine_seconds;
    r.solve_seconds = run.log.solve_seconds;
    r.link_estimates = run.refine.evaluated;
    r.rays = state->rays_at_solve = state->visibility->rays_cast();
    r.epsilon_watts = epsilon_watts;
    r.link_receiver.resize(links.size());
    r.link_source.resize(links.size());
    r.link_coupling.resize(links.size());
    r.link_unoccluded.resize(links.size());
    for (size_t k = 0; k < links.size(); ++k) {
        r.link_receiver[k] = links[k].receiver;
        r.link_source[k] = links[k].source;
        r.link_coupling[k] = links[k].coupling;
        r.link_unoccluded[k] = links[k].unoccluded;
    }
    r.node_parent.resize(h.nodes.size());
    r.node_area.resize(h.nodes.size());
    r.node_cluster.resize(h.nodes.size());
    for (size_t i = 0; i < h.nodes.size(); ++i) {
        r.node_parent[i] = h.nodes[i].parent == kNoNode ? -1 : static_cast<int32_t>(h.nodes[i].parent);
        r.node_area[i] = h.nodes[i].area;
        r.node_cluster[i] = h.nodes[i].cluster;
    }
    r.leaf_node.assign(leaves.begin(), leaves.end());
    state->radiosity = std::move(sol.radiosity);
    if (with_groups)
        for (HierarchicalSolution& g : groups) state->group_radiosity.push_back(std::move(g.radiosity));
    state->leaves = std::move(leaves);
    solved_ = std::move(state);
    leaves_published_ = false;
    return r;
}

void Engine::use_leaves_as_patches(bool release_hierarchy) {
    if (!solved_) throw std::invalid_argument("use_leaves_as_patches needs a hierarchical solve first");
    if (leaves_published_) return;
    // The leaves' shapes are copied now, not at the solve's end: until then (final-gather
    // lightmaps) the hierarchy's own serve, and no second copy is held.
    if (release_hierarchy) {  // what the copy does not read goes first: the peak holds less
        solved_->gatherer.reset();
        solved_->gather_table.reset();
        std::vector<Link>().swap(solved_->links);
        std::vector<RGB>().swap(solved_->radiosity);
        std::vector<std::vector<RGB>>().swap(solved_->group_radiosity);
        std::vector<uint32_t>().swap(solved_->leaf_index);
    }
    FaceTable leaves(PatchCentroid::CornerMean, Welding::ByMesh);
    leaves.reserve(solved_->leaves.size());
    Patch scratch;
    for (uint32_t leaf : solved_->leaves) leaves.push_back(solved_->hierarchy.shape(leaf, scratch));
    leaves.seal();
    leaves_published_ = true;
    if (release_hierarchy)
        this->release_hierarchy();  // before the copy's BVH is built
    else
        std::vector<uint32_t>().swap(solved_->leaf_index);  // the published patches' BVH finds leaves now
    links_.reset();
    visibility_.reset();
    display_ = DisplayMesh{};
    patches_ = PatchSet{};
    leaves_ = std::move(leaves);
    visibility_ = std::make_unique<Visibility>(patch_view(), &glazing_);
}

LeafArrays Engine::leaf_arrays() const {
    if (!solved_) throw std::invalid_argument("leaf_arrays needs a hierarchical solve (and its hierarchy held)");
    const size_t n = solved_->leaves.size();
    LeafArrays a;
    a.mesh.resize(n);
    a.area.resize(n);
    for (size_t k = 0; k < n; ++k) {
        const Patch& s = solved_->hierarchy.shape(solved_->leaves[k]);
        a.mesh[k] = static_cast<int32_t>(s.mesh);
        a.area[k] = s.area;
    }
    return a;
}

void Engine::release_scene() {
    if (scene_released_) return;
    scene_faces_ = scene_.faces.size();
    face_origins_.resize(scene_faces_);
    emitting_faces_.clear();
    for (size_t f = 0; f < scene_faces_; ++f) {
        const Face& x = scene_.faces[f];
        face_origins_[f] = {x.mesh, x.source_face};
        const RGB none{};
        if (std::memcmp(&x.emission, &none, sizeof(RGB)) != 0)  // any bits, -0.0 kept (as FaceTable's light)
            emitting_faces_.emplace_back(static_cast<uint32_t>(f), x.emission);
    }
    std::vector<Face>().swap(scene_.faces);
    scene_released_ = true;
}

Engine::FaceRecord Engine::face_record(uint32_t f) const {
    if (!scene_released_) {
        const Face& x = scene_.faces[f];
        return {x.emission, x.transmittance, x.source_face, x.mesh};
    }
    FaceRecord r;
    r.mesh = face_origins_[f][0];
    r.source_face = face_origins_[f][1];
    r.transmittance = glazing_.face_transmittance[f];
    const auto it = std::lower_bound(emitting_faces_.begin(), emitting_faces_.end(), f,
                                     [](const std::pair<uint32_t, RGB>& e, uint32_t g) { return e.first < g; });
    if (it != emitting_faces_.end() && it->first == f) r.emission = it->second;
    return r;
}

void Engine::release_patches() {
    if (solved_) throw std::invalid_argument("release_patches: the hierarchy is held (release_hierarchy first)");
    links_.reset();
    if (visibility_) rays_let_go_ += visibility_->rays_cast();
    visibility_.reset();
    patches_ = PatchSet{};
    leaves_ = FaceTable(PatchCentroid::CornerMean, Welding::ByMesh);
    display_ = DisplayMesh{};
    patches_released_ = true;
}

void Engine::release_hierarchy() {
    if (!solved_) return;
    if (!leaves_published_) throw std::invalid_argument("release_hierarchy: call use_leaves_as_patches() first");
    rays_let_go_ += solved_->visibility->rays_cast() - solved_->rays_at_solve;
    solved_.reset();
    hierarchy_released_ = true;
}

// ---- outputs -----------------------------------------------------------------------------

const DisplayMesh& Engine::display_mesh(double crease_angle) {
    require_mesh();
    display_ = leaves_.empty() ? build_display_mesh(patches_, crease_angle) : build_display_mesh(leaves_, crease_angle);
    return display_;
}

std::vector<RGB> Engine::vertex_values(const std::vector<RGB>& values) const {
    if (display_.corners.size() != num_patches() || num_patches() == 0)
        throw std::invalid_argument("vertex_values: call display_mesh first");
    if (values.size() != num_patches()) throw std::invalid_argument("values: one row per patch");
    return leaves_.empty() ? hirad::vertex_values(patches_, display_, values)
                           : hirad::vertex_values(leaves_, display_, values);
}

std::vector<float> Engine::direct_transmittance(const std::vector<Vec3>& points, const std::vector<Vec3>& normals,
                                                const std::vector<Vec3>& directions) const {
    require_mesh();
    require_points(points, normals);
    std::vector<float> out(points.size() * directions.size());
    distant_transmittance(*visibility_, points.data(), normals.data(), points.size(), unit_directions(directions),
                          visibility_->ray_offset(), out.data());
    return out;
}

namespace {

// The luminaires' part of the gather's directional moments (gather.h): every luminaire point
// (or distant direction) is a delta of radiance, so its irradiance dE at x arrives from one
// direction d with cos = n . d > 0, and carries dE / cos of radiance times solid angle:
// l0 += dE / cos, l1 += dE / cos d. Each point's dE comes from luminaire_irradiance itself on
// a copy of the light holding that point alone (its weight kept), so shadow rays, glazing
// transmittance, tints and the intensity table are the irradiance's own; the sum of the
// copies' dE is the irradiance's luminaire term. Costs the luminaires' rays a second time.
void add_luminaire_moments(const std::vector<Luminaire>& lums, const Visibility& vis, const std::vector<Vec3>& x,
                           const std::vector<Vec3>& n, double lift, std::vector<RadianceMoments>& mo) {
    std::vector<RGB> d(x.size());
    std::vector<Luminaire> one(1);
    for (const Luminaire& l : lums)
        for (size_t p = 0; p < l.points.size(); ++p) {
            if (!(l.weights[p] > 0)) continue;
            Luminaire& c = one[0];
            c = l;
            c.points.assign(1, l.points[p]);
            c.weights.assign(1, l.weights[p]);
            c.interleave = false;  // one direction: nothing to share out
            if (!l.tints.empty()) c.tints.assign(1, l.tints[p]);
            luminaire_irradiance(one, &vis, x.data(), n.data(), x.size(), d.data(), lift);
            for (size_t k = 0; k < x.size(); ++k) {
                if (d[k].x == 0 && d[k].y == 0 && d[k].z == 0) continue;
                const Vec3 dir = l.distant ? l.points[p] : normalize(l.points[p] - x[k]);
                const double cosine = dot(n[k], dir);
                if (!(cosine > 1e-12)) continue;  // luminaire_irradiance drops cos <= 0: dE is 0 there
                const RGB radiance_sa = d[k] / cosine;
                mo[k].l0 += radiance_sa;
                for (int a = 0; a < 3; ++a) mo[k].l1[a] += radiance_sa * dir[a];
            }
        }
}

}  // namespace

PointValues Engine::gather(const std::vector<Vec3>& points, const std::vector<Vec3>& normals,
                           const GatherOptions& options, double max_distance, int group) {
    if (!solved_)
        throw std::invalid_argument(hierarchy_released_
                                        ? "gather: the solved hierarchy was let go once no output needed it "
                                          "(release_hierarchy; hirad.bake(..., keep_hierarchy=True) keeps it)"
                                        : "gather needs a hierarchical solve first");
    if (group >= 0 && size_t(group) >= solved_->group_radiosity.size())
        throw std::invalid_argument("gather: light group " + std::to_string(group) + " out of range (" +
                                    std::to_string(solved_->group_radiosity.size()) + " solved)");
    const std::vector<RGB>& radiosity = group < 0 ? solved_->radiosity : solved_->group_radiosity[group];
    const std::vector<Luminaire>& lums = group < 0 ? luminaires_ : groups_[group].luminaires;
    require_points(points, normals);
    // The first gather makes the links' table (12 bytes a link): an out-of-core solve's read
    // from its store, an in-memory solve's from its links, which it replaces.
    if (!solved_->gather_table) {
        const size_t nodes = solved_->hierarchy.nodes.size();
        if (solved_->links.empty() && !solved_->store_round.empty()) {
            solved_->gather_table =
                std::make_unique<GatherLinks>(gather_links(solved_->store_round, solved_->groups, nodes));
        } else {
            solved_->gather_table = std::make_unique<GatherLinks>(solved_->links, nodes);
            std::vector<Link>().swap(solved_->links);
        }
    }
    const size_t n = points.size();
    PointValues out;
    out.patch.assign(n, -1);
    out.irradiance.assign(n, RGB{});
    out.radiance.assign(n, RGB{});
    // Each point's leaf: the nearest published leaf, or, before the leaves are published (a
    // bake's final-gather lightmaps, baked right after the solve), the nearest face of the
    // hierarchy's own BVH and the leaf below it at the point (Hierarchy::leaf_at), so that the
    // gather needs no second copy of the surfaces and their BVH (the 1M-triangle kitchen:
    // 0.35 GB of polygons and their BVH less at the lightmaps' peak).
    const Hierarchy& h = solved_->hierarchy;
    std::lock_guard<std::mutex> turn(solved_->gather_mutex);
    if (!leaves_published_ && solved_->leaf_index.empty()) {
        solved_->leaf_index.assign(h.nodes.size(), UINT32_MAX);
        for (size_t k = 0; k < solved_->leaves.size(); ++k) solved_->leaf_index[solved_->leaves[k]] = uint32_t(k);
    }
    tbb::parallel_for(size_t(0), n, [&](size_t q) {
        if (leaves_published_) {
            out.patch[q] = visibility_->closest_point(points[q], normals[q], max_distance).patch;
            return;
        }
        const RayHit hit = solved_->visibility->closest_point(points[q], normals[q], max_distance);
        if (hit.patch < 0) return;
        const Vec2 st = h.faces[hit.patch].coordinates(points[q]);
        out.patch[q] = int32_t(solved_->leaf_index[h.leaf_at(h.face_node[hit.patch], st.u, st.v)]);
    });
    std::vector<uint32_t> leaf;
    std::vector<Vec3> x;
    std::vector<uint64_t> key;
    std::vector<size_t> slot;
    for (size_t q = 0; q < n; ++q) {
        if (out.patch[q] < 0) continue;
        leaf.push_back(solved_->leaves[out.patch[q]]);
        x.push_back(points[q]);
        key.push_back(q);
        slot.push_back(q);
    }
    if (!solved_->gatherer || !same_gather(solved_->gatherer_options, options) || solved_->gatherer_group != group) {
        solved_->gatherer.reset();
        solved_->gatherer = std::make_unique<Gatherer>(solved_->hierarchy, *solved_->gather_table, radiosity,
                                                       *solved_->visibility, options);
        solved_->gatherer_options = options;
        solved_->gatherer_group = group;
    }
    const Gatherer& g = *solved_->gatherer;
    std::vector<RGB> e(leaf.size());
    std::vector<RadianceMoments> mo(options.directional ? leaf.size() : 0);
    g.irradiance(leaf.data(), x.data(), key.data(), leaf.size(), e.data(), options.directional ? mo.data() : nullptr);
    if (!lums.empty()) {
        std::vector<Vec3> ln(leaf.size());
        for (size_t k = 0; k < leaf.size(); ++k) ln[k] = solved_->hierarchy.normal(leaf[k]);
        std::vector<RGB> d(x.size());
        const double lift = solved_->visibility->ray_offset();
        luminaire_irradiance(lums, solved_->visibility.get(), x.data(), ln.data(), x.size(), d.data(), lift);
        for (size_t k = 0; k < leaf.size(); ++k) e[k] += d[k];
        if (options.directional)
            add_luminaire_moments(lums, *solved_->visibility, x, ln, lift, mo);
    }
    if (options.directional) {
        out.l0.assign(n, RGB{});
        out.l1.assign(n, std::array<RGB, 3>{});
        for (size_t k = 0; k < leaf.size(); ++k) {
            out.l0[slot[k]] = mo[k].l0;
            out.l1[slot[k]] = mo[k].l1;
        }
    }
    for (size_t k = 0; k < leaf.size(); ++k) {
        const Patch& s = std::as_const(solved_->hierarchy).shape(leaf[k]);
        out.irradiance[slot[k]] = e[k];
        out.radiance[slot[k]] = group < 0 ? exitant(s, e[k])
                                          : (group_emission(groups_[group], s.face) + mul(s.reflectance, e[k])) / kPi;
    }
    return out;
}

LiftResult Engine::lift_samples(std::vector<Vec3> points, const std::vector<Vec3>& normals, double epsilon,
                                double reach, const std::vector<Vec3>* anchors) const {
    LiftResult r;
    if (solved_ && !leaves_published_)  // the hierarchy's faces, as the gather before publishing
        hirad::lift_samples(solved_->hierarchy.faces, *solved_->visibility, points, normals, epsilon, reach, r.moved,
                            anchors);
    else if (visibility_)
        hirad::lift_samples(patch_view(), *visibility_, points, normals, epsilon, reach, r.moved, anchors);
    else
        throw std::invalid_argument("lift_samples needs meshed patches or a solved hierarchy");
    r.points = std::move(points);
    return r;
}

RayCastResult Engine::ray_cast(const std::vector<Vec3>& origins, const std::vector<Vec3>& directions) const {
    if (!visibility_) throw std::invalid_argument("ray_cast needs meshed patches");
    return cast_rays(patch_view(), *visibility_, origins, directions);
}

PointValues Engine::gather_flat(const std::vector<Vec3>& points, const std::vector<Vec3>& normals,
                                const std::vector<RGB>& radiosity, int rays, uint64_t seed) const {
    const size_t n = points.size(), np = num_patches();
    if (!visibility_ || np == 0) throw std::invalid_argument("gather_flat needs a meshed, solved model");
    const std::vector<Patch> made = leaves_.empty() ? std::vector<Patch>{} : patch_vector();
    const std::vector<Patch>& patches = leaves_.empty() ? patches_.patches : made;
    require_points(points, normals);
    if (radiosity.size() != np) throw std::invalid_argument("radiosity: one row per patch");
    std::vector<Vec3> x(n), nn(n);
    PointValues out;
    out.patch.resize(n);
    out.irradiance.assign(n, RGB{});
    out.radiance.assign(n, RGB{});
    for (size_t q = 0; q < n; ++q) {
        const RayHit hit = visibility_->closest_point(points[q], normals[q], 1e30);
        out.patch[q] = hit.patch;
        const Patch& s = patches[std::max(0, hit.patch)];
        nn[q] = s.normal;
        x[q] = points[q] - s.normal * dot(points[q] - s.p[0], s.normal);
    }
    std::vector<RGB> e(n);
    hirad::gather_flat(patches, radiosity, *visibility_, x.data(), nn.data(), n, rays, seed, e.data());
    const std::vector<RGB> d = luminaire_light(x, nn, *visibility_);
    for (size_t q = 0; q < n; ++q) e[q] += d[q];
    for (size_t q = 0; q < n; ++q) {
        if (out.patch[q] < 0) continue;
        out.irradiance[q] = e[q];
        out.radiance[q] = exitant(patches[out.patch[q]], e[q]);
    }
    return out;
}

ReferenceResult Engine::reference(const std::vector<uint32_t>& patch, const std::vector<Vec2>& st,
                                  const ReferenceOptions& options) const {
    require_mesh();
    if (st.size() != patch.size()) throw std::invalid_argument("patch and st differ in length");
    for (uint32_t p : patch)
        if (p >= num_patches()) throw std::out_of_range("patch index out of range");
    const std::vector<Patch> made = leaves_.empty() ? std::vector<Patch>{} : patch_vector();
    std::vector<ReferenceEstimate> est = reference_radiance(leaves_.empty() ? patches_.patches : made, *visibility_, patch,
                                                            st, options, luminaires_);
    ReferenceResult r;
    r.radiance.resize(est.size());
    r.standard_error.resize(est.size());
    for (size_t q = 0; q < est.size(); ++q) {
        r.radiance[q] = est[q].radiance;
        r.standard_error[q] = est[q].standard_error;
    }
    return r;
}

ReferenceResult Engine::reference_at(const std::vector<Vec3>& points, const std::vector<Vec3>& normals,
                                     const ReferenceOptions& options, double max_distance) const {
    require_mesh();
    require_points(points, normals);
    const size_t n = points.size();
    std::vector<uint32_t> ids(n);
    std::vector<Vec2> st(n);
    for (size_t q = 0; q < n; ++q) {
        const RayHit hit = visibility_->closest_point(points[q], normals[q], max_distance);
        if (hit.patch < 0)
            throw std::invalid_argument("point " + std::to_string(q) + ": no surface within " +
                                        std::to_string(max_distance) + " m");
        ids[q] = static_cast<uint32_t>(hit.patch);
        // The closest point's (s, t) in the patch's own parametrisation (Patch::point).
        st[q] = {hit.u, hit.v};
    }
    return reference(ids, st, options);
}

}  // namespace hirad
