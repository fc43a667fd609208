// The link of hierarchical radiosity: the one record the refinement makes, the solvers and
// the gather read, and the link store (formats/linkstore.h) writes to disk as it is.
//
// A link carries light from a source node to a receiver node: H_receiver += G / A_receiver *
// B_source. Plain data, no pointers: nodes are indices into the hierarchy's node array.
//
// The oracle decides on one estimate (unoccluded, visibility) and the link transports another,
// independent one (coupling): deciding and keeping on the same noisy number would keep the
// links whose estimate came out low and split those that came out high, a bias towards dark.
#pragma once
#include <cstdint>
#include <type_traits>

namespace hirad {

struct Link {
    uint32_t receiver = 0;
    uint32_t source = 0;
    float coupling = 0;       // G: m^2; F_receiver,source = G / A_receiver; finite, >= 0
    float unoccluded = 0;     // G without visibility (the oracle's estimate); finite, >= 0
    float visibility = 0;     // mean of what the oracle estimate's rays carried, in [0, 1]: the
                              // fraction that arrived, a ray through glass counting its T
    float error = 0;          // the oracle's bound on the power the link carries when it was
                              // last checked (B_max(source) x G, unoccluded G if partly visible), W
};
static_assert(sizeof(Link) == 24, "Link must be 24 bytes without padding");
static_assert(std::is_trivially_copyable_v<Link>, "Link must be memcpy-able (the store reads and writes it in place)");

}  // namespace hirad
