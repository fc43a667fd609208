// The engine: one scene taken through the pipeline, scene -> patches -> links -> solution,
// by either method.
//
//   flat          mesh(MeshOptions)                    patches of bounded area and edge
//                 compute_links(FormFactorOptions)     every pair that exchanges light (ray-cast
//                                                      or symmetrised hemicube form factors)
//                 solve(SolveOptions)                  B = E + rho F B (direct, Jacobi, Gauss-
//                                                      Seidel, Southwell, progressive)
//                 transport(B)                         irradiance H = F B and escaped power
//   hierarchical  solve_hierarchical(HierarchyOptions, SolveOptions[, OutOfCoreOptions])
//                                                      refine -> solve rounds (rounds.h) over
//                                                      the scene's own hierarchy; then
//                 use_leaves_as_patches()              the leaf elements become the patches
//
// After either, the patches and their values feed the outputs: display_mesh / vertex_values
// (Gouraud reconstruction), gather / gather_flat (final gather at points) and reference (the
// Monte Carlo path tracer, independent of links and solution).
//
// Luminaires (set_luminaires, luminaire.h: point, spot, IES, sphere and cylinder lights) are
// not surfaces: their light reaches the surfaces as a first, exact bounce, the direct
// irradiance `direct` of every patch or element (the mean of g x g points over it, with
// visibility), and a surface re-emits rho x direct as a source term like self-emission. So
// the flat, hierarchical and out-of-core solvers solve B = E + rho direct + rho F B unchanged.
// Before a hierarchy is linked, its elements are split where the luminaires' light varies
// across them by more than epsilon x the emitted power (over their area, W), down to
// min_area; elements made later by refinement are lit before each solve. The final gather
// and the reference evaluate the luminaires exactly at their points.
//
// Light groups (set_light_groups): radiosity is linear in its source term, so the solution of
// the whole scene is the sum of the solutions of each group's emitters alone (emitting faces of
// some input meshes, some luminaires). With groups set, the links are computed once (flat
// compute_links; the hierarchical refinement, driven by all the emitters together) and every
// group is then solved again on those final links with only its own source term (solve_groups
// for the flat method; the hierarchical and out-of-core solves do it before the leaves are
// balanced, into HierarchicalResult::groups). The same inputs give the same bits whatever the
// thread count; without groups nothing changes.
//
// Units: metres, m^2; radiosity B, irradiance H and emission E (exitance) in W/m^2 per RGB
// channel; radiance L = B / pi in W/(m^2 sr); power in W. Colours are linear RGB.
//
// Long calls take progress callbacks. They are called from the thread doing the work (link
// rows: from TBB worker threads), so they must be cheap, thread-safe and must not throw; the
// Python bindings run each long call on a worker thread and poll what the callbacks stored.
#pragma once
#include <array>
#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "pipeline/engine/rounds.h"
#include "pipeline/flat/links.h"
#include "pipeline/flat/solvers.h"
#include "pipeline/geometry/luminaire.h"
#include "pipeline/geometry/patches.h"
#include "pipeline/geometry/scene.h"
#include "pipeline/geometry/visibility.h"
#include "pipeline/hierarchy/gather.h"
#include "pipeline/hierarchy/hierarchy.h"
#include "pipeline/outputs/reconstruct.h"
#include "pipeline/reference/reference.h"

namespace hirad {

struct LiftResult;     // pipeline/engine/ray_scene.h
struct RayCastResult;  // pipeline/engine/ray_scene.h

// Caps the engine's TBB threads (0: all cores). Results do not depend on it.
void set_threads(int threads);

// ---- options ----------------------------------------------------------------------------

// Flat meshing: every face is cut into patches no larger than these.
struct MeshOptions {
    double max_patch_area = 0.01;   // m^2
    double max_edge_length = 0.1;   // m
    uint64_t max_patches = 50000000;  // more is refused before anything is built (MeshingOptions)
};

// Form factors of the flat method.
struct FormFactorOptions {
    // "raycast": stratified area-to-area sampling with Embree visibility (reciprocal by
    // construction); "hemicube": rasterised hemicubes, rows made reciprocal by averaging
    // G_ij = (A_i F_ij + A_j F_ji) / 2.
    std::string method = "raycast";
    int samples = 16;               // raycast: stratified points per patch (also the progressive solver's)
    int hemicube_resolution = 128;  // hemicube: pixels along the top face (even)
    int hemicube_points = 4;        // hemicube: hemicubes averaged per patch
    uint64_t seed = 1;              // equal seeds give equal bits, whatever the thread count
};

// The solve: of B = E + rho F B (flat) or of the hierarchy's links (hierarchical).
struct SolveOptions {
    // flat: "direct", "jacobi", "gauss_seidel", "southwell", "progressive";
    // hierarchical in memory: "jacobi", "gauss_seidel", "southwell" (with push-pull);
    // hierarchical out of core: ignored (streaming block Southwell).
    std::string method = "southwell";
    double tolerance = 1e-4;        // relative residual ||E - M B|| / ||E|| to stop at
    uint64_t max_iterations = 100000000;  // sweeps, or shots for shooting methods
    uint64_t snapshot_every = 0;    // progressive only: a snapshot every this many shots (0: none)
};

// Hierarchical radiosity with clustering (refine.h).
struct HierarchyOptions {
    double epsilon = 1e-5;          // a link may carry at most epsilon x the emitted power (W) unsplit
    double min_area = 1e-3;         // m^2: elements are not split below this
    int samples = 16;               // point pairs per link estimate
    uint64_t seed = 1;
    int max_rounds = 6;             // refine -> solve rounds at most (>= 1)
    double relative = 0;            // after round 1, also split links above this fraction of
                                    // their receiver's light (refine.h; 0: off)
    double spread = 1e-3;           // close or partly visible links of uneven sources are split
                                    // at the source above spread x epsilon (refine.h; 0: off)
    bool cluster_receivers = false; // clusters whose faces all face a source receive as a whole
                                    // (refine.h, Hierarchy::reception)
    double closure_reflectance = Hierarchy::kClosureReflectance;  // leaves of at least this
                                    // reflectance have their form factors normalised to their
                                    // closure (Hierarchy::closure)
    bool release_scene = false;     // the input faces let go (Engine::release_scene) once the
                                    // hierarchy holds its copy and the store's fingerprints are
                                    // taken: a bake that will not mesh or solve again (the
                                    // 1M-triangle kitchen: 0.2 GB less at the solve's peak)
};

// The hierarchical method out of core: links streamed through a link store.
struct OutOfCoreOptions {
    std::string store;              // the link store's directory; empty: links in memory
    uint64_t memory_budget = 0;     // bytes for solver state and decoded chunks; 0: unlimited
    uint32_t group_faces = 1024;    // input faces per source group (one chunk each)
    double checkpoint_seconds = 0;  // the running solve's state this often (0: never)
    bool resume = false;            // continue what a killed bake with the same inputs left
    bool reuse_links = false;       // solve on the store's final links (same geometry and
                                    // settings, other materials): no link estimates
};

// ---- results ------------------------------------------------------------------------------

// Counts of the scene and of what has been built from it so far.
struct Stats {
    uint64_t input_faces = 0;         // polygons given
    uint64_t faces = 0;               // usable faces after triangulation and cleaning
    uint64_t degenerate_faces = 0;    // dropped: zero area
    uint64_t nonfinite_faces = 0;     // dropped: a NaN or infinite corner
    uint64_t self_intersecting_faces = 0;  // dropped: polygons whose edges cross in their plane
    uint64_t triangulated_faces = 0;  // non-quads and non-planar or concave quads split
    uint64_t nonmanifold_edges = 0;   // edges of more than two faces (kept, only counted)
    uint64_t patches = 0;             // current patches (flat patches, or published leaves)
    uint64_t links = 0;               // flat links stored (0 before compute_links)
    uint64_t link_bytes = 0;          // their memory
    uint64_t rays = 0;                // rays cast against the current patches
};

// What the atlas needs of a hierarchical solve's leaves, published or not (row k is leaf k).
struct LeafArrays {
    std::vector<int32_t> mesh;  // input mesh index
    std::vector<double> area;   // m^2
};

// The current patches as flat arrays (row k is patch k).
struct PatchArrays {
    size_t count = 0;
    std::vector<double> corners;      // (n, 4, 3) m; triangles repeat corner 2 as corner 3
    std::vector<double> uv;           // (n, 4, 2) the face's texture coordinates at the corners
    std::vector<double> area;         // (n) m^2
    std::vector<double> normal;       // (n, 3) unit
    std::vector<double> centroid;     // (n, 3) m
    std::vector<double> reflectance;  // (n, 3)
    std::vector<double> emission;     // (n, 3) self-emitted exitance, W/m^2
    std::vector<double> direct;       // (n, 3) the luminaires' irradiance (mean over the patch), W/m^2
    std::vector<int32_t> nv;          // (n) 3 or 4
    std::vector<int32_t> mesh;        // (n) input mesh
    std::vector<int32_t> face;        // (n) engine face (after triangulation)
    std::vector<int32_t> source_face; // (n) the authored face within its mesh
    std::vector<double> transmittance; // (n) glazing's normal transmittance (0: opaque)
};

// A flat solve.
struct FlatSolveResult {
    std::vector<RGB> radiosity;       // per patch, W/m^2
    uint64_t iterations = 0;
    double residual = 0;              // final relative residual
    bool converged = false;
    std::vector<double> residual_history;
    uint64_t rows_computed = 0;       // progressive: coupling rows computed on the fly
};

// The two terms of the flat energy balance, per patch.
struct Transport {
    std::vector<RGB> irradiance;      // H = F B, W/m^2
    std::vector<RGB> escaped;         // (A_i - sum_j G_ij) B_i, W: leaves and reaches no patch
                                      // (signed: sampling makes some rows sum above 1)
};

// A light group: the emission of the faces of some input meshes, and some luminaires.
struct LightGroup {
    std::vector<uint32_t> meshes;        // input meshes whose faces' emission is the group's
    std::vector<Luminaire> luminaires;   // the group's luminaires (validated)
};

// One group's solution on the shared links, per patch (flat) or per leaf (hierarchical).
struct GroupSolution {
    std::vector<RGB> radiosity;       // B_g, W/m^2 (the group's own emission included)
    std::vector<RGB> irradiance;      // from the surfaces, W/m^2 (flat: F B_g; hierarchical: gathered)
    std::vector<RGB> direct;          // the group's luminaires' irradiance, W/m^2
    uint64_t iterations = 0;
    double residual = 0;
    bool converged = false;
    double seconds = 0;               // wall time of its solve (and its direct light)
};

// A hierarchical solve. Per-leaf arrays follow the leaves of the 2:1 balanced hierarchy, the
// patches that use_leaves_as_patches() makes.
struct HierarchicalResult {
    std::vector<RGB> radiosity;       // per leaf, W/m^2
    std::vector<RGB> irradiance;      // per leaf, W/m^2
    std::vector<RGB> escaped;         // per leaf, W: B A (open - outgoing fraction), signed
    std::vector<double> open;         // per leaf: its open share (Hierarchy::open); B, H, direct are that part's
    double residual = 0;
    bool converged = false;
    uint64_t iterations = 0;          // all rounds
    std::vector<double> residual_history;  // in memory: all rounds; out of core: the last solve's
    uint64_t links = 0;               // final links
    uint64_t elements = 0;            // leaves
    uint64_t nodes = 0;
    uint64_t clusters = 0;
    int64_t links_on_clusters = -1;   // final links that end on a cluster (-1: out of core, not counted)
    uint64_t balance_splits = 0;      // leaves split for the 2:1 balance of the display
    // Glazing (Hierarchy::glass), W (lm): of the unpublished backs of glazed faces the direct light
    // they reflect (rho D A), what they take of the interreflected light ((1 - rho) H A: absorbed
    // or let through, report.energy_balance) and their light that reaches no surface.
    RGB glass_back_entered, glass_back_absorbed, glass_back_escaped;
    uint64_t limited_leaves = 0;      // leaves whose gather the last solve kept to the gain limit
                                      // (hierarchical_solver.h kGainLimit)
    uint64_t normalised_leaves = 0;   // leaves whose inherited light the last solve scaled to their
                                      // closure (Hierarchy::closure)
    int rounds = 0;                   // the final round
    bool settled = false;             // refinement stopped splitting (else max_rounds ended it)
    uint64_t face_bytes = 0;          // the hierarchy's input faces (FaceTable::bytes)
    uint64_t bvh_bytes = 0;           // Embree's scene over them after the build (Visibility::bytes)
    uint64_t bvh_peak_bytes = 0;      // and the most Embree held during the build
    std::vector<uint64_t> links_per_round;
    // Links split per refinement pass. In memory: each pass after the first, the last 0 when
    // it settled; out of core: each pass that made a round, the first included. (Two
    // conventions kept from before the loop was shared, so reports compare with old ones.)
    std::vector<uint64_t> splits_per_round;
    std::vector<double> refine_seconds, solve_seconds;
    uint64_t link_estimates = 0;      // form factor estimates made by refinement
    uint64_t rays = 0;                // rays cast over the hierarchy's faces
    double epsilon_watts = 0;         // epsilon x emitted power: the split threshold, W
    // out of core only
    bool out_of_core = false;
    bool reused_links = false;
    int resumed_from_round = 0;       // 0: started fresh
    uint64_t store_bytes = 0;         // compressed link payload of the final round
    uint64_t transport_bytes = 0;     // of which the transport sections
    uint64_t peak_refine_links = 0;   // most links refinement held at once
    uint64_t source_groups = 0;
    StreamingStats streaming;         // the last streaming solve
    std::vector<double> merge_seconds;  // distributed: per remote refinement, the driver's merge (s)
    // The hierarchy and its links as plain arrays (tests, inspection).
    std::vector<int32_t> link_receiver, link_source;
    std::vector<double> link_coupling, link_unoccluded;  // G, m^2
    std::vector<int32_t> node_parent;  // -1 at the root
    std::vector<double> node_area;
    std::vector<uint8_t> node_cluster;
    std::vector<int32_t> leaf_node;    // per leaf
    // One solution per light group (set_light_groups) on the final links, per leaf; empty
    // without groups.
    std::vector<GroupSolution> groups;
};

// Values at query points on the surfaces.
struct PointValues {
    std::vector<int32_t> patch;       // the patch each point went to (-1: none within reach)
    std::vector<RGB> irradiance;      // W/m^2 (0 where patch is -1)
    std::vector<RGB> radiance;        // exitant, W/(m^2 sr)
    // With GatherOptions::directional (gather only; empty otherwise): the moments of the
    // radiance arriving over each point's hemisphere (gather.h), surfaces and luminaires:
    // l0 = integral L dw and l1[a] = integral L w_a dw (world axis a), W/m^2 per channel;
    // n . l1 = irradiance (but see gather.h on sources straddling the horizon). Zero where
    // patch is -1.
    std::vector<RGB> l0;
    std::vector<std::array<RGB, 3>> l1;
};

struct ReferenceResult {
    std::vector<RGB> radiance;        // exitant, W/(m^2 sr)
    std::vector<RGB> standard_error;  // of `radiance`
};

using DoneFn = std::function<void(uint64_t done)>;
using FlatProgressFn = std::function<void(uint64_t iteration, double residual)>;
using SnapshotFn = std::function<void(uint64_t shot, const std::vector<RGB>& display)>;

class Engine {
public:
    // The scene as flat arrays (validated: counts, indices, per-face rows). Faces that are
    // degenerate or not finite are dropped and counted (stats()).
    Engine(const SceneInput& scene, size_t num_indices);
    ~Engine();

    Stats stats() const;

    // Luminaires replace any earlier ones; the current flat patches (if any) are lit at once,
    // a hierarchical solve uses them from its start. Each is validated (std::invalid_argument).
    void set_luminaires(std::vector<Luminaire> luminaires);
    const std::vector<Luminaire>& luminaires() const { return luminaires_; }
    RGB luminaire_flux() const;  // their total flux (lm or W); distant lights count 0

    // Glazing (visibility.h): the faces' transmittance comes with the scene
    // (SceneInput::face_transmittance); this sets glass's relative angular transmittance
    // r(cos theta) at evenly spaced cosines 0 .. 1 (empty: 1 at every angle). Call it before
    // meshing or solving.
    void set_glass_angular(std::vector<double> relative);
    const Glazing& glazing() const { return glazing_; }

    // Light groups replace any earlier ones (empty: none). Meshes must be input mesh indices;
    // luminaires are validated (std::invalid_argument). They do not change the total solve.
    void set_light_groups(std::vector<LightGroup> groups);
    size_t num_light_groups() const { return groups_.size(); }

    // ---- flat method
    void mesh(const MeshOptions& options);
    size_t num_patches() const { return leaves_.empty() ? patches_.patches.size() : leaves_.size(); }
    PatchArrays patch_arrays() const;
    // `done(rows)`: rows finished so far (called from TBB worker threads, not in order).
    void compute_links(const FormFactorOptions& options, const DoneFn& done = {});
    // Progressive solves need no links (rows are computed as they are shot, with `ff`'s
    // samples and seed); the others need compute_links first. `snapshot` (progressive,
    // snapshot_every > 0) receives B + rho x ambient, the displayed radiosity.
    FlatSolveResult solve(const SolveOptions& options, const FormFactorOptions& ff = {},
                          const SnapshotFn& snapshot = {}, const FlatProgressFn& progress = {});
    // H and escaped power from B; couplings from the links, or sampled with `ff` without links.
    Transport transport(const std::vector<RGB>& radiosity, const FormFactorOptions& ff = {}) const;
    // Each light group solved alone on the flat links (the same solver and tolerance; progressive:
    // rows sampled with `ff` again), with its irradiance F B_g (transport) and its direct light.
    std::vector<GroupSolution> solve_groups(const SolveOptions& options, const FormFactorOptions& ff = {});
    double residual_of(const std::vector<RGB>& radiosity) const;
    double form_factor(uint32_t i, uint32_t j, int samples, uint64_t seed) const;
    std::vector<double> hemicube_row(uint32_t i, int resolution, int points) const;  // dense F_i.
    uint64_t rays_cast() const;

    // ---- hierarchical method (replaces any earlier hierarchical solve and drops flat links)
    HierarchicalResult solve_hierarchical(const HierarchyOptions& hierarchy, const SolveOptions& solve,
                                          const RoundProgressFn& progress = {});
    // With `remote`, link generation is distributed (rounds.h: every refinement's source groups
    // refined by workers, merged here in group order; the same bits as without).
    HierarchicalResult solve_out_of_core(const HierarchyOptions& hierarchy, const SolveOptions& solve,
                                         const OutOfCoreOptions& out_of_core, const RoundProgressFn& progress = {},
                                         const RemoteRefineFn& remote = {});
    // A worker's share of a distributed out-of-core bake (rounds.h, refine_range): round
    // `round`'s refinement of source groups [begin, end) from what the link store
    // out_of_core.store holds, into its spill directory. Options and scene must be the driver's
    // (checked through the store's fingerprints when the driver merges).
    SpillLog refine_groups(const HierarchyOptions& hierarchy, const OutOfCoreOptions& out_of_core, int round,
                           uint32_t begin, uint32_t end);
    // Makes the last hierarchical solve's leaves the patches (in the order of the result's
    // per-leaf arrays), so that patch_arrays, display_mesh, vertex_values, gather and
    // reference work on them. Until then the patches are the flat meshing's (if any).
    // With release_hierarchy the hierarchy is let go (release_hierarchy) as soon as the leaves
    // are copied out of it, before their BVH is built: the peak holds one of the two.
    void use_leaves_as_patches(bool release_hierarchy = false);
    bool leaves_are_patches() const { return leaves_published_; }
    // The last hierarchical solve's leaves' meshes and areas (m^2), in the per-leaf order,
    // published or not: what the atlas needs of them before they are published.
    LeafArrays leaf_arrays() const;
    // Lets go of the solved hierarchy once no output will gather from it: its nodes, face
    // polygons and their BVH, its links (when held in memory) and per-node radiosity. The
    // patches (the published leaves), the display mesh and everything read from them stay.
    // On the 1M-triangle kitchen this is about 0.7 GB. gather then refuses, saying why.
    void release_hierarchy();
    bool has_hierarchy() const { return solved_ != nullptr; }
    // Lets go of the input faces once nothing will mesh or solve again (those then refuse):
    // about 200 bytes a face. What patch_arrays reads of them is kept; stats keep their counts.
    void release_scene();
    // Lets go of the patches, their BVH and the display mesh once every output read from them
    // is made (a hierarchical bake's reconstruction and vertex gather; the written layer and
    // the Result keep their own arrays): the 1M-triangle kitchen's published leaves, about
    // 0.45 GB. Needs the hierarchy let go first; what reads the patches then refuses.
    void release_patches();

    // ---- outputs
    const DisplayMesh& display_mesh(double crease_angle_degrees);   // kept for vertex_values
    std::vector<RGB> vertex_values(const std::vector<RGB>& patch_values) const;
    // Final gather after a hierarchical solve: each point goes to the nearest leaf facing along
    // its normal within max_distance, every link reaching that leaf is re-evaluated at the
    // point. Before use_leaves_as_patches the leaf is found through the hierarchy's own faces
    // and BVH (no published copy needed); `patch` is the leaf's place in the per-leaf arrays
    // either way.
    // `group` >= 0: the gather of that light group's solution alone (its radiosity on the same
    // links, its luminaires, its emission).
    PointValues gather(const std::vector<Vec3>& points, const std::vector<Vec3>& normals,
                       const GatherOptions& options, double max_distance = 1e30, int group = -1);
    // Lightmap sample points lifted off their surface and out of geometry (volume.h's
    // lift_samples) against the surfaces the gather finds its leaves on (the published patches,
    // or before publishing the hierarchy's faces) and their BVH: a final gather's lightmaps
    // then build no second ray-tracing scene (SurfaceField) for it.
    LiftResult lift_samples(std::vector<Vec3> points, const std::vector<Vec3>& normals, double epsilon,
                            double reach, const std::vector<Vec3>* anchors) const;
    // First hits of rays against the current patches and their BVH (as SurfaceField.ray_cast):
    // the vertex gather's enclosure test, without a SurfaceField of its own.
    RayCastResult ray_cast(const std::vector<Vec3>& origins, const std::vector<Vec3>& directions) const;
    // Direct light from far directions at points (daylight: annual sun hours, sky patches):
    // out[p * D + d] = max(0, n_p . d_d) T(x_p, d_d), T the transmittance of the ray from x_p
    // (lifted off its surface) towards unit direction d_d out of the scene (visibility.h: 0
    // blocked, glass factors through windows), over the current patches. Deterministic.
    std::vector<float> direct_transmittance(const std::vector<Vec3>& points, const std::vector<Vec3>& normals,
                                            const std::vector<Vec3>& directions) const;
    // Final gather from a flat solution `radiosity` (per patch): O(patches) a point.
    PointValues gather_flat(const std::vector<Vec3>& points, const std::vector<Vec3>& normals,
                            const std::vector<RGB>& radiosity, int rays, uint64_t seed) const;
    // Monte Carlo reference at (s, t) of the given patches.
    ReferenceResult reference(const std::vector<uint32_t>& patch, const std::vector<Vec2>& st,
                              const ReferenceOptions& options) const;
    // The same at arbitrary points, each on the closest patch facing along its normal (any when
    // the normal is zero) within max_distance (an error naming the point otherwise).
    ReferenceResult reference_at(const std::vector<Vec3>& points, const std::vector<Vec3>& normals,
                                 const ReferenceOptions& options, double max_distance) const;

private:
    struct Solved;
    void require_mesh() const;
    void require_index(uint32_t i) const;
    RadiositySystem system() const;
    void replace_patches(PatchSet patches);
    std::unique_ptr<Solved> fresh_hierarchy(const HierarchyOptions& options, double& emitted);
    StoreFingerprints store_fingerprints(const HierarchyOptions& options, const OutOfCoreOptions& out_of_core) const;
    HierarchicalResult publish(std::unique_ptr<Solved> state, RoundsRun& run, double epsilon_watts,
                               std::vector<HierarchicalSolution> groups = {},
                               const std::vector<double>& group_seconds = {});
    // Each group's source term on the hierarchy's elements, solved by `solve` (per node
    // solutions); the total source term is restored afterwards.
    std::vector<HierarchicalSolution> solve_groups_on(
        Hierarchy& h, const Visibility& visibility,
        const std::function<HierarchicalSolution(const std::vector<RGB>& start)>& solve,
        std::vector<double>* seconds = nullptr) const;
    // A group's emission of face f.
    RGB group_emission(const LightGroup& g, uint32_t face) const;
    void glazing_balance(const Hierarchy& h, const HierarchicalSolution& sol, const std::vector<uint32_t>& backs,
                         HierarchicalResult& r) const;
    // The direct light of groups [begin, end) over `shapes`, lit together
    // (element_group_irradiance): row (q - begin) * shapes.size() + k.
    std::vector<RGB> groups_direct(size_t begin, size_t end, const Visibility& vis,
                                   const std::vector<Patch*>& shapes) const;
    size_t group_batch(size_t elements) const;  // how many groups are lit together
    // The source term of patches lit by the luminaires: direct and emission = E_self + rho direct.
    void light_patches(std::vector<Patch*>& patches, const Visibility& visibility, std::vector<double>* spread) const;
    void light_new_elements(Hierarchy& h, const Visibility& visibility, std::vector<uint32_t>* fresh,
                            std::vector<double>* spread) const;
    void split_for_luminaires(Hierarchy& h, const Visibility& visibility, double epsilon_watts, double min_area) const;
    // What the distant lights deliver to `faces` (luminance Y x area), W or lm.
    double distant_power(const FaceTable& faces, const Visibility& vis) const;
    // Luminaire irradiance at points x with unit normals n (zero without luminaires).
    std::vector<RGB> luminaire_light(const std::vector<Vec3>& x, const std::vector<Vec3>& n, const Visibility& vis) const;

    Scene scene_;
    std::vector<Luminaire> luminaires_;
    Glazing glazing_;
    std::vector<LightGroup> groups_;
    std::vector<std::vector<uint8_t>> group_mesh_;  // per group: per input mesh, 1 when in it
    PatchSet patches_;
    // After use_leaves_as_patches: the leaves, compact (about 190 of a Patch's 328 bytes, with
    // texture coordinates), welded as weld_patches welds; patches_ is empty then.
    FaceTable leaves_{PatchCentroid::CornerMean, Welding::ByMesh};
    PatchView patch_view() const { return leaves_.empty() ? PatchView(patches_.patches) : PatchView(leaves_); }
    // The patches as a vector: patches_'s own, or the leaves made again (a copy, for the calls
    // written over vectors: the flat final gather and the reference).
    std::vector<Patch> patch_vector() const;
    // Throws for the flat method's calls once the patches are a hierarchy's leaves.
    void require_flat(const char* what) const;
    std::unique_ptr<Visibility> visibility_;   // over patch_view()
    std::unique_ptr<LinkMatrix> links_;
    std::unique_ptr<Solved> solved_;
    bool leaves_published_ = false;
    DisplayMesh display_;
    bool hierarchy_released_ = false;
    bool scene_released_ = false;
    bool patches_released_ = false;
    uint64_t rays_let_go_ = 0;  // rays counted by BVHs since let go (release_patches, release_hierarchy)
    size_t scene_faces_ = 0;  // their count, kept when they are let go
    // What the solves and patch_arrays read of an input face, kept when the faces are let go
    // (light groups' emission, glazing, and the arrays of leaves published after
    // release_scene): its mesh and authored face (8 bytes a face), the emission of the faces
    // that have some, by face, and the transmittance from glazing_ (which holds it a face).
    // 8 bytes a face where a record of 48 was, through the whole bake (480 MB at 10 M faces).
    struct FaceRecord {
        RGB emission;
        double transmittance = 0;
        uint32_t source_face = 0;
        uint32_t mesh = 0;
    };
    std::vector<std::array<uint32_t, 2>> face_origins_;       // per face: mesh, authored face
    std::vector<std::pair<uint32_t, RGB>> emitting_faces_;    // ascending by face
    // What the solves and the patch arrays read of input face f, held or let go.
    FaceRecord face_record(uint32_t f) const;
    void require_scene(const char* what) const;
};

}  // namespace hirad
