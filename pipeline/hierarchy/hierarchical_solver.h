// Solving on the hierarchy: gathering over links, then push-pull.
//
// One iteration gathers H_R = sum over links (R <- S) of G / A_R * B_S at every receiver node,
// pushes the gathered irradiance down to the leaves (irradiance is per unit area, so a child
// receives its parent's unchanged: power is conserved), sets B = E + rho H at the leaves and
// pulls B back up as area-weighted means. Iterating this is Jacobi's method on the
// hierarchical operator. A receiving cluster (Hierarchy::reception) gathers a vector
// irradiance instead, sum of G B_S reception(R, S); it is pushed down the clusters as a vector
// and becomes n_f . E at each face root below.
#pragma once
#include <vector>

#include "pipeline/hierarchy/hierarchy.h"
#include "pipeline/hierarchy/refine.h"
#include "pipeline/flat/solvers.h"

namespace hirad {

struct HierarchicalSolution {
    std::vector<RGB> radiosity;   // per node (leaves: B; inner nodes: area-weighted mean)
    std::vector<RGB> irradiance;  // per node: everything gathered at it and above it
    std::vector<double> outgoing; // per node: fraction of its power that its links and its
                                  // ancestors' links carry to some receiver
    uint64_t iterations = 0;
    double residual = 0;
    bool converged = false;
    std::vector<double> residual_history;
    double least_residual = 1e300;  // the smallest residual so far (divergence check)
    uint64_t limited_leaves = 0;    // leaves whose gather the gain limit scaled (gather_terms)
    uint64_t normalised_leaves = 0; // leaves whose inherited light was scaled to their closure
};

// The gain limit. A leaf's estimated form factors F (the sum of G / A_R over the links received
// at it and at its ancestors) sum to at most 1 exactly, but a sampled estimate may exceed 1; with
// a reflectance rho near 1 (hirad allows up to 0.999) the leaf then reflects more than it
// receives (rho F > 1) and Jacobi, Gauss-Seidel and Southwell diverge. Every leaf's gathered
// irradiance is kept to rho_max F <= kGainLimit (rho_max its largest channel): the iteration is
// then a contraction in the max norm (each leaf's row of rho K sums to at most kGainLimit < 1;
// pulling up averages) and converges. Leaves with rho_max F <= kGainLimit, which is every leaf of
// a material below 0.8 unless its estimates exceed the hemisphere by 25 %, are untouched.
// Leaves of a reflectance near 1 are first normalised to their closure (Hierarchy::closure):
// without that, the limit cut the spread of their sums on one side only and darkened rooms of
// white walls (the closure's comment has the figures).
// Glass (Hierarchy::glass): links see through a pane with its factor T <= tau0, so a leaf
// behind glass gathers both from the pane's side facing it (F_g) and, through it, from what
// lies beyond (at most tau0 F_g more): its estimates may sum to 1 + tau0 F_g with no error in
// them, and the limit may then scale a leaf that needs none. Counting links from glass at
// (1 - tau0) of their F was tried (stop 33): on the Modern Hall it left 695 fewer leaves under
// the limit (11,452 against 12,147 of 50,171) and moved no figure; on the country kitchen, 14,000
// fewer, and its solve converged so slowly (round 3's streamed solve past 19 minutes, against
// 96 s) that it was taken out again. Which leaves make the slow mode was not found.
// (The cut of cluster-pair estimates to min(A_R, A_S) in refine.cpp is what stopped the country
// kitchen, with panes of tau0 = 1, from diverging in its second round.)
constexpr double kGainLimit = 0.999;
// The most a leaf's gathered light is scaled by its closure (Hierarchy::closure), up or down.
constexpr double kClosureMost = 2.0;

// Per node, the form factors summed at it: the sum of G / A_R over the links received at it
// and at its ancestors, a receiving cluster's links counted at each face below it by the face's
// orientation. At a leaf this is its estimated F to everything it sees, which cannot exceed 1
// (tau0 F_g more behind glass) and is 1 in a closed room.
std::vector<double> form_factor_sums(const Hierarchy& h, const std::vector<Link>& links);
// Adds one link's coupling to those sums: G / A_R to f[R] for an element, G reception(R, S)
// to fc[slot of R] for a cluster (fc sized on first use).
void add_coupling(const Hierarchy& h, uint32_t receiver, uint32_t source, double coupling, std::vector<double>& f,
                  std::vector<Reception>& fc);

// What one link brings its receiver with the source at radiosity b: b G / A_R to an element's
// irradiance `at`, b G reception(R, S) to a receiving cluster's vector (`clusters`, per
// cluster slot, sized on first use).
void add_link(const Hierarchy& h, const Link& l, const RGB& b, std::vector<RGB>& at,
              std::vector<VectorIrradiance>& clusters);
// Whether some link ends on a cluster; the solvers that work face by face refuse such links.
bool any_cluster_receiver(const Hierarchy& h, const std::vector<Link>& links);

// Sorts links by receiver, then source (the order the gather reads them in).
void sort_links(std::vector<Link>& links);

// Push-pull: irradiance gathered at every node pushed down to the leaves (a child receives its
// parent's irradiance unchanged: it is per unit area, so power is conserved), B = E + rho H
// at the leaves, B pulled up as area-weighted means. `irradiance` receives the pushed values.
// What a leaf's B takes besides E + rho H: H = s (H_own + c H_above), H_own gathered by the
// leaf's own links, H_above what it inherits from its ancestors; c normalises the sum of its
// form factors to its closure (Hierarchy::closure), s is the gain limit.
struct LeafTerms {
    std::vector<double> scale;      // per node: s (empty: 1 everywhere)
    std::vector<double> inherited;  // per node: c (empty: 1 everywhere)
    uint64_t limited() const;       // leaves the gain limit scales
    uint64_t normalised() const;    // leaves whose inherited light is scaled
    // The irradiance of node i from what it gathered itself and what is pushed to it from
    // above (its ancestors' irradiance and, below a receiving cluster, n . E).
    RGB leaf_irradiance(uint32_t i, bool leaf, const RGB& own, const RGB& above) const {
        if (!leaf) return own + above;
        const RGB h = inherited.empty() ? own + above : own + above * inherited[i];
        return scale.empty() ? h : h * scale[i];
    }
};
// The terms of a hierarchy whose leaves do not change until the solve ends, from its links
// (or from the sums of G / A_R over the links received at each element, and per cluster slot
// the sums of G reception(R, S) over the links received at it: streamed links; empty: no
// cluster receives): the closure's normalisation, then the gain limit.
LeafTerms gather_terms(const Hierarchy& h, const std::vector<Link>& links);
LeafTerms gather_terms(const Hierarchy& h, std::vector<double> received, std::vector<Reception> cluster_received = {});

// push_pull with the leaves' terms (empty: B = E + rho H). `clusters`: the vector irradiance
// gathered at receiving clusters (per cluster slot; empty: none), pushed down the clusters and
// given to each face root below as n_f . E. The walk is depth first from the root, in
// parallel over large subtrees; the pushed vectors are summed on its stack (a per-cluster copy
// was about 1 GB on a 10M-triangle building, and the walk in index order one core's work:
// bench/README.md). `gathered` may be `irradiance` itself (each node is read before written).
void push_pull(const Hierarchy& h, const std::vector<RGB>& gathered, std::vector<RGB>& irradiance,
               std::vector<RGB>& radiosity, const LeafTerms& terms = {},
               const std::vector<VectorIrradiance>& clusters = {});
// The same from the power each node received (`received`, divided by the node's area: an
// area of 0 receives nothing), the irradiance written to `irradiance` only when asked for: the
// streaming solver pushes and pulls after every round and needs only B (24 bytes a node less
// through the solve).
void push_pull_power(const Hierarchy& h, const std::vector<RGB>& received, std::vector<RGB>& radiosity,
                     const LeafTerms& terms, const std::vector<VectorIrradiance>& clusters,
                     std::vector<RGB>* irradiance = nullptr);

// Area-weighted mean emission per node.
std::vector<RGB> node_emission(const Hierarchy& h);

// The emission norm (colour.h) the hierarchical residuals divide by: sqrt(sum A |E|^2) over
// `leaves` in their order (h.leaves()), or 1 without emission.
double leaf_emission_norm(const Hierarchy& h, const std::vector<uint32_t>& leaves);

// Jacobi iteration with push-pull from `start` (per node radiosity; emission if empty) until
// the relative residual sqrt(sum A (B' - B)^2) / sqrt(sum A E^2) over the leaves falls below
// the tolerance. Links must be sorted by sort_links.
HierarchicalSolution solve_push_pull(const Hierarchy& h, const std::vector<Link>& links,
                                     const std::vector<RGB>& start, const SolverOptions& options);

// Gauss-Seidel on the hierarchy (links to elements only): face by face, gather the links received anywhere in the
// face's element tree and push-pull that tree at once, so later faces already see the new
// radiosity. The residual is measured as for Jacobi (one more gather per sweep).
HierarchicalSolution solve_gauss_seidel_push_pull(const Hierarchy& h, const std::vector<Link>& links,
                                                  const std::vector<RGB>& start, const SolverOptions& options);

// Southwell on the hierarchy (links to elements only): shoot the face whose element tree holds the most unshot power
// through every link whose source is in that tree or is a cluster above it (the cluster's
// links carry the face's share, A_face / A_cluster), push the received irradiance down the
// receivers' trees and add it to their unshot radiosity. The residual is the unshot
// radiosity, sqrt(sum A dB^2) / sqrt(sum A E^2) over the leaves.
HierarchicalSolution solve_southwell_push_pull(const Hierarchy& h, const std::vector<Link>& links,
                                               const std::vector<RGB>& start, const SolverOptions& options);

}  // namespace hirad
