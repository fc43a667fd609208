#include "pipeline/hierarchy/refine.h"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <utility>

#include "pipeline/geometry/formfactors.h"

namespace hirad {

Refiner::Refiner(Hierarchy& hierarchy, const Visibility& visibility, const RefineOptions& options)
    : h_(hierarchy), vis_(visibility), opt_(options) {}

namespace {
// The distance between two nodes' boxes (0 when they overlap).
double node_gap(const Node& a, const Node& b) {
    double gap2 = 0;
    for (int k = 0; k < 3; ++k) {
        const double d = std::max({0.0, a.lo[k] - b.hi[k], b.lo[k] - a.hi[k]});
        gap2 += d * d;
    }
    return std::sqrt(gap2);
}
}  // namespace

bool Refiner::must_split_clusters(uint32_t a, uint32_t b) const {
    // Clusters that are close compared with their size cannot be summarised by a few point
    // pairs (the kernel varies too much across them): such links are always split.
    const Node& na = h_.nodes[a];
    const Node& nb = h_.nodes[b];
    if (!na.cluster && !nb.cluster) return false;
    const double size = std::max(na.cluster ? na.diagonal() : 0.0, nb.cluster ? nb.diagonal() : 0.0);
    return node_gap(na, nb) < 0.5 * size;
}

bool Refiner::misdirected(const Link& l) const {
    // A cluster receiver whose sharing (Hierarchy::reception) may misplace more than the
    // direction tolerance of the link's light, and more than a small part of epsilon.
    if (!h_.nodes[l.receiver].cluster) return false;
    const double misplaced = h_.misplaced(l.receiver, l.source);
    if (misplaced <= Hierarchy::kDirectionTolerance) return false;
    return misplaced * power_bound(l) > kSlight * opt_.epsilon;
}

bool Refiner::slight(const Link& l) const { return power_bound(l) <= kSlight * opt_.epsilon; }

double Refiner::power_bound(const Link& l) const {
    // The most the link could carry, B_max(S) times a bound on G that needs no estimate: G is
    // at most min(A_R, A_S) (F <= 1 and reciprocity), and A_R A_S / (pi d^2) for nodes d apart
    // that are not a close pair (close pairs are judged by the first bound, as in decide).
    const Node& nr = h_.nodes[l.receiver];
    const Node& ns = h_.nodes[l.source];
    double bound = std::min(nr.area, ns.area);
    const double gap = node_gap(nr, ns);
    if (gap > 0 && !close_pair(l.receiver, l.source)) bound = std::min(bound, nr.area * ns.area / (kPi * gap * gap));
    return peak_[l.source] * bound;
}

bool Refiner::estimable(const Link& l) const {
    if (l.receiver == l.source) return false;
    const bool cluster = h_.nodes[l.receiver].cluster;
    if (!opt_.cluster_receivers) return !cluster && !must_split_clusters(l.receiver, l.source);
    if (must_split_clusters(l.receiver, l.source) && !slight(l)) return false;
    if (cluster && h_.facing(l.receiver, l.source) == Hierarchy::Facing::Back) return false;
    return !misdirected(l);
}

bool Refiner::close_pair(uint32_t a, uint32_t b) const {
    // Elements whose boxes are nearer than half the larger one's diagonal (clusters that close
    // are always split: must_split_clusters).
    const Node& na = h_.nodes[a];
    const Node& nb = h_.nodes[b];
    return node_gap(na, nb) < 0.5 * std::max(na.diagonal(), nb.diagonal());
}

bool Refiner::may_face(uint32_t a, uint32_t b) const {
    // Whether light can pass between two nodes at all: some corner of each in front of the
    // other's plane. A cluster holds surfaces facing every way: only its box is known, which
    // must reach in front of an element's plane (tiles of one floor never light each other).
    const Node& na = h_.nodes[a];
    const Node& nb = h_.nodes[b];
    auto in_front = [](const Patch& of, const Patch& plane) {
        for (int k = 0; k < of.nv; ++k)
            if (dot(of.p[k] - plane.p[0], plane.normal) > 1e-9) return true;
        return false;
    };
    auto box_in_front = [](const Node& box, const Patch& plane) {
        for (int k = 0; k < 8; ++k) {
            const Vec3 c{k & 1 ? box.hi.x : box.lo.x, k & 2 ? box.hi.y : box.lo.y, k & 4 ? box.hi.z : box.lo.z};
            if (dot(c - plane.p[0], plane.normal) > 1e-9) return true;
        }
        return false;
    };
    if (na.cluster && nb.cluster) return true;
    Patch scratch_a, scratch_b;
    if (na.cluster) return box_in_front(na, h_.shape(b, scratch_b));
    if (nb.cluster) return box_in_front(nb, h_.shape(a, scratch_a));
    const Patch& pa = h_.shape(a, scratch_a);
    const Patch& pb = h_.shape(b, scratch_b);
    return in_front(pb, pa) && in_front(pa, pb);
}

Link Refiner::estimate(uint32_t r, uint32_t s, uint64_t stream) const {
    Link link;
    link.receiver = r;
    link.source = s;
    const Node& nr = h_.nodes[r];
    const Node& ns = h_.nodes[s];
    const int g = std::max(1, static_cast<int>(std::lround(std::sqrt(double(opt_.samples)))));
    const int n = g * g;
    const double lift = vis_.ray_offset();
    // Seeded by the nodes' keys, not their indices: the same pair draws the same samples however
    // the hierarchy was numbered (on whichever machine its group was refined).
    const uint64_t kr = h_.key(r), ks = h_.key(s);
    Rng rng(hash_pair(std::min(kr, ks), std::max(kr, ks), opt_.seed ^ 0x11E7ull ^ (stream * 0x9E3779B97F4A7C15ull)));
    std::vector<Vec3> from, to;
    std::vector<double> weight;
    from.reserve(n);
    to.reserve(n);
    weight.reserve(n);
    double unoccluded = 0;
    // With an element at one end, points on the other end see it through the exact
    // point-to-polygon form factor (A_x F(dA_x -> polygon)); with clusters at both ends the
    // point-to-point kernel between stratified points is used.
    const bool polygon_source = !ns.cluster;
    const bool polygon_receiver = !polygon_source && !nr.cluster;
    const uint32_t sampled = polygon_source ? r : (polygon_receiver ? s : r);
    Patch scratch;
    const Patch& target = h_.shape(polygon_source ? s : r, scratch);  // (empty between clusters)
    const double area = h_.nodes[sampled].area;
    // A polygon far from the sampled end compared with its size (RefineOptions::far): the
    // point-to-point kernel between stratified points of both ends, the polygon's strata
    // paired with the sampled end's in a shuffled order.
    const bool far = (polygon_source || polygon_receiver) &&
                     h_.nodes[polygon_source ? s : r].diagonal() <= opt_.far * node_gap(nr, ns);
    std::vector<int> cell;
    if (far) {
        cell.resize(n);
        for (int k = 0; k < n; ++k) cell[k] = k;
        for (int k = n - 1; k > 0; --k) std::swap(cell[k], cell[rng.next() % uint64_t(k + 1)]);
    }
    for (int k = 0; k < n; ++k) {
        const double s0 = (k % g + rng.uniform()) / g, t0 = (k / g + rng.uniform()) / g;
        Vec3 x, nx;
        h_.sample(sampled, rng.uniform(), s0, t0, x, nx);
        const double s1 = rng.uniform(), t1 = rng.uniform();
        if (far) {
            const Vec3 y = target.point((cell[k] % g + s1) / g, (cell[k] / g + t1) / g);
            const Vec3 d = y - x;
            const double r2 = dot(d, d);
            const double cx = dot(nx, d), cy = -dot(target.normal, d);
            if (!(r2 > 0) || cx <= 0 || cy <= 0) continue;
            const double w = cx * cy / (kPi * r2 * r2) * target.area * area / n;
            unoccluded += w;
            from.push_back(x + nx * lift);
            to.push_back(y + target.normal * lift);
            weight.push_back(w);
        } else if (polygon_source || polygon_receiver) {
            // y drawn by the kernel, not by area (formfactors.h): V(x, y) then estimates the
            // visible share of F, however large the polygon is next to x.
            Vec3 y;
            bool drawn = false;
            const double f = point_polygon_form_factor_and_point(x, nx, target.p.data(), target.nv, target.normal, rng,
                                                                 y, drawn);
            if (f <= 0) continue;
            const double w = f * area / n;
            unoccluded += w;
            from.push_back(x + nx * lift);
            if (!drawn) y = target.point(s1, t1);
            to.push_back(y + target.normal * lift);
            weight.push_back(w);
        } else {
            Vec3 y, ny;
            h_.sample(s, rng.uniform(), s1, t1, y, ny);
            Vec3 d = y - x;
            double r2 = dot(d, d);
            if (r2 <= 0) continue;
            double cx = dot(nx, d), cy = -dot(ny, d);
            if (cx <= 0 || cy <= 0) continue;
            double w = cx * cy / (kPi * r2 * r2) * nr.area * ns.area / n;
            unoccluded += w;
            from.push_back(x + nx * lift);
            to.push_back(y + ny * lift);
            weight.push_back(w);
        }
    }
    // What arrives along each ray: 1, 0 where something opaque is in the way, the product of
    // the panes' T(theta) through glass (visibility.h: glass is a thin sheet to links too).
    std::vector<float> pass(from.size());
    vis_.segments_transmittance(from.data(), to.data(), from.size(), pass.data());
    double g_sum = 0;
    double arrived = 0;
    for (size_t k = 0; k < from.size(); ++k)
        if (pass[k] > 0) { g_sum += weight[k] * double(pass[k]); arrived += double(pass[k]); }
    if (!polygon_source && !polygon_receiver) {
        // The point-to-point kernel is unbounded where the two clusters touch (1 / r^2 at
        // points r apart), so a few pairs drawn near a shared edge can make the sum as large as
        // a float holds. G is at most min(A_R, A_S) (F <= 1 and reciprocity): a larger estimate
        // is that noise, and is cut to the bound (clusters that close are linked only while the
        // link carries little: kSlight).
        const double most = std::min(nr.area, ns.area);
        unoccluded = std::min(unoccluded, most);
        g_sum = std::min(g_sum, most);
    }
    link.coupling = static_cast<float>(g_sum);
    link.unoccluded = static_cast<float>(unoccluded);
    link.visibility = from.empty() ? 0.0f : static_cast<float>(arrived / double(from.size()));
    return link;
}

double Refiner::link_error(const Link& link, const std::vector<double>& peak) const {
    // Power the link could carry: the brightest radiosity below the source (luminance) times
    // G. The link transports the source's mean radiosity, so where the source's surfaces
    // differ (a cluster whose bright faces look at the receiver while its dark ones look
    // away) the error is up to (B_max - B_min) G, which B_max G bounds. The unoccluded G
    // stands for G: where visibility is partial the estimate is uncertain up to it (so such
    // links refine towards shadow boundaries), and where it is full the two are equal.
    return peak[link.source] * link.unoccluded;
}

Refiner::Action Refiner::decide(const Link& link, const std::vector<double>& peak) const {
    if (link.receiver == link.source) return h_.nodes[link.receiver].cluster ? Action::SplitSelf : Action::Drop;
    const bool receiver_splits = h_.can_subdivide(link.receiver, opt_.min_area);
    const bool source_splits = h_.can_subdivide(link.source, opt_.min_area);
    auto split_larger = [&] {
        const double ar = h_.nodes[link.receiver].area, as = h_.nodes[link.source].area;
        if (receiver_splits && (!source_splits || ar >= as)) return Action::SplitReceiver;
        return Action::SplitSource;
    };
    // Sources may stay clusters: the estimate sees each source surface with its own normal.
    // Clusters too close to summarise by a few point pairs are split. A cluster receives
    // where Hierarchy::facing says one vector shares the light among its faces (faces of one
    // orientation, or all of them seeing the source from their front within the direction
    // tolerance), and a source wholly behind its faces is dropped; other cluster receivers
    // are split.
    // Links that carry little (refine.h): with clusters that receive, both geometric rules
    // give way where what they guard against is within a small part of epsilon: close
    // clusters are kept while the most the link can carry is at most kSlight x epsilon (so
    // is any error of its estimate), and any other cluster receiver while the light its
    // sharing may misplace (Hierarchy::misplaced) is. Without this, round 1 (every source
    // dark but the luminaires) split receivers down to single directions and close clusters
    // down to faces whatever the links carried: some 500,000 links per source group of 1,024
    // faces on a 1M-face kitchen. Later rounds judge the links by the solved radiosity.
    const Node& rn = h_.nodes[link.receiver];
    const Node& sn = h_.nodes[link.source];
    if (rn.cluster && !opt_.cluster_receivers) return Action::SplitReceiver;
    if (must_split_clusters(link.receiver, link.source) && !(opt_.cluster_receivers && slight(link)))
        return rn.cluster && !(sn.cluster && sn.diagonal() > rn.diagonal()) ? Action::SplitReceiver
                                                                              : Action::SplitSource;
    if (rn.cluster && h_.facing(link.receiver, link.source) == Hierarchy::Facing::Back) return Action::Drop;
    // One direction would misplace the light among its faces.
    if (misdirected(link)) return Action::SplitReceiver;
    // No sample pair faced both ways. A few samples miss the part of a large pair that does
    // face: dropping such links for good biased the transport dark (the kept links' transport
    // comes from an independent estimate, which would not have been zero). So when the two
    // can face each other, the link is split if the most it could carry exceeds epsilon (G is
    // at most min(A_R, A_S), by F <= 1 and reciprocity, and A_R A_S / (pi d^2) at a distance
    // d apart), and kept otherwise, with its independent transport estimate like any other.
    if (link.unoccluded <= 0) {
        if (!may_face(link.receiver, link.source)) return Action::Drop;
        if (!receiver_splits && !source_splits) return Action::Keep;
        const Node& nr = h_.nodes[link.receiver];
        const Node& ns = h_.nodes[link.source];
        const double gap = node_gap(nr, ns), gap2 = gap * gap;
        double bound = std::min(nr.area, ns.area);
        if (gap2 > 0) bound = std::min(bound, nr.area * ns.area / (kPi * gap2));
        return peak[link.source] * bound > opt_.epsilon ? split_larger() : Action::Keep;
    }
    // Partly visible links refine towards the shadow boundary, and a link none of whose rays
    // arrived is only dropped when even its unoccluded transfer is negligible.
    const double error = link_error(link, peak);
    // Close pairs: a few points drawn by area on an end that is large next to the gap between
    // the two (a 200 m ground plane 3 m under a lamp) all land where the kernel is small, and
    // the estimate, bound included, comes out near zero while G is up to min(A_R, A_S) (F <= 1
    // and reciprocity). Such links are judged by that bound, so the large end is split until it
    // is no larger than about twice the gap, where a few points do sample the kernel.
    const bool close = close_pair(link.receiver, link.source);
    const double bounded =
        close ? std::max(error, peak[link.source] * std::min(h_.nodes[link.receiver].area, h_.nodes[link.source].area))
              : error;
    // Kept whatever its own rays saw: dropping the links none of whose oracle rays arrived
    // would bias the transport dark.
    if (!receiver_splits && !source_splits) return Action::Keep;
    if (bounded > opt_.epsilon) return split_larger();
    // Uneven sources seen in part (see refine.h): split at the source, whose hidden and visible
    // parts then become links of their own.
    if (opt_.spread > 0 && source_splits && !h_.nodes[link.source].cluster && (close || link.visibility < 1) &&
        (peak[link.source] - trough_[link.source]) * link.unoccluded > opt_.spread)
        return Action::SplitSource;
    // The relative rule (see refine.h) judges the estimate, not the close-pair bound; links none
    // of whose rays arrived carry nothing to compare, and are left to the absolute rule.
    if (!gathered_.empty() && link.visibility > 0 && error > 1e-3 * opt_.epsilon &&
        error > opt_.relative * h_.nodes[link.receiver].area * gathered_[link.receiver])
        return split_larger();
    return Action::Keep;
}

std::vector<Link> Refiner::initial_links(const std::vector<RGB>& radiosity, RefineStats& stats) {
    if (h_.nodes.empty()) return {};
    Link self;
    self.receiver = self.source = h_.root;
    set_radiosity(radiosity, false);
    return run_group({self}, {1}, stats);
}

std::vector<Link> Refiner::refine(const std::vector<Link>& links, const std::vector<RGB>& radiosity, RefineStats& stats) {
    set_radiosity(radiosity, true);
    return run_group(links, std::vector<uint8_t>(links.size(), 1), stats);
}

void Refiner::set_radiosity(const std::vector<RGB>& radiosity, bool solved) {
    // Children come after their parents: one backward sweep.
    if (radiosity.size() != h_.nodes.size()) throw std::invalid_argument("refine: one radiosity per node needed");
    peak_.assign(h_.nodes.size(), 0.0);
    trough_.assign(h_.nodes.size(), 0.0);
    for (size_t i = h_.nodes.size(); i-- > 0;) {
        const Node& node = h_.nodes[i];
        // The brightest below a node counts its own value too; the darkest is its leaves' (a
        // parent's own value is their mean, never below the darkest of them).
        double b = std::max(0.0, luminance(radiosity[i]));
        double lo = node.child_count ? std::numeric_limits<double>::infinity() : b;
        for (uint32_t c = 0; c < node.child_count; ++c) {
            b = std::max(b, peak_[node.first_child + c]);
            lo = std::min(lo, trough_[node.first_child + c]);
        }
        peak_[i] = b;
        trough_[i] = lo;
    }
    gathered_.clear();
    if (!solved || !(opt_.relative > 0)) return;
    gathered_.assign(h_.nodes.size(), std::numeric_limits<double>::infinity());
    for (size_t i = 0; i < h_.nodes.size(); ++i) {
        const Node& node = h_.nodes[i];
        if (node.cluster) continue;
        const double rho = luminance(h_.reflectance(uint32_t(i)));
        if (rho > 0) gathered_[i] = std::max(0.0, luminance(radiosity[i])) / rho;
    }
}

void Refiner::release() {
    std::vector<double>().swap(peak_);
    std::vector<double>().swap(trough_);
    std::vector<double>().swap(gathered_);
}

std::vector<Link> Refiner::run_group(std::vector<Link> frontier, std::vector<uint8_t> evaluated, RefineStats& stats) {
    std::vector<Link> all;
    run_group(std::move(frontier), std::move(evaluated), stats, SIZE_MAX, [&](std::vector<Link>& kept) {
        if (all.empty()) all.swap(kept);
        else all.insert(all.end(), kept.begin(), kept.end());
    });
    return all;
}

uint64_t Refiner::run_group(std::vector<Link> first, std::vector<uint8_t> first_evaluated, RefineStats& stats,
                            size_t batch, const std::function<void(std::vector<Link>&)>& keep) {
    batch = std::max<size_t>(1, batch);
    std::vector<double>& peak = peak_;
    // Batches waiting, the next one last; with one batch of everything this is breadth first.
    struct Batch {
        std::vector<Link> links;
        std::vector<uint8_t> evaluated;
    };
    std::vector<Batch> stack;
    stack.push_back({std::move(first), std::move(first_evaluated)});
    uint64_t waiting = stack.back().links.size(), held_peak = waiting;
    std::vector<Link> kept;
    auto flush = [&](bool all) {
        while (kept.size() >= batch || (all && !kept.empty())) {
            if (kept.size() <= batch) {
                std::vector<Link> out;
                out.swap(kept);
                keep(out);
                break;
            }
            std::vector<Link> out(kept.begin(), kept.begin() + long(batch));
            kept.erase(kept.begin(), kept.begin() + long(batch));
            keep(out);
        }
    };
    while (!stack.empty()) {
        std::vector<Link> frontier = std::move(stack.back().links);
        std::vector<uint8_t> evaluated = std::move(stack.back().evaluated);
        stack.pop_back();
        waiting -= frontier.size();
        // 1. Estimate the links that are new, in parallel.
        tbb::parallel_for(size_t(0), frontier.size(), [&](size_t k) {
            if (evaluated[k] || !estimable(frontier[k])) return;
            frontier[k] = estimate(frontier[k].receiver, frontier[k].source);
        });
        // (Without clusters that receive, the count also takes the element receivers of close
        // clusters, which are not estimated: the reports' figures are kept as they were.)
        for (size_t k = 0; k < frontier.size(); ++k)
            if (!evaluated[k] && frontier[k].receiver != frontier[k].source &&
                (opt_.cluster_receivers ? estimable(frontier[k])
                                        : !h_.nodes[frontier[k].receiver].cluster || estimable(frontier[k])))
                ++stats.evaluated;
        // 2. Decide, in parallel; 4. grow the nodes that split and queue the children's links,
        // in frontier order so the result does not depend on threads.
        std::vector<Action> action(frontier.size());
        tbb::parallel_for(size_t(0), frontier.size(), [&](size_t k) { action[k] = decide(frontier[k], peak); });
        // 3. The links kept from this pass's estimates get their independent transport estimate,
        // spread over the receiver's open area (Hierarchy::open: its part inside geometry
        // receives nothing, and its H is that of the rest).
        h_.measure_open(vis_);
        tbb::parallel_for(size_t(0), frontier.size(), [&](size_t k) {
            if (action[k] == Action::Keep && !evaluated[k]) {
                const double open = h_.open_share(frontier[k].receiver);
                const double g = estimate(frontier[k].receiver, frontier[k].source, 1).coupling;
                frontier[k].coupling = static_cast<float>(open > 0 ? g / open : g);
            }
        });
        for (size_t k = 0; k < frontier.size(); ++k) stats.evaluated += action[k] == Action::Keep && !evaluated[k];
        std::vector<Link> next;
        for (size_t k = 0; k < frontier.size(); ++k) {
            const Link& l = frontier[k];
            switch (action[k]) {
                case Action::Keep:
                    // A zero transport estimate with light that could pass is kept: later
                    // rounds may split it, and the final gather evaluates it again at each
                    // point (dropping it biased the transport dark).
                    if (!(l.coupling > 0) && !(l.unoccluded > 0)) break;
                    kept.push_back(l);
                    kept.back().error = static_cast<float>(link_error(l, peak));
                    break;
                case Action::Drop: break;
                case Action::SplitSelf: {
                    const Node node = h_.nodes[l.receiver];
                    for (uint32_t a = 0; a < node.child_count; ++a)
                        for (uint32_t b = 0; b < node.child_count; ++b) {
                            Link c;
                            c.receiver = node.first_child + a;
                            c.source = node.first_child + b;
                            next.push_back(c);
                        }
                    ++stats.split;
                    break;
                }
                case Action::SplitReceiver:
                case Action::SplitSource: {
                    const uint32_t end = action[k] == Action::SplitReceiver ? l.receiver : l.source;
                    h_.subdivide(end);
                    const Node node = h_.nodes[end];
                    for (uint32_t c = 0; c < node.child_count; ++c) {
                        Link child;
                        child.receiver = action[k] == Action::SplitReceiver ? node.first_child + c : l.receiver;
                        child.source = action[k] == Action::SplitSource ? node.first_child + c : l.source;
                        next.push_back(child);
                    }
                    ++stats.split;
                    break;
                }
            }
        }
        // New nodes inherit their parent's bounds (and light, for the relative rule) for the oracle.
        for (size_t i = peak.size(); i < h_.nodes.size(); ++i) {
            const uint32_t parent = h_.nodes[i].parent;
            peak.push_back(peak[parent]);
            trough_.push_back(trough_[parent]);
            if (!gathered_.empty()) gathered_.push_back(gathered_[parent]);
        }
        // The children's links, cut into batches, the first on top: depth first.
        for (size_t end = next.size(); end > 0;) {
            const size_t begin = end > batch ? ((end - 1) / batch) * batch : 0;
            Batch b{std::vector<Link>(next.begin() + long(begin), next.begin() + long(end)), {}};
            b.evaluated.assign(b.links.size(), 0);
            waiting += b.links.size();
            stack.push_back(std::move(b));
            end = begin;
        }
        held_peak = std::max<uint64_t>(held_peak, frontier.size() + waiting + kept.size());
        flush(false);
    }
    flush(true);
    stats.rays = vis_.rays_cast();
    return held_peak;
}

}  // namespace hirad
