#include "pipeline/hierarchy/gather.h"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>

#include "pipeline/core/colour.h"
#include "pipeline/geometry/formfactors.h"

namespace hirad {

namespace {

// Redraws of a source point that fell below the receiving point's horizon.
constexpr int kHorizonRedraws = 8;

// Whether a source emits light of its own (not only its luminaires' share rho x direct): its
// links are traced from every point, 4 x 4 rays (element_transfer).
bool emits(const RGB& emission, const RGB& reflectance, const RGB& direct) {
    return luminance(emission - mul(reflectance, direct)) > 0;  // Patch::self_emission
}
bool emits(const Patch& s) { return emits(s.emission, s.reflectance, s.direct); }

// The part of the polygon strictly above the plane through x with normal n (as the form
// factor clips it, so that n . w1 = pi F to rounding).
int clip_to_hemisphere(const Vec3& x, const Vec3& n, const Vec3* in, int count, Vec3* out) {
    int m = 0;
    for (int k = 0; k < count; ++k) {
        const Vec3& a = in[k];
        const Vec3& b = in[(k + 1) % count];
        const double da = dot(a - x, n), db = dot(b - x, n);
        if (da > 0) out[m++] = a;
        if ((da > 0) != (db > 0)) out[m++] = a + (b - a) * (da / (da - db));
    }
    return m;
}

// The distance from x to the box [lo, hi] (0 inside it).
double box_gap(const Vec3& lo, const Vec3& hi, const Vec3& x) {
    double gap2 = 0;
    for (int k = 0; k < 3; ++k) {
        const double d = std::max({0.0, lo[k] - x[k], x[k] - hi[k]});
        gap2 += d * d;
    }
    return std::sqrt(gap2);
}

// b Omega / pi and b W / pi added to the moments: the radiance L = b / pi over the solid angle.
void add_moments(RadianceMoments& mo, const RGB& b, const SolidAngleMoments& g) {
    const RGB radiance = b / kPi;
    mo.l0 += radiance * g.omega;
    for (int a = 0; a < 3; ++a) mo.l1[a] += radiance * g.w1[a];
}

}  // namespace

SolidAngleMoments polygon_solid_angle_moments(const Vec3& x, const Vec3& n, const Vec3* poly, int nv,
                                              const Vec3& poly_normal) {
    SolidAngleMoments out;
    if (dot(x - poly[0], poly_normal) <= 0) return out;  // behind the emitting side
    Vec3 clipped[8];
    const int m = clip_to_hemisphere(x, n, poly, nv, clipped);
    if (m < 3) return out;
    Vec3 dir[8];
    for (int k = 0; k < m; ++k) {
        const double l = length(clipped[k] - x);
        if (!(l > 0)) return out;  // x on a corner: no direction (the form factor is 0 there too)
        dir[k] = (clipped[k] - x) / l;
    }
    // Solid angle: the clipped polygon is convex (a convex patch cut by a plane), so its fan
    // from corner 0 covers it once; each spherical triangle by Van Oosterom and Strackee.
    for (int k = 1; k + 1 < m; ++k) {
        const Vec3 &a = dir[0], &b = dir[k], &c = dir[k + 1];
        const double num = std::abs(dot(a, cross(b, c)));
        const double den = 1 + dot(a, b) + dot(b, c) + dot(c, a);
        out.omega += 2 * std::atan2(num, den);
    }
    // First moment: Stokes' theorem on the sphere, 1/2 sum gamma_k u_k over the edges.
    Vec3 v;
    for (int k = 0; k < m; ++k) {
        const Vec3 a = clipped[k] - x, b = clipped[(k + 1) % m] - x;
        const Vec3 c = cross(a, b);
        const double lc = length(c);
        if (lc <= 0) continue;
        v += c * (std::atan2(lc, dot(a, b)) / lc);
    }
    out.w1 = v * (dot(n, v) >= 0 ? 0.5 : -0.5);
    return out;
}

GatherLinks::GatherLinks(const std::vector<Link>& sorted, size_t nodes) {
    first.assign(nodes + 1, 0);
    links.resize(sorted.size());
    for (size_t k = 0; k < sorted.size(); ++k) {
        const Link& l = sorted[k];
        if (l.receiver >= nodes || l.source >= nodes) throw std::invalid_argument("gather: a link's node is out of range");
        if (k > 0 && l.receiver < sorted[k - 1].receiver)
            throw std::invalid_argument("gather: links must be sorted by receiver");
        ++first[l.receiver + 1];
        links[k] = GatherLink{l.source, l.coupling, l.visibility};
    }
    for (size_t i = 0; i < nodes; ++i) first[i + 1] += first[i];
}

Gatherer::Gatherer(const Hierarchy& hierarchy, const std::vector<Link>& links, const std::vector<RGB>& radiosity,
                   const Visibility& visibility, const GatherOptions& options)
    : h_(hierarchy), own_(std::make_unique<GatherLinks>(links, hierarchy.nodes.size())), table_(*own_),
      links_(table_.links), first_link_(table_.first), radiosity_(radiosity), vis_(visibility), opt_(options) {
    build_steps();
}

Gatherer::Gatherer(const Hierarchy& hierarchy, const GatherLinks& links, const std::vector<RGB>& radiosity,
                   const Visibility& visibility, const GatherOptions& options)
    : h_(hierarchy), table_(links), links_(table_.links), first_link_(table_.first), radiosity_(radiosity),
      vis_(visibility), opt_(options) {
    if (table_.first.size() != h_.nodes.size() + 1)
        throw std::invalid_argument("gather: the links' table is not this hierarchy's");
    build_steps();
}

void Gatherer::build_steps() {
    const size_t n = h_.nodes.size();
    steps_.resize(n);
    for (size_t i = 0; i < n; ++i) {
        const Node& node = h_.nodes[i];
        steps_[i] = DescentStep{node.first_child, node.child_count, static_cast<uint8_t>(h_.nv(uint32_t(i)))};
    }
}

double Gatherer::mean_coupling(const GatherLink& l, uint32_t receiver, uint32_t leaf) const {
    // G / A_R over an element receiver; over a receiving cluster, what the leaf's face takes
    // of it by its orientation (Hierarchy::reception).
    if (h_.slot_of(receiver) == kNoNode) return double(l.coupling) / h_.nodes[receiver].area;
    return double(l.coupling) * std::max(0.0, h_.reception(receiver, l.source).along(h_.normal(leaf)));
}

bool Gatherer::varies(const GatherLink& l, uint32_t leaf) const {
    const Node& me = h_.nodes[leaf];
    const Node& s = h_.nodes[l.source];
    if (!s.cluster && luminance(h_.emission(l.source)) > 0) return true;
    double gap2 = 0;
    for (int a = 0; a < 3; ++a) {
        const double d = std::max({0.0, s.lo[a] - me.hi[a], me.lo[a] - s.hi[a]});
        gap2 += d * d;
    }
    return std::sqrt(gap2) < std::max(me.diagonal(), s.diagonal());
}

Gatherer::Split Gatherer::split(uint32_t leaf) const {
    struct Candidate {
        double share;
        uint64_t link;
        uint32_t receiver;
    };
    std::vector<Candidate> weak;
    Split out;
    double total = 0;
    for (uint32_t i = leaf; i != kNoNode; i = h_.nodes[i].parent)
        for (uint64_t k = first_link_[i]; k < first_link_[i + 1]; ++k) {
            const GatherLink& l = links_[k];
            const double share = std::max(0.0, luminance(radiosity_[l.source])) * mean_coupling(l, i, leaf);
            total += share;
            if (varies(l, leaf)) out.links.push_back(k);
            else weak.push_back({share, k, i});
        }
    // The weakest first into the rest while it stays within the allowance; ties by link order.
    std::sort(weak.begin(), weak.end(),
              [](const Candidate& a, const Candidate& b) { return a.share != b.share ? a.share < b.share : a.link < b.link; });
    double rest = 0;
    size_t taken = 0;
    for (; taken < weak.size() && rest + weak[taken].share <= opt_.importance * total; ++taken) {
        rest += weak[taken].share;
        const GatherLink& l = links_[weak[taken].link];
        out.rest += radiosity_[l.source] * mean_coupling(l, weak[taken].receiver, leaf);
    }
    for (size_t k = taken; k < weak.size(); ++k) out.links.push_back(weak[k].link);
    std::sort(out.links.begin(), out.links.end());  // chain order: the samples drawn do not depend on the ranking
    return out;
}

RGB Gatherer::element_transfer(const GatherLink& link, const Vec3& x, const Vec3& n, Rng& rng, RadianceMoments* mo,
                               int depth) const {
    // F(x -> S) exactly, times the mean of V(x, y) B(y) over stratified points y of S, B(y)
    // from the leaf below S that holds y: where S is partly hidden from x and its radiosity
    // uneven (the floor under a block), the mean B_S times the visible fraction would count
    // the hidden dark part twice.
    const Node& node = h_.nodes[link.source];
    if (!node.leaf() && !node.cluster) {
        // x close to S compared with its size: the kernel is far from uniform over S, and
        // the radiosity under it may vary (a floor at the foot of a wall). Gather from S's
        // children, each with its own exact form factor and radiosity.
        if (box_gap(node.lo, node.hi, x) < node.diagonal()) {
            RGB sum;
            for (uint32_t c = 0; c < node.child_count; ++c) {
                GatherLink child = link;
                child.source = node.first_child + c;
                sum += element_transfer(child, x, n, rng, mo, depth);
            }
            return sum;
        }
    }
    // A close leaf: its radiosity gathered again in cells (GatherOptions::second_bounce).
    if (depth == 0 && opt_.second_bounce > 0 && node.leaf() &&
        box_gap(node.lo, node.hi, x) < opt_.second_bounce * node.diagonal())
        return cell_transfer(link, link.source, h_.shape(link.source), 0, 0, x, n, rng, mo);
    Patch scratch;
    const Patch& s = h_.shape(link.source, scratch);
    // Self-emitting sources exactly (the direct light); others far from x compared with their
    // size by quadrature (formfactors.h: within about 1e-3, at a fraction of the cost).
    const bool emitter = emits(s);
    const bool quadrature = !emitter && node.diagonal() <= kQuadratureFar * box_gap(node.lo, node.hi, x);
    const double f = quadrature ? point_polygon_form_factor_by_quadrature(x, n, s.p.data(), s.nv, s.normal, s.area)
                                : point_polygon_form_factor(x, n, s.p.data(), s.nv, s.normal);
    if (f <= 0) return {};
    // A link all of whose estimate rays arrived is taken as unoccluded: refinement already
    // split the links whose visibility varies and that carry enough power to matter. Not an
    // emitter's: its estimate's few point pairs are spread over the whole receiver and miss a
    // shadow that covers a small part of it (a floor point 1 mm inside the Cornell box's short
    // block's umbra read +32 % with the emitter unoccluded), and the direct light's shadows are
    // the sharpest, so an emitter's link is traced from the point whatever its estimate saw.
    // The second bounce's own gather (depth 1) traces only emitters' links, whose shadows are
    // what changes within a millimetre of a contact; other partly visible links carry their
    // estimate's visible fraction there.
    const bool trace = emitter || (link.visibility < 1.0f && depth == 0);
    const double seen_share = trace ? 1.0 : double(link.visibility);
    SolidAngleMoments geo;
    if (mo) {
        geo = polygon_solid_angle_moments(x, n, s.p.data(), s.nv, s.normal);
        // n . w1 = pi F exactly; with F by quadrature the moments are scaled to it (by 1 within
        // about 1e-3), so that a directional gather's n . l1 is its irradiance and that
        // irradiance the same bits as without directions.
        const double nw = dot(n, geo.w1);
        if (quadrature && nw > 0) {
            const double k = kPi * f / nw;
            geo.omega *= k;
            geo.w1 = geo.w1 * k;
        }
    }
    if (!trace && node.leaf()) {
        if (mo) add_moments(*mo, radiosity_[link.source], geo);
        return radiosity_[link.source] * (f * seen_share);
    }
    // The mean of V(x, y) B(y) over the part of S above x's tangent plane, the part F counts:
    // a point of S below the horizon reaches x from under its own surface (a floor element
    // that runs on under the block whose side x is on) and would count as blocked, biasing E
    // low by the hidden share of S (-5 to -11 % at the foot of the Cornell box's blocks).
    // Stratified points, each one below the horizon redrawn uniformly over S (rejection:
    // uniform over the clipped part).
    // (The second bounce's own gather, depth 1, traces one ray: its samples are averaged.)
    // An emitter's link takes 4 x 4 rays whatever `rays` says: the direct light's penumbrae are
    // the sharpest light there is, and 2 x 2 rays left a vertex in the Cornell box's penumbra
    // 15 % off where 4 x 4 left 4 % (tests/python/outputs/test_vertex_gather.py).
    const int g = depth > 0 ? 1
                            : emitter ? 4
                                      : std::max(1, std::min(4, static_cast<int>(std::lround(std::sqrt(double(opt_.rays))))));
    const int m = g * g;
    const double lift = vis_.ray_offset();
    Vec3 from[16], to[16];
    RGB b[16];
    float seen[16];  // what each ray carries: 1, 0 blocked, T through glass (visibility.h)
    int used = 0;
    for (int k = 0; k < m; ++k) {
        double s0 = (k % g + rng.uniform()) / g, t0 = (k / g + rng.uniform()) / g;
        Vec3 y = s.point(s0, t0);
        for (int r = 0; r < kHorizonRedraws && dot(y - x, n) <= 0; ++r) {
            s0 = rng.uniform();
            t0 = rng.uniform();
            y = s.point(s0, t0);
        }
        if (dot(y - x, n) <= 0) continue;
        b[used] = radiosity_[leaf_at(link.source, s0, t0)];
        from[used] = x + n * lift;
        to[used] = y + s.normal * lift;
        seen[used] = 1.0f;
        ++used;
    }
    // Nothing drawn above the horizon: S shows x a sliver (its F is as small); its mean.
    const RGB mean = used == 0 ? radiosity_[link.source] * static_cast<double>(link.visibility) : [&] {
        if (trace) vis_.segments_transmittance(from, to, used, seen);
        RGB sum;
        for (int k = 0; k < used; ++k)
            if (seen[k] > 0) sum += b[k] * double(seen[k]);
        return sum / used;
    }();
    if (mo) add_moments(*mo, mean, geo);
    return mean * (f * (used == 0 ? 1.0 : seen_share));  // (with none drawn, mean has the visibility)
}

RGB Gatherer::cell_difference(uint32_t source, const Vec3& y, bool near, uint64_t code) const {
    RGB h_y, mean_h;
    Rng rng(hash_pair(h_.key(source), code, opt_.seed ^ 0x5EC0Dull));
    const Vec3 n = h_.normal(source);
    for (uint32_t i = source; i != kNoNode; i = h_.nodes[i].parent)
        for (uint64_t k = first_link_[i]; k < first_link_[i + 1]; ++k) {
            const GatherLink& l = links_[k];
            if (h_.nodes[l.source].cluster || varies(l, source) != near) continue;
            mean_h += radiosity_[l.source] * mean_coupling(l, i, source);
            h_y += element_transfer(l, y, n, rng, nullptr, 1);
        }
    return h_y - mean_h;
}

RGB Gatherer::cell_radiosity(uint32_t source, const Patch& cell, uint64_t code) const {
    const uint64_t key = uint64_t(source) << 16 | code;  // code: the path (2 bits a level), then the depth
    {
        CellCache::const_accessor hit;
        if (cells_.find(hit, key)) return hit->second;
    }
    // Each cell is gathered once, by the thread that inserts its key, holding the key's write
    // lock (a thread asking for it meanwhile waits for the value): two threads gathering the
    // same cell would give the same bits but count its rays twice, and the report's ray count
    // would depend on the threads' timing. No lock is held while another is taken: the
    // leaf's far part is read before the cell's lock, and gathering asks the cache for
    // nothing (element_transfer at depth 1 gathers no cells).
    // B(y) = B_S + rho_S (H(y) - H_S) at the cell's centre y: H(y) from the leaf's chain at y,
    // its sources at their leaves' radiosity; H_S the leaf's irradiance in the solution, the
    // same links at their mean coupling. Seeded by the leaf's key and the cell: whichever
    // point asks first, the same bits.
    // A cluster source is taken at its mean at y as well: it adds nothing to the difference.
    // The element sources whose light varies across the leaf (varies(): emitters, sources
    // close to it) are gathered at y. The others are far from the leaf compared with its size
    // and theirs does not vary across it; what they bring the leaf can still differ from the
    // mean over the ancestor whose link carries it (a leaf under a cabinet whose ancestor
    // spans the open floor), so they are gathered once, at the leaf's centre, and that
    // difference is shared by all its cells. Gathering every link at every cell was most of
    // the country kitchen's lightmap time.
    Patch scratch;
    const Patch& s = h_.shape(source, scratch);
    RGB far;
    {
        const uint64_t leaf_key = uint64_t(source) << 16 | kLeafCode;
        CellCache::const_accessor hit;
        if (cells_.find(hit, leaf_key)) {
            far = hit->second;
        } else {  // (a failed find holds no lock)
            CellCache::accessor slot;
            if (cells_.insert(slot, leaf_key)) slot->second = cell_difference(source, s.centroid, false, kLeafCode);
            far = slot->second;
        }
    }
    Vec3 centre;
    for (int k = 0; k < cell.nv; ++k) centre += cell.p[k];
    centre = centre / double(cell.nv);
    CellCache::accessor slot;
    if (cells_.insert(slot, key))
        slot->second = radiosity_[source] + mul(s.reflectance, far + cell_difference(source, centre, true, code));
    return slot->second;
}

RGB Gatherer::cell_transfer(const GatherLink& link, uint32_t source, const Patch& cell, uint64_t code, int depth,
                            const Vec3& x, const Vec3& n, Rng& rng, RadianceMoments* mo) const {
    // Cells near x compared with their size are cut in four again (split_in_four), down to
    // kCellDepth levels below the leaf: the kernel from x sits on the cells next to it.
    Vec3 lo = cell.p[0], hi = cell.p[0];
    for (int k = 1; k < cell.nv; ++k)
        for (int a = 0; a < 3; ++a) {
            lo[a] = std::min(lo[a], cell.p[k][a]);
            hi[a] = std::max(hi[a], cell.p[k][a]);
        }
    if (depth < kCellDepth && box_gap(lo, hi, x) < opt_.second_bounce * length(hi - lo)) {
        Patch kids[4];
        split_in_four(cell, kids);
        RGB sum;
        for (int c = 0; c < 4; ++c)
            sum += cell_transfer(link, source, kids[c], code | (uint64_t(c) << (2 * depth)), depth + 1, x, n, rng, mo);
        return sum;
    }
    const double f = point_polygon_form_factor(x, n, cell.p.data(), cell.nv, cell.normal);
    if (f <= 0) return {};
    const RGB b = cell_radiosity(source, cell, code | uint64_t(depth) << (2 * kCellDepth));
    // One ray to the cell, above x's horizon, where the link's estimate saw a shadow or the
    // source emits (element_transfer: an emitter's estimate can miss a small shadow).
    if (link.visibility < 1.0f || emits(h_.emission(source), h_.reflectance(source), h_.direct(source))) {
        Vec3 y = cell.point(rng.uniform(), rng.uniform());
        for (int r = 0; r < kHorizonRedraws && dot(y - x, n) <= 0; ++r) y = cell.point(rng.uniform(), rng.uniform());
        const double lift = vis_.ray_offset();
        const Vec3 from = x + n * lift, to = y + cell.normal * lift;
        float seen = 0;
        vis_.segments_transmittance(&from, &to, 1, &seen);
        if (!(seen > 0)) return {};
        const RGB carried = b * double(seen);
        if (mo) add_moments(*mo, carried, polygon_solid_angle_moments(x, n, cell.p.data(), cell.nv, cell.normal));
        return carried * f;
    }
    if (mo) add_moments(*mo, b, polygon_solid_angle_moments(x, n, cell.p.data(), cell.nv, cell.normal));
    return b * f;
}

RGB Gatherer::cluster_transfer(const GatherLink& link, const Vec3& x, const Vec3& n, Rng& rng, RadianceMoments* mo) const {
    // Faces drawn with probability A_f / A_S (stratified), each seen through its exact
    // form factor, with the radiosity of the leaf at a point y drawn on it and the visibility
    // of y: sum_f F(x -> f) B_f ~ E[F(x -> f) B(y) V(x, y) A_S / A_f]. The cluster's mean
    // radiosity would mix in surfaces that face away from x (the undersides of furniture,
    // say) and bias the gather dark.
    const Node& c = h_.nodes[link.source];
    const int m = std::max(1, std::min(16, opt_.cluster_samples));
    const double lo = h_.area_prefix[c.face_begin], hi = h_.area_prefix[c.face_end];
    const double lift = vis_.ray_offset();
    Vec3 from[16], to[16];
    RGB f[16], wb[16];
    SolidAngleMoments geo[16];
    int used = 0;
    RGB sum;
    for (int k = 0; k < m; ++k) {
        const double target = lo + (k + rng.uniform()) / m * (hi - lo);
        auto it = std::upper_bound(h_.area_prefix.begin() + c.face_begin + 1, h_.area_prefix.begin() + c.face_end + 1, target);
        uint32_t j = static_cast<uint32_t>(it - h_.area_prefix.begin()) - 1;
        j = std::min(std::max(j, c.face_begin), c.face_end - 1);
        const uint32_t face_index = h_.face_order[j];
        const Patch& face = h_.faces[face_index];
        const double fk = point_polygon_form_factor(x, n, face.p.data(), face.nv, face.normal);
        double s0 = rng.uniform(), t0 = rng.uniform();
        if (fk <= 0 || face.area <= 0) continue;
        // y above x's horizon, where F(x -> f) counts the face (as for element sources)
        Vec3 y = face.point(s0, t0);
        for (int r = 0; r < kHorizonRedraws && dot(y - x, n) <= 0; ++r) {
            s0 = rng.uniform();
            t0 = rng.uniform();
            y = face.point(s0, t0);
        }
        f[used] = radiosity_[leaf_at(h_.face_node[face_index], s0, t0)] * (fk * c.area / face.area);
        if (mo) {  // the face's moments with the same weight B A_S / (A_f m) as its irradiance
            wb[used] = radiosity_[leaf_at(h_.face_node[face_index], s0, t0)] * (c.area / face.area / m);
            geo[used] = polygon_solid_angle_moments(x, n, face.p.data(), face.nv, face.normal);
        }
        from[used] = x + n * lift;
        to[used] = y + face.normal * lift;
        ++used;
    }
    if (used == 0) return sum;
    float seen[16];
    vis_.segments_transmittance(from, to, used, seen);
    for (int k = 0; k < used; ++k)
        if (seen[k] > 0) sum += f[k] * double(seen[k]);
    if (mo)
        for (int k = 0; k < used; ++k)
            if (seen[k] > 0) add_moments(*mo, wb[k] * double(seen[k]), geo[k]);
    return sum / m;
}

RGB Gatherer::at(uint32_t leaf, const Vec3& x_in, uint64_t key, RadianceMoments* mo, const Split* sp) const {
    Patch scratch;
    const Patch& shape = h_.shape(leaf, scratch);
    const Vec3 n = shape.normal;
    // On the leaf's plane, whatever small offset the query point had.
    const Vec3 x = x_in - n * dot(x_in - shape.p[0], n);
    Rng rng(hash_pair(leaf, key, opt_.seed ^ 0x6A7Eull));
    if (!sp) return chain(leaf, x, n, rng, mo);
    RGB h = sp->rest;
    for (uint64_t k : sp->links) {
        const GatherLink& l = links_[k];
        h += h_.nodes[l.source].cluster ? cluster_transfer(l, x, n, rng, mo) : element_transfer(l, x, n, rng, mo);
    }
    return h;
}

RGB Gatherer::chain(uint32_t leaf, const Vec3& x, const Vec3& n, Rng& rng, RadianceMoments* mo) const {
    RGB h;
    for (uint32_t i = leaf; i != kNoNode; i = h_.nodes[i].parent)
        for (uint64_t k = first_link_[i]; k < first_link_[i + 1]; ++k) {
            const GatherLink& l = links_[k];
            h += h_.nodes[l.source].cluster ? cluster_transfer(l, x, n, rng, mo) : element_transfer(l, x, n, rng, mo);
        }
    return h;
}

void Gatherer::irradiance(const uint32_t* leaf, const Vec3* x, const uint64_t* key, size_t count, RGB* out,
                          RadianceMoments* moments) const {
    for (size_t k = 0; k < count; ++k)
        if (leaf[k] >= h_.nodes.size() || h_.nodes[leaf[k]].cluster)
            throw std::invalid_argument("gather: a query point's element is not an element of the hierarchy");
    const bool split_links = opt_.importance > 0 && !moments;
    // The points in leaf order, kSplitBlock leaves at a time. Per leaf queried its split
    // (GatherOptions::importance), made once, the block's splits let go before the next (a
    // split holds the indices of most of its chain's links); and the cell cache emptied between
    // blocks once it holds kCellCacheMost cells (a lightmap page of the 1M-triangle kitchen
    // filled it with millions). A point's value depends on its leaf, its key and the cells'
    // values, which depend on their keys alone: not on the blocks, the cache or the threads.
    std::vector<uint32_t> order(count);
    for (size_t k = 0; k < count; ++k) order[k] = uint32_t(k);
    std::stable_sort(order.begin(), order.end(), [&](uint32_t a, uint32_t b) { return leaf[a] < leaf[b]; });
    std::vector<size_t> first_of;  // per unique leaf, its first place in `order`
    for (size_t k = 0; k < count; ++k)
        if (k == 0 || leaf[order[k]] != leaf[order[k - 1]]) first_of.push_back(k);
    first_of.push_back(count);
    const size_t unique = first_of.size() - 1;
    std::vector<Split> splits;
    for (size_t u0 = 0; u0 < unique; u0 += kSplitBlock) {
        const size_t u1 = std::min(unique, u0 + kSplitBlock);
        if (split_links) {
            splits.assign(u1 - u0, Split{});
            tbb::parallel_for(u0, u1, [&](size_t u) { splits[u - u0] = split(leaf[order[first_of[u]]]); });
        }
        tbb::parallel_for(first_of[u0], first_of[u1], [&](size_t j) {
            const uint32_t k = order[j];
            if (moments) moments[k] = RadianceMoments{};
            const Split* sp = nullptr;
            if (split_links) {
                const auto at_u = std::upper_bound(first_of.begin() + u0, first_of.begin() + u1, j);
                sp = &splits[size_t(at_u - first_of.begin()) - 1 - u0];
            }
            out[k] = at(leaf[k], x[k], key[k], moments ? moments + k : nullptr, sp);
        });
        if (cells_.size() > kCellCacheMost) cells_.clear();
    }
}

void Gatherer::radiance(const uint32_t* leaf, const Vec3* x, const uint64_t* key, size_t count, RGB* out) const {
    irradiance(leaf, x, key, count, out);
    for (size_t k = 0; k < count; ++k) {
        out[k] = (h_.emission(leaf[k]) + mul(h_.reflectance(leaf[k]), out[k])) / kPi;
    }
}

void gather_flat(const std::vector<Patch>& patches, const std::vector<RGB>& radiosity, const Visibility& vis,
                 const Vec3* x, const Vec3* n, size_t count, int rays, uint64_t seed, RGB* out) {
    const int g = std::max(1, std::min(4, static_cast<int>(std::lround(std::sqrt(double(rays))))));
    const int m = g * g;
    const double lift = vis.ray_offset();
    tbb::parallel_for(size_t(0), count, [&](size_t q) {
        Rng rng(hash_pair(q, 0xF1A7ull, seed));
        RGB h;
        Vec3 from[16], to[16];
        uint8_t seen[16];
        for (size_t j = 0; j < patches.size(); ++j) {
            const Patch& s = patches[j];
            // The point's own patch and its coplanar neighbours send nothing (rounding would
            // put x a hair in front of them and count their whole hemisphere).
            if (dot(x[q] - s.p[0], s.normal) <= 1e-9 * vis.scene_size()) continue;
            const double f = point_polygon_form_factor(x[q], n[q], s.p.data(), s.nv, s.normal);
            if (f <= 0) continue;
            for (int k = 0; k < m; ++k) {
                from[k] = x[q] + n[q] * lift;
                to[k] = s.point((k % g + rng.uniform()) / g, (k / g + rng.uniform()) / g) + s.normal * lift;
            }
            vis.segments_visible(from, to, m, seen);
            int arrived = 0;
            for (int k = 0; k < m; ++k) arrived += seen[k];
            h += radiosity[j] * (f * arrived / m);
        }
        out[q] = h;
    });
}

}  // namespace hirad
