// Links of hierarchical radiosity and the refinement that creates them.
//
// A link carries light from a source node to a receiver node: H_receiver += G / A_receiver *
// B_source, where G = integral over both node surfaces of cos cos V / (pi r^2) is estimated
// with the surfaces' own normals (so a cluster is treated as the surfaces it holds, not as a
// flat patch). Links (pipeline/core/link.h) are plain data: no pointers, written to disk in
// chunks as they are.
//
// Sources may be clusters. Receivers are elements unless `cluster_receivers` is set: then a
// cluster receives as a whole where one vector shares its light among its faces by their
// orientation (Hierarchy::facing, Hierarchy::reception: faces of one orientation, or faces
// that all see the source from their front within a direction tolerance), so the links a
// million small faces need grow with the lighting, not with the faces. Other clusters are
// split; a link to faces that all see the source from behind is dropped. Refinement is brightness weighted:
// a link whose power bound B_max(S) * G exceeds epsilon (B_max: the brightest surface below
// the source, so that sources of uneven radiosity are split) is replaced by links to the
// children of its larger end. For a partly occluded link the
// unoccluded transfer is used, so links refine towards shadow boundaries. It starts from the
// root's self-link and runs level by level, the estimates of each level in parallel.
//
// epsilon is one threshold for the whole scene, so a dim room in a bright scene (a classroom on
// a 220 m ground plane under the sky: the ground takes 99 % of the light) keeps links that each
// carry a large part of what its surfaces receive, and its interreflected light comes out far
// too dark. The relative rule bounds a link against its own receiver instead: once a round has
// been solved, a link (any of whose rays arrived) is also split while its power bound exceeds
// `relative` x A_R x H_R, H_R = B_R / rho_R the light the receiver gathers (with its direct
// light), so every receiver is resolved to about the same fraction of its own light, as
// Radiance's -aa bounds ambient error relative to the local value. Below 1e-3 x epsilon
// nothing is split for it (near-black corners would otherwise refine to min_area).
//
// Uneven sources seen in part. A link carries its source's mean radiosity, B_S times G, where
// the light that arrives is the integral of B(y) dG(y) over S. The two differ when both B and
// the kernel vary over S: where S is partly hidden from R, or close to R (the kernel then
// weights S's near part far above its far part). The difference is at most
// (B_max(S) - B_min(S)) G, and it has one sign over many links: a ground plane that is the
// room's floor inside and sunlit outside brings its outside mean into the room through every
// ceiling element's link to it. Each such link may carry far less than epsilon, but their
// errors add up (the classroom's daylight factor came out 1.9x Radiance's). So a link that is
// close (close_pair) or partly visible is also split at its source while (B_max - B_min) x G_u
// exceeds `spread` (W, the configured fraction of epsilon's power): its hidden or far parts
// then become links of their own, each with its own mean. Sources of even radiosity are never
// split by this, whatever their size.
#pragma once
#include <cstdint>
#include <functional>
#include <vector>

#include "pipeline/core/link.h"
#include "pipeline/hierarchy/hierarchy.h"
#include "pipeline/geometry/visibility.h"

namespace hirad {

// Links that carry little (clusters that receive only): the geometric rules that split
// close clusters and clusters of several directions give way for a link whose power bound
// (B_max(S) times a bound on G that needs no estimate), times the share of it they guard, is
// at most kSlight x epsilon. A fraction, not epsilon itself: the furnace of tests/cpp/
// cluster_receivers_test.cpp (a 0.3 m box of 3.75 cm faces in a 10 m room, epsilon 1e-5 of
// the emitted power; every link to a face of the box carries less than epsilon) came out
// -9 to +13 % on the box's faces with 1 and -16 to +16 % with 0.1, within 1 % with 0.03 and
// 0.01.
constexpr double kSlight = 0.01;

struct RefineOptions {
    double epsilon = 1e-3;     // W: the largest power a link may carry before it is split
    double min_area = 1e-4;    // m^2: elements are not split below this
    int samples = 16;          // point pairs per link estimate
    uint64_t seed = 1;
    double relative = 0;       // also split a link above this fraction of its receiver's light (0: off)
    double spread = 0;         // W: close or partly visible links of uneven sources split above this (0: off)
    bool cluster_receivers = false;  // clusters may receive (see above)
    // The cheap form for far pairs. An estimate with a polygon at one end integrates
    // F(x -> polygon) over points x of the other end; Lambert's contour sum gives F exactly and
    // Arvo's sampling draws the visibility ray's end by it, about ten transcendental calls a
    // sample (two thirds of the Cornell box's refinement time). Where the polygon's diagonal is
    // at most `far` times the gap between the two ends' boxes, every point of it is between d
    // and (1 + far) d from every x, so cos cos / (pi r^2) varies across it by a bounded factor
    // and the point-to-point kernel between stratified points of both ends (y uniform by area)
    // estimates G without bias and with little spread, at a few multiplications a sample
    // (RefinerEstimate tests in tests/cpp). 0: the exact form everywhere.
    double far = 1.0;
};

struct RefineStats {
    uint64_t evaluated = 0;    // link estimates computed
    uint64_t split = 0;        // links replaced by their children's links
    uint64_t rays = 0;
};

class Refiner {
public:
    Refiner(Hierarchy& hierarchy, const Visibility& visibility, const RefineOptions& options);

    // Links from scratch, starting at the root's self-link, judged with node radiosity
    // `radiosity` (per node; emission alone on the first round).
    std::vector<Link> initial_links(const std::vector<RGB>& radiosity, RefineStats& stats);

    // Checks every link against the current radiosity; splits those that carry too much.
    // Returns the new link set; `stats.split` counts the links that were split.
    std::vector<Link> refine(const std::vector<Link>& links, const std::vector<RGB>& radiosity, RefineStats& stats);

    // For refinement in pieces (one source group at a time, see outofcore.h): set the
    // radiosity the oracle judges by, then refine each piece's links. New nodes inherit
    // their parent's bound. `solved`: the radiosity is a round's solution (not the emission
    // alone), which the relative rule needs.
    void set_radiosity(const std::vector<RGB>& radiosity, bool solved = false);
    // Lets go of what set_radiosity made (three doubles a node: 24 bytes, about 120 MB on a
    // 2.5M-face floor), which only refinement reads: a round's solve runs without it, and the
    // next refinement makes it again.
    void release();
    std::vector<Link> run_group(std::vector<Link> frontier, std::vector<uint8_t> evaluated, RefineStats& stats);
    // The same within bounded memory: the links waiting to be judged are taken `batch` at a
    // time, depth first, and the kept ones are handed to `keep` as soon as `batch` of them are
    // there (exactly `batch` each time, the last time fewer), in an order that depends only
    // on the input. Returns the most links held at once (waiting and kept).
    uint64_t run_group(std::vector<Link> frontier, std::vector<uint8_t> evaluated, RefineStats& stats, size_t batch,
                       const std::function<void(std::vector<Link>&)>& keep);

    // The estimate for one pair (exposed for tests). Different `stream`s draw independent
    // samples.
    Link estimate(uint32_t receiver, uint32_t source, uint64_t stream = 0) const;

private:
    enum class Action : uint8_t { Keep, Drop, SplitReceiver, SplitSource, SplitSelf };
    Action decide(const Link& link, const std::vector<double>& peak) const;
    double link_error(const Link& link, const std::vector<double>& peak) const;
    bool must_split_clusters(uint32_t a, uint32_t b) const;
    bool estimable(const Link& link) const;  // a pair that may be kept, so worth an estimate
    bool misdirected(const Link& link) const;   // a cluster receiver that does not face the source
    double power_bound(const Link& link) const;  // the most it can carry, by a bound that needs no estimate
    bool slight(const Link& link) const;         // power_bound within kSlight x epsilon
    bool may_face(uint32_t a, uint32_t b) const;
    bool close_pair(uint32_t a, uint32_t b) const;
    Hierarchy& h_;
    std::vector<double> peak_;   // per node: the brightest luminance below it
    std::vector<double> trough_; // per node: the darkest luminance below it
    std::vector<double> gathered_;  // per node: luminance(B) / luminance(rho), the relative rule's
                                    // H_R (empty: rule off; infinite: black receivers)
    const Visibility& vis_;
    RefineOptions opt_;
};

}  // namespace hirad
