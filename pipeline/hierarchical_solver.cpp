#include "hierarchical_solver.h"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>

namespace hirad {

void sort_links(std::vector<Link>& links) {
    std::sort(links.begin(), links.end(), [](const Link& a, const Link& b) {
        return a.receiver < b.receiver || (a.receiver == b.receiver && a.source < b.source);
    });
}

std::vector<RGB> node_emission(const Hierarchy& h) {
    std::vector<RGB> e(h.nodes.size());
    // Children have larger indices than their parents: a reverse sweep pulls.
    for (size_t i = h.nodes.size(); i-- > 0;) {
        const Node& n = h.nodes[i];
        if (n.leaf()) {
            e[i] = n.cluster ? RGB{} : n.shape.emission;
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

// Push irradiance down from `root`, set B = E + rho H at leaves, pull B up. Parents come
// before children in index order, so one forward sweep pushes and one backward sweep pulls.
void push_pull(const Hierarchy& h, const std::vector<RGB>& gathered, std::vector<RGB>& irradiance,
               std::vector<RGB>& radiosity) {
    const size_t n = h.nodes.size();
    for (size_t i = 0; i < n; ++i) {
        const Node& node = h.nodes[i];
        irradiance[i] = gathered[i] + (node.parent == kNoNode ? RGB{} : irradiance[node.parent]);
    }
    for (size_t i = n; i-- > 0;) {
        const Node& node = h.nodes[i];
        if (node.leaf()) {
            radiosity[i] = node.cluster ? RGB{} : node.shape.emission + mul(node.shape.reflectance, irradiance[i]);
            continue;
        }
        RGB acc;
        for (uint32_t c = 0; c < node.child_count; ++c)
            acc += radiosity[node.first_child + c] * h.nodes[node.first_child + c].area;
        radiosity[i] = acc / node.area;
    }
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
    double enorm = 0;
    for (uint32_t i : leaves) enorm += h.nodes[i].area * dot(h.nodes[i].shape.emission, h.nodes[i].shape.emission);
    enorm = enorm > 0 ? std::sqrt(enorm) : 1.0;

    for (uint64_t it = 1; it <= opt.max_iterations; ++it) {
        std::fill(gathered.begin(), gathered.end(), RGB{});
        tbb::parallel_for(size_t(0), groups.size() - 1, [&](size_t g) {
            RGB acc;
            const uint32_t r = links[groups[g]].receiver;
            for (size_t k = groups[g]; k < groups[g + 1]; ++k) acc += b[links[k].source] * double(links[k].coupling);
            gathered[r] = acc / h.nodes[r].area;
        });
        push_pull(h, gathered, irradiance, next);
        double r2 = 0;
        for (uint32_t i : leaves) {
            RGB d = next[i] - b[i];
            r2 += h.nodes[i].area * dot(d, d);
        }
        const double res = std::sqrt(r2) / enorm;
        sol.residual_history.push_back(res);
        sol.iterations = it;
        sol.residual = res;
        bool go_on = !opt.on_iteration || opt.on_iteration({it, res, UINT32_MAX});
        if (res <= opt.tolerance || !go_on || it == opt.max_iterations) {
            sol.converged = res <= opt.tolerance;
            break;
        }
        b.swap(next);
    }
    // The irradiance that goes with the returned b.
    std::fill(gathered.begin(), gathered.end(), RGB{});
    for (size_t g = 0; g + 1 < groups.size(); ++g) {
        RGB acc;
        const uint32_t r = links[groups[g]].receiver;
        for (size_t k = groups[g]; k < groups[g + 1]; ++k) acc += b[links[k].source] * double(links[k].coupling);
        gathered[r] = acc / h.nodes[r].area;
    }
    for (size_t i = 0; i < n; ++i) {
        const Node& node = h.nodes[i];
        irradiance[i] = gathered[i] + (node.parent == kNoNode ? RGB{} : irradiance[node.parent]);
    }
    // Fraction of each node's power that links carry somewhere: its own links' couplings over
    // its area, plus what its ancestors' links take of it.
    std::vector<double> own(n, 0.0);
    for (const Link& l : links) own[l.source] += double(l.coupling) / h.nodes[l.source].area;
    sol.outgoing.assign(n, 0.0);
    for (size_t i = 0; i < n; ++i)
        sol.outgoing[i] = own[i] + (h.nodes[i].parent == kNoNode ? 0.0 : sol.outgoing[h.nodes[i].parent]);
    sol.radiosity = std::move(b);
    sol.irradiance = std::move(irradiance);
    return sol;
}

}  // namespace hirad
