#include "pipeline/hierarchy/hierarchical_solver.h"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <queue>
#include <stdexcept>

#include "pipeline/core/checks.h"

namespace hirad {

void sort_links(std::vector<Link>& links) {
    std::sort(links.begin(), links.end(), [](const Link& a, const Link& b) {
        return a.receiver < b.receiver || (a.receiver == b.receiver && a.source < b.source);
    });
}

double leaf_emission_norm(const Hierarchy& h, const std::vector<uint32_t>& leaves) {
    return emission_norm(
        leaves.size(), [&](size_t k) { return h.nodes[leaves[k]].area; },
        [&](size_t k) { return h.emission(leaves[k]); });
}

std::vector<RGB> node_emission(const Hierarchy& h) {
    std::vector<RGB> e(h.nodes.size());
    // Children have larger indices than their parents: a reverse sweep pulls.
    for (size_t i = h.nodes.size(); i-- > 0;) {
        const Node& n = h.nodes[i];
        if (n.leaf()) {
            e[i] = n.cluster ? RGB{} : h.emission(uint32_t(i));
            continue;
        }
        RGB acc;
        for (uint32_t c = 0; c < n.child_count; ++c) acc += e[n.first_child + c] * h.nodes[n.first_child + c].area;
        e[i] = acc / n.area;
    }
    return e;
}

namespace {

// Groups of links with the same receiver, for a deterministic parallel gather.
std::vector<size_t> receiver_groups(const std::vector<Link>& links) {
    std::vector<size_t> starts;
    for (size_t k = 0; k < links.size(); ++k)
        if (k == 0 || links[k].receiver != links[k - 1].receiver) starts.push_back(k);
    starts.push_back(links.size());
    return starts;
}

}  // namespace

// Parents come before children in index order, so one forward sweep pushes and one backward
// sweep pulls.
void add_link(const Hierarchy& h, const Link& l, const RGB& b, std::vector<RGB>& at,
              std::vector<VectorIrradiance>& clusters) {
    const uint32_t slot = h.slot_of(l.receiver);
    if (slot == kNoNode) {
        at[l.receiver] += b * (double(l.coupling) / h.nodes[l.receiver].area);
        return;
    }
    if (clusters.empty()) clusters.resize(h.cluster_shapes.size());
    clusters[slot].add(b * double(l.coupling), h.reception(l.receiver, l.source));
}

bool any_cluster_receiver(const Hierarchy& h, const std::vector<Link>& links) {
    for (const Link& l : links)
        if (h.slot_of(l.receiver) != kNoNode) return true;
    return false;
}

void add_coupling(const Hierarchy& h, uint32_t receiver, uint32_t source, double coupling, std::vector<double>& f,
                  std::vector<Reception>& fc) {
    const uint32_t slot = h.slot_of(receiver);
    if (slot == kNoNode) {
        f[receiver] += coupling / h.nodes[receiver].area;
        return;
    }
    if (fc.empty()) fc.resize(h.cluster_shapes.size());
    fc[slot] += h.reception(receiver, source) * coupling;
}

LeafTerms gather_terms(const Hierarchy& h, const std::vector<Link>& links) {
    std::vector<double> f(h.nodes.size(), 0.0);
    std::vector<Reception> fc;
    for (const Link& l : links) add_coupling(h, l.receiver, l.source, double(l.coupling), f, fc);
    return gather_terms(h, std::move(f), std::move(fc));
}

namespace {
// Pushes the sums of G / A_R (and the clusters' receptions) down to node i, its parent's
// already pushed: returns what i inherits from above (f[i] keeps what is received at i).
double inherited_sum(const Hierarchy& h, const std::vector<double>& f, std::vector<Reception>& fc, size_t i) {
    const Node& node = h.nodes[i];
    double above = node.parent == kNoNode ? 0.0 : f[node.parent];
    if (!fc.empty() && node.parent != kNoNode && h.nodes[node.parent].cluster) {
        const Reception& r = fc[h.cluster_slot[node.parent]];
        if (node.cluster) fc[h.cluster_slot[i]] += r;
        else above += std::max(0.0, r.along(h.normal(uint32_t(i))));
    }
    return above;
}
}  // namespace

std::vector<double> form_factor_sums(const Hierarchy& h, const std::vector<Link>& links) {
    std::vector<double> f(h.nodes.size(), 0.0);
    std::vector<Reception> fc;
    for (const Link& l : links) add_coupling(h, l.receiver, l.source, double(l.coupling), f, fc);
    for (size_t i = 0; i < h.nodes.size(); ++i) f[i] += inherited_sum(h, f, fc, i);  // parents come first
    return f;
}

LeafTerms gather_terms(const Hierarchy& h, std::vector<double> f, std::vector<Reception> fc) {
    const size_t n = h.nodes.size();
    if (f.size() != n) throw std::invalid_argument("gather_terms: one sum per node");
    if (!fc.empty() && fc.size() != h.cluster_shapes.size())
        throw std::invalid_argument("gather_terms: one vector per cluster");
    LeafTerms t;
    for (size_t i = 0; i < n; ++i) {
        const Node& node = h.nodes[i];
        const double own = f[i], above = inherited_sum(h, f, fc, i);
        f[i] = own + above;
        if (!node.leaf() || node.cluster) continue;
        const RGB& rho = h.reflectance(uint32_t(i));
        const double rho_max = std::max({rho.x, rho.y, rho.z});
        // What the leaf inherits is scaled so that its sum comes to the leaf's closure where
        // that was measured (Hierarchy::closure), by at most kClosureMost either way: its own
        // links hold their light, and the ancestors' means it takes in their stead are what
        // differ from its own values. Then the gain limit scales the whole.
        double inherit = 1, whole = 1;
        const double closure = h.closure_of(uint32_t(i));
        if (closure >= 0 && above > 0) inherit = std::clamp((closure - own) / above, 1 / kClosureMost, kClosureMost);
        const double sum = own + inherit * above;
        if (rho_max * sum > kGainLimit) whole = kGainLimit / (rho_max * sum);
        if (inherit != 1) {
            if (t.inherited.empty()) t.inherited.assign(n, 1.0);
            t.inherited[i] = inherit;
        }
        if (whole != 1) {
            if (t.scale.empty()) t.scale.assign(n, 1.0);
            t.scale[i] = whole;
        }
    }
    return t;
}

uint64_t LeafTerms::limited() const {
    uint64_t count = 0;
    for (double s : scale) count += s < 1.0;
    return count;
}

uint64_t LeafTerms::normalised() const {
    uint64_t count = 0;
    for (double c : inherited) count += c != 1.0;
    return count;
}

namespace {

// One push-pull over the subtree of a node, depth first: the node's irradiance from its
// parent's (already final), its children, then its radiosity from theirs. A receiving
// cluster's pushed vector (its own plus its ancestors') lives on the stack of the walk, not in
// a per-cluster array, and subtrees of more than kSerialFaces faces are walked in parallel.
// Every node's value is the same sum, in the same order, as a walk in index order would
// make, so the bits do not depend on the threads.
struct PushPullWalk {
    const Hierarchy& h;
    const std::vector<RGB>& gathered;
    bool power;                     // `gathered` is power, divided by each node's area here
    std::vector<RGB>* irradiance;   // each node's pushed irradiance (null: not kept)
    std::vector<RGB>& radiosity;
    const LeafTerms& terms;
    const std::vector<VectorIrradiance>& clusters;
    static constexpr uint32_t kSerialFaces = 4096;

    // `parent_irradiance`: the parent's (zero at the root); `from_parent`: its pushed vector when the
    // parent is a receiving cluster.
    void visit(uint32_t i, const RGB& parent_irradiance, const VectorIrradiance* from_parent) const {
        const Node& node = h.nodes[i];
        RGB above = parent_irradiance;
        VectorIrradiance pushed;
        const bool pushes = node.cluster && !clusters.empty();
        if (pushes) {
            pushed = clusters[h.cluster_slot[i]];
            if (from_parent) pushed.add(*from_parent);
        } else if (from_parent) {
            above += from_parent->along(h.normal(i));
        }
        RGB own = gathered[i];
        if (power) own = node.area > 0 ? own / node.area : RGB{};
        const RGB here = terms.leaf_irradiance(i, node.leaf(), own, above);
        if (irradiance) (*irradiance)[i] = here;
        if (node.leaf()) {
            radiosity[i] = node.cluster ? RGB{} : h.emission(i) + mul(h.reflectance(i), here);
            return;
        }
        const VectorIrradiance* down = pushes ? &pushed : nullptr;
        if (node.cluster && node.face_end - node.face_begin > kSerialFaces)
            tbb::parallel_for(uint32_t(0), uint32_t(node.child_count),
                              [&](uint32_t c) { visit(node.first_child + c, here, down); });
        else
            for (uint32_t c = 0; c < node.child_count; ++c) visit(node.first_child + c, here, down);
        RGB acc;
        for (uint32_t c = 0; c < node.child_count; ++c)
            acc += radiosity[node.first_child + c] * h.nodes[node.first_child + c].area;
        radiosity[i] = acc / node.area;
    }
};

}  // namespace

void push_pull(const Hierarchy& h, const std::vector<RGB>& gathered, std::vector<RGB>& irradiance,
               std::vector<RGB>& radiosity, const LeafTerms& terms, const std::vector<VectorIrradiance>& clusters) {
    if (h.nodes.empty()) return;
    PushPullWalk{h, gathered, false, &irradiance, radiosity, terms, clusters}.visit(h.root, RGB{}, nullptr);
}

void push_pull_power(const Hierarchy& h, const std::vector<RGB>& received, std::vector<RGB>& radiosity,
                     const LeafTerms& terms, const std::vector<VectorIrradiance>& clusters,
                     std::vector<RGB>* irradiance) {
    if (h.nodes.empty()) return;
    PushPullWalk{h, received, true, irradiance, radiosity, terms, clusters}.visit(h.root, RGB{}, nullptr);
}

namespace {

// Stores b with the irradiance that goes with it, and per node the fraction of its power its
// own and its ancestors' links carry to some receiver (for the energy balance).
void finish(const Hierarchy& h, const std::vector<Link>& links, std::vector<RGB> b, HierarchicalSolution& sol,
            const LeafTerms& terms) {
    const size_t n = h.nodes.size();
    std::vector<RGB> gathered(n), irradiance(n), unused(n);
    std::vector<VectorIrradiance> clusters;
    for (const Link& l : links) add_link(h, l, b[l.source], gathered, clusters);
    push_pull(h, gathered, irradiance, unused, terms, clusters);
    sol.limited_leaves = terms.limited();
    sol.normalised_leaves = terms.normalised();
    std::vector<double> own(n, 0.0);
    for (const Link& l : links) own[l.source] += h.sent(l) / h.nodes[l.source].area;
    sol.outgoing.assign(n, 0.0);
    for (size_t i = 0; i < n; ++i)
        sol.outgoing[i] = own[i] + (h.nodes[i].parent == kNoNode ? 0.0 : sol.outgoing[h.nodes[i].parent]);
    sol.radiosity = std::move(b);
    sol.irradiance = std::move(irradiance);
}

// Records step `step`'s residual (refused when not finite) and says whether the solve stops
// there: converged (as sol.converged says), stopped by opt.on_iteration, or the last step.
bool record_step(HierarchicalSolution& sol, const SolverOptions& opt, const char* solver, uint64_t step, double res,
                 uint32_t face, const char* step_name = "iteration") {
    require_finite_residual(solver, res, step, step_name);
    // A solve whose residual has grown a million times over its best diverges. The gain limit
    // (gather_scale) keeps every leaf's rho F below 1, so this is the last guard, not the cure:
    // stop now, not after max_iterations with an overflowing radiosity.
    sol.least_residual = std::min(sol.least_residual, res);
    if (step > 8 && res > 1e6 * sol.least_residual)
        throw NonFiniteError(std::string(solver) + ": the residual grew from " + std::to_string(sol.least_residual) +
                             " to " + std::to_string(res) + " at " + step_name + " " + std::to_string(step) +
                             ": the solve diverges (a reflectance near 1, up to the 0.999 hirad allows, where the link "
                             "estimates of an element sum above 1; lower that material's reflectance or raise "
                             "hierarchy.samples); stopped, nothing was written");
    sol.residual_history.push_back(res);
    sol.iterations = step;
    sol.residual = res;
    const bool go_on = !opt.on_iteration || opt.on_iteration({step, res, face});
    if (res <= opt.tolerance || !go_on || step == opt.max_iterations) {
        sol.converged = res <= opt.tolerance;
        return true;
    }
    return false;
}

}  // namespace

HierarchicalSolution solve_push_pull(const Hierarchy& h, const std::vector<Link>& links, const std::vector<RGB>& start,
                                     const SolverOptions& opt) {
    const size_t n = h.nodes.size();
    for (size_t i = 1; i < n; ++i)
        if (h.nodes[i].parent != kNoNode && h.nodes[i].parent >= i)
            throw std::logic_error("hierarchy: a parent must come before its children");
    HierarchicalSolution sol;
    std::vector<RGB> b = start.size() == n ? start : node_emission(h);
    std::vector<RGB> gathered(n), irradiance(n), next(n);
    const std::vector<size_t> groups = receiver_groups(links);
    const std::vector<uint32_t> leaves = h.leaves();
    const double enorm = leaf_emission_norm(h, leaves);
    const LeafTerms terms = gather_terms(h, links);
    // Receiving clusters: each link's reception, computed once.
    std::vector<Reception> reception(links.size());
    const bool clusters_receive = any_cluster_receiver(h, links);
    std::vector<VectorIrradiance> clusters(clusters_receive ? h.cluster_shapes.size() : 0);
    if (clusters_receive)
        for (size_t k = 0; k < links.size(); ++k)
            if (h.slot_of(links[k].receiver) != kNoNode) reception[k] = h.reception(links[k].receiver, links[k].source);

    for (uint64_t it = 1; it <= opt.max_iterations; ++it) {
        std::fill(gathered.begin(), gathered.end(), RGB{});
        tbb::parallel_for(size_t(0), groups.size() - 1, [&](size_t g) {
            const uint32_t r = links[groups[g]].receiver;
            const uint32_t slot = h.slot_of(r);
            if (slot != kNoNode) {
                VectorIrradiance acc;
                for (size_t k = groups[g]; k < groups[g + 1]; ++k)
                    acc.add(b[links[k].source] * double(links[k].coupling), reception[k]);
                clusters[slot] = acc;
                return;
            }
            RGB acc;
            for (size_t k = groups[g]; k < groups[g + 1]; ++k) acc += b[links[k].source] * double(links[k].coupling);
            gathered[r] = acc / h.nodes[r].area;
        });
        push_pull(h, gathered, irradiance, next, terms, clusters);
        double r2 = 0;
        for (uint32_t i : leaves) {
            RGB d = next[i] - b[i];
            r2 += h.nodes[i].area * dot(d, d);
        }
        const double res = std::sqrt(r2) / enorm;
        if (record_step(sol, opt, "hierarchical Jacobi", it, res, UINT32_MAX)) break;
        b.swap(next);
    }
    finish(h, links, std::move(b), sol, terms);
    return sol;
}

namespace {

// The element trees of the faces: for every element its face root, and per face root its
// nodes in parent-first order.
struct FaceTrees {
    std::vector<uint32_t> root_of;                 // per node (kNoNode for clusters)
    std::vector<uint32_t> roots;                   // face roots in index order
    std::vector<uint32_t> slot;                    // per node: index of its face in `roots`
    std::vector<std::vector<uint32_t>> nodes;      // per face: its tree, parents first
};

FaceTrees face_trees(const Hierarchy& h) {
    FaceTrees t;
    const size_t n = h.nodes.size();
    t.root_of.assign(n, kNoNode);
    t.slot.assign(n, kNoNode);
    for (size_t i = 0; i < n; ++i) {
        const Node& node = h.nodes[i];
        if (node.cluster) continue;
        const bool is_root = node.parent == kNoNode || h.nodes[node.parent].cluster;
        t.root_of[i] = is_root ? static_cast<uint32_t>(i) : t.root_of[node.parent];
        if (is_root) {
            t.slot[i] = static_cast<uint32_t>(t.roots.size());
            t.roots.push_back(static_cast<uint32_t>(i));
            t.nodes.emplace_back();
        }
        t.slot[i] = t.slot[t.root_of[i]];
        t.nodes[t.slot[i]].push_back(static_cast<uint32_t>(i));
    }
    return t;
}

// Push `gathered` down one face tree and set B at its leaves, pull B up to the face root.
void push_pull_face(const Hierarchy& h, const std::vector<uint32_t>& tree, const std::vector<RGB>& gathered,
                    std::vector<RGB>& irradiance, std::vector<RGB>& radiosity, const LeafTerms& terms) {
    for (uint32_t i : tree) {
        const Node& node = h.nodes[i];
        const bool root = node.parent == kNoNode || h.nodes[node.parent].cluster;
        irradiance[i] = terms.leaf_irradiance(i, node.leaf(), gathered[i], root ? RGB{} : irradiance[node.parent]);
    }
    for (size_t k = tree.size(); k-- > 0;) {
        const uint32_t i = tree[k];
        const Node& node = h.nodes[i];
        if (node.leaf()) {
            radiosity[i] = h.emission(uint32_t(i)) + mul(h.reflectance(uint32_t(i)), irradiance[i]);
            continue;
        }
        RGB acc;
        for (uint32_t c = 0; c < node.child_count; ++c)
            acc += radiosity[node.first_child + c] * h.nodes[node.first_child + c].area;
        radiosity[i] = acc / node.area;
    }
}

// Area-weighted means up the clusters above a node.
void pull_ancestors(const Hierarchy& h, uint32_t i, std::vector<RGB>& radiosity) {
    for (uint32_t p = h.nodes[i].parent; p != kNoNode; p = h.nodes[p].parent) {
        const Node& node = h.nodes[p];
        RGB acc;
        for (uint32_t c = 0; c < node.child_count; ++c)
            acc += radiosity[node.first_child + c] * h.nodes[node.first_child + c].area;
        radiosity[p] = acc / node.area;
    }
}

double leaf_norm(const Hierarchy& h, const std::vector<uint32_t>& leaves, const std::vector<RGB>& v) {
    double s = 0;
    for (uint32_t i : leaves) s += h.nodes[i].area * dot(v[i], v[i]);
    return std::sqrt(s);
}

// One Jacobi evaluation T(b) = E + rho * (gather + push) at the leaves, pulled up.
std::vector<RGB> apply(const Hierarchy& h, const std::vector<Link>& links, const std::vector<RGB>& b,
                       const LeafTerms& terms) {
    const size_t n = h.nodes.size();
    std::vector<RGB> gathered(n), irradiance(n), out(n);
    std::vector<VectorIrradiance> clusters;
    for (const Link& l : links) add_link(h, l, b[l.source], gathered, clusters);
    push_pull(h, gathered, irradiance, out, terms, clusters);
    return out;
}

}  // namespace

HierarchicalSolution solve_gauss_seidel_push_pull(const Hierarchy& h, const std::vector<Link>& links,
                                                  const std::vector<RGB>& start, const SolverOptions& opt) {
    const size_t n = h.nodes.size();
    const FaceTrees trees = face_trees(h);
    // Links grouped by the face tree of their receiver (links are sorted by receiver).
    std::vector<std::vector<uint32_t>> by_face(trees.roots.size());
    for (uint32_t k = 0; k < links.size(); ++k) {
        const uint32_t slot = trees.slot[links[k].receiver];
        if (slot == kNoNode)
            throw std::invalid_argument("hierarchical Gauss-Seidel works face by face and cannot solve links that "
                                        "end on clusters (hierarchy.cluster_receivers): use solver.method jacobi "
                                        "or block_southwell");
        by_face[slot].push_back(k);
    }
    const std::vector<uint32_t> leaves = h.leaves();
    const double enorm = leaf_emission_norm(h, leaves);
    const LeafTerms terms = gather_terms(h, links);

    HierarchicalSolution sol;
    std::vector<RGB> b = start.size() == n ? start : node_emission(h);
    std::vector<RGB> gathered(n), irradiance(n);
    for (uint64_t it = 1; it <= opt.max_iterations; ++it) {
        // Residual of the current iterate, then one sweep.
        std::vector<RGB> tb = apply(h, links, b, terms);
        std::vector<RGB> diff(n);
        for (uint32_t i : leaves) diff[i] = tb[i] - b[i];
        const double res = leaf_norm(h, leaves, diff) / enorm;
        if (record_step(sol, opt, "hierarchical Gauss-Seidel", it, res, UINT32_MAX)) break;
        for (size_t f = 0; f < trees.roots.size(); ++f) {
            for (uint32_t i : trees.nodes[f]) gathered[i] = RGB{};
            for (uint32_t k : by_face[f])
                gathered[links[k].receiver] += b[links[k].source] * (double(links[k].coupling) / h.nodes[links[k].receiver].area);
            push_pull_face(h, trees.nodes[f], gathered, irradiance, b, terms);
            pull_ancestors(h, trees.roots[f], b);
        }
    }
    finish(h, links, std::move(b), sol, terms);
    return sol;
}

HierarchicalSolution solve_southwell_push_pull(const Hierarchy& h, const std::vector<Link>& links,
                                               const std::vector<RGB>& start, const SolverOptions& opt) {
    const size_t n = h.nodes.size();
    if (any_cluster_receiver(h, links))
        throw std::invalid_argument("hierarchical Southwell shoots face by face and cannot solve links that end on "
                                    "clusters (hierarchy.cluster_receivers): use solver.method jacobi or "
                                    "block_southwell");
    const FaceTrees trees = face_trees(h);
    const std::vector<uint32_t> leaves = h.leaves();
    // Links by source.
    std::vector<uint32_t> source_first(n + 1, 0), by_source(links.size());
    for (const Link& l : links) ++source_first[l.source + 1];
    for (size_t i = 0; i < n; ++i) source_first[i + 1] += source_first[i];
    {
        std::vector<uint32_t> cursor(source_first.begin(), source_first.end() - 1);
        for (uint32_t k = 0; k < links.size(); ++k) by_source[cursor[links[k].source]++] = k;
    }
    const double enorm = leaf_emission_norm(h, leaves);
    const LeafTerms terms = gather_terms(h, links);

    // b: radiosity already shot; r = T(b) - b: unshot, kept at the leaves.
    std::vector<RGB> b = start.size() == n ? start : std::vector<RGB>(n);
    std::vector<RGB> r(n);
    {
        std::vector<RGB> tb = apply(h, links, b, terms);
        for (uint32_t i : leaves) r[i] = tb[i] - b[i];
    }
    auto face_power = [&](size_t f) {
        double p = 0;
        for (uint32_t i : trees.nodes[f])
            if (h.nodes[i].leaf()) p += (std::fabs(r[i].x) + std::fabs(r[i].y) + std::fabs(r[i].z)) * h.nodes[i].area;
        return p;
    };
    std::vector<double> power(trees.roots.size());
    std::priority_queue<std::pair<double, int64_t>> queue;  // (power, -face): ties to the lower face
    for (size_t f = 0; f < trees.roots.size(); ++f) {
        power[f] = face_power(f);
        queue.push({power[f], -int64_t(f)});
    }
    double r2 = 0;
    for (uint32_t i : leaves) r2 += h.nodes[i].area * dot(r[i], r[i]);

    HierarchicalSolution sol;
    std::vector<RGB> delta(n), gathered(n), pushed(n);
    std::vector<uint8_t> touched_face(trees.roots.size(), 0);
    std::vector<uint32_t> touched;
    for (uint64_t shot = 1; shot <= opt.max_iterations; ++shot) {
        // The face with the most unshot power (stale queue entries are skipped).
        size_t f = 0;
        while (!queue.empty()) {
            auto [p, neg] = queue.top();
            queue.pop();
            if (p == power[size_t(-neg)]) { f = size_t(-neg); break; }
        }
        const std::vector<uint32_t>& tree = trees.nodes[f];
        // Shoot: the face's unshot radiosity moves into b, pulled up its tree as delta.
        for (size_t k = tree.size(); k-- > 0;) {
            const uint32_t i = tree[k];
            const Node& node = h.nodes[i];
            if (node.leaf()) {
                delta[i] = r[i];
                b[i] += r[i];
                r2 -= node.area * dot(r[i], r[i]);
                r[i] = RGB{};
                continue;
            }
            RGB acc;
            for (uint32_t c = 0; c < node.child_count; ++c) acc += delta[node.first_child + c] * h.nodes[node.first_child + c].area;
            delta[i] = acc / node.area;
            b[i] = RGB{};
            for (uint32_t c = 0; c < node.child_count; ++c) b[i] += b[node.first_child + c] * h.nodes[node.first_child + c].area;
            b[i] = b[i] / node.area;
        }
        pull_ancestors(h, trees.roots[f], b);
        // Send delta through the links of the tree's nodes and of the clusters above it.
        auto send = [&](uint32_t source, const RGB& d) {
            for (uint32_t k = source_first[source]; k < source_first[source + 1]; ++k) {
                const Link& l = links[by_source[k]];
                gathered[l.receiver] += d * (double(l.coupling) / h.nodes[l.receiver].area);
                const uint32_t g = trees.slot[l.receiver];
                if (!touched_face[g]) { touched_face[g] = 1; touched.push_back(g); }
            }
        };
        for (uint32_t i : tree) send(i, delta[i]);
        const uint32_t face_root = trees.roots[f];
        for (uint32_t p = h.nodes[face_root].parent; p != kNoNode; p = h.nodes[p].parent)
            send(p, delta[face_root] * (h.nodes[face_root].area / h.nodes[p].area));
        // Receivers: push down their trees, add rho * H to the unshot radiosity of the leaves.
        std::sort(touched.begin(), touched.end());
        for (uint32_t g : touched) {
            for (uint32_t i : trees.nodes[g]) {
                const Node& node = h.nodes[i];
                const bool root = node.parent == kNoNode || h.nodes[node.parent].cluster;
                pushed[i] = terms.leaf_irradiance(i, node.leaf(), gathered[i], root ? RGB{} : pushed[node.parent]);
                gathered[i] = RGB{};
                if (node.leaf()) {
                    const RGB got = pushed[i];
                    r2 -= node.area * dot(r[i], r[i]);
                    r[i] += mul(h.reflectance(uint32_t(i)), got);
                    r2 += node.area * dot(r[i], r[i]);
                }
            }
            power[g] = face_power(g);
            queue.push({power[g], -int64_t(g)});
            touched_face[g] = 0;
        }
        touched.clear();
        if (!touched_face[f]) {
            power[f] = face_power(f);
            queue.push({power[f], -int64_t(f)});
        }
        // The running sum drifts; recompute it exactly now and then and before stopping.
        double res = std::sqrt(std::max(r2, 0.0)) / enorm;
        if (shot % 4096 == 0 || res <= opt.tolerance) {
            r2 = 0;
            for (uint32_t i : leaves) r2 += h.nodes[i].area * dot(r[i], r[i]);
            res = std::sqrt(r2) / enorm;
        }
        if (record_step(sol, opt, "hierarchical Southwell", shot, res, face_root, "shot")) break;
    }
    // Irradiance of the returned b, and the outgoing fractions, as for Jacobi.
    finish(h, links, std::move(b), sol, terms);
    return sol;
}

}  // namespace hirad
