#include "pipeline/hierarchy/hierarchy.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <numeric>
#include <stdexcept>
#include <string>

#include <tbb/parallel_for.h>

#include "pipeline/geometry/visibility.h"

namespace hirad {

namespace {

// Faces and elements are finished with the mean of their corners as the centroid: the cluster
// tree is built from median splits of the faces' centroids.
void finish_shape(Patch& p) { finish_patch(p, PatchCentroid::CornerMean); }

void bound_shape(Node& node, const Patch& shape) {
    node.lo = {1e300, 1e300, 1e300};
    node.hi = {-1e300, -1e300, -1e300};
    for (int k = 0; k < shape.nv; ++k)
        for (int a = 0; a < 3; ++a) {
            node.lo[a] = std::min(node.lo[a], shape.p[k][a]);
            node.hi[a] = std::max(node.hi[a], shape.p[k][a]);
        }
}

// Midpoints are computed as (a + b) / 2, which is symmetric in a and b: the two faces of a
// shared edge produce the same bits and their vertices weld.
Vec3 mid(const Vec3& a, const Vec3& b) { return (a + b) * 0.5; }

// The sizes of the ranges a cluster of m faces is cut into (Hierarchy's constructor). The
// faces are taken in buckets of kClusterFaces (the last may hold fewer, and stays last): a
// range of one bucket has its faces as children; a larger one is cut in halves of whole
// buckets, and each half of more than one bucket in halves again, so that all but the last
// cluster above the faces hold kClusterFaces of them.
struct ClusterCut {
    int parts = 0;                        // children
    int lower = 0;                        // of them in the lower half (0: the faces themselves)
    uint32_t size[kClusterChildren] = {}; // faces in each
};

ClusterCut cluster_cut(uint32_t m) {
    const auto buckets = [](uint32_t faces) { return (faces + kClusterFaces - 1) / kClusterFaces; };
    ClusterCut c;
    if (buckets(m) <= 1) {
        for (uint32_t k = 0; k < m; ++k) c.size[c.parts++] = 1;
        return c;
    }
    const uint32_t lo = buckets(m) / 2 * kClusterFaces;
    for (uint32_t half : {lo, m - lo}) {
        if (buckets(half) < 2) {
            c.size[c.parts++] = half;
        } else {
            c.size[c.parts] = buckets(half) / 2 * kClusterFaces;
            c.size[c.parts + 1] = half - c.size[c.parts];
            c.parts += 2;
        }
        if (c.lower == 0) c.lower = c.parts;
    }
    return c;
}

// Nodes in the cluster tree over m faces (one visit a node, as building it).
size_t tree_nodes(uint32_t m) {
    if (m <= 1) return m;
    const ClusterCut c = cluster_cut(m);
    size_t count = 1;
    for (int k = 0; k < c.parts; ++k) count += tree_nodes(c.size[k]);
    return count;
}

}  // namespace

Hierarchy::Hierarchy(const Scene& scene) {
    const uint32_t ns = static_cast<uint32_t>(scene.faces.size());
    scene_faces = ns;
    std::vector<uint32_t> glazed;
    for (uint32_t f = 0; f < ns; ++f)
        if (scene.faces[f].transmittance > 0) glazed.push_back(f);
    faces.reserve(ns + glazed.size());
    // Each face's centroid, while the tree is built (the table makes it on demand).
    std::vector<Vec3> centroid;
    centroid.reserve(ns + glazed.size());
    auto add = [&](const Patch& p) {
        faces.push_back(p);
        centroid.push_back(p.centroid);
    };
    for (uint32_t f = 0; f < ns; ++f) {
        const Face& face = scene.faces[f];
        Patch p;
        p.nv = face.nv;
        for (int k = 0; k < 4; ++k) { p.p[k] = face.p[std::min(k, face.nv - 1)]; p.uv[k] = face.uv[std::min(k, face.nv - 1)]; }
        p.reflectance = face.reflectance;
        p.emission = face.emission;
        p.mesh = face.mesh;
        p.face = f;
        p.vertex = {0, 0, 0, 0};
        finish_shape(p);
        add(p);
    }
    // The backs of glazed faces: the same polygon turned over (corners reversed), reflecting as
    // the front, emitting nothing, after all the scene's faces.
    for (uint32_t f : glazed) {
        const Patch front = faces[f];
        Patch back = front;
        const int nv = back.nv;
        for (int k = 0; k < nv; ++k) {
            back.p[k] = front.p[nv - 1 - k];
            back.uv[k] = front.uv[nv - 1 - k];
        }
        if (nv == 3) { back.p[3] = back.p[2]; back.uv[3] = back.uv[2]; }
        back.emission = RGB{};
        back.back = true;
        finish_shape(back);
        add(back);
    }
    faces.seal();
    const uint32_t n = static_cast<uint32_t>(faces.size());
    face_order.resize(n);
    std::iota(face_order.begin(), face_order.end(), 0u);
    face_node.assign(n, kNoNode);
    if (n == 0) return;

    // Node 0 is the root; every split reserves all its child slots before recursing so that
    // siblings are adjacent. The nodes are reserved exactly (grown by doubling they held up to
    // twice their number: 82 MB unused on a 615k-face floor): how a range is cut depends on its
    // size alone.
    nodes.reserve(tree_nodes(n));
    // Puts the faces of face_order[begin, end) whose centroids come first along the longest
    // axis of their bounds (ties by face index) before `at`, the others after it.
    auto split_at = [&](uint32_t begin, uint32_t at, uint32_t end) {
        Vec3 clo{1e300, 1e300, 1e300}, chi{-1e300, -1e300, -1e300};
        for (uint32_t k = begin; k < end; ++k)
            for (int a = 0; a < 3; ++a) {
                clo[a] = std::min(clo[a], centroid[face_order[k]][a]);
                chi[a] = std::max(chi[a], centroid[face_order[k]][a]);
            }
        const Vec3 ext = chi - clo;
        const int axis = ext.x >= ext.y && ext.x >= ext.z ? 0 : (ext.y >= ext.z ? 1 : 2);
        std::nth_element(face_order.begin() + begin, face_order.begin() + at, face_order.begin() + end,
                         [&](uint32_t a, uint32_t b) {
                             double ca = centroid[a][axis], cb = centroid[b][axis];
                             return ca < cb || (ca == cb && a < b);
                         });
    };
    nodes.emplace_back();
    struct Task { uint32_t node, begin, end; };
    std::vector<Task> stack{{0, 0, n}};
    while (!stack.empty()) {
        Task t = stack.back();
        stack.pop_back();
        Node& node = nodes[t.node];
        node.face_begin = t.begin;
        node.face_end = t.end;
        if (t.end - t.begin == 1) {
            const uint32_t f = face_order[t.begin];
            node.element = f;  // an element root is its face
            node.area = faces.area(f);
            node.cluster = false;
            node.lo = {1e300, 1e300, 1e300};
            node.hi = {-1e300, -1e300, -1e300};
            for (int k = 0; k < faces.nv(f); ++k)
                for (int a = 0; a < 3; ++a) {
                    node.lo[a] = std::min(node.lo[a], faces.corner(f, k)[a]);
                    node.hi[a] = std::max(node.hi[a], faces.corner(f, k)[a]);
                }
            face_node[f] = t.node;
            continue;
        }
        node.cluster = true;
        // Children: up to kClusterChildren ranges (cluster_cut), each of one face (an element
        // root) or of several (a cluster).
        const ClusterCut c = cluster_cut(t.end - t.begin);
        const int parts = c.parts;
        uint32_t cut[kClusterChildren + 1];
        cut[0] = t.begin;
        for (int k = 0; k < parts; ++k) cut[k + 1] = cut[k] + c.size[k];
        // The same cuts made along the faces' centroids: the halves, then each half's halves.
        if (c.lower > 0) {
            split_at(t.begin, cut[c.lower], t.end);
            if (c.lower == 2) split_at(t.begin, cut[1], cut[2]);
            if (parts - c.lower == 2) split_at(cut[c.lower], cut[parts - 1], t.end);
        }
        const uint32_t first = static_cast<uint32_t>(nodes.size());
        nodes[t.node].first_child = first;
        nodes[t.node].child_count = static_cast<uint8_t>(parts);
        for (int k = 0; k < parts; ++k) {
            nodes.emplace_back();
            nodes.back().parent = t.node;
        }
        for (int k = parts; k-- > 0;) stack.push_back({first + uint32_t(k), cut[k], cut[k + 1]});
    }
    if (nodes.size() != nodes.capacity()) throw std::logic_error("hierarchy: cluster tree not of its counted size");
    area_prefix.assign(n + 1, 0.0);
    for (uint32_t k = 0; k < n; ++k) area_prefix[k + 1] = area_prefix[k] + faces.area(face_order[k]);
    // Cluster bounds and areas, children before parents (they have larger indices).
    for (uint32_t i = static_cast<uint32_t>(nodes.size()); i-- > 0;) {
        Node& node = nodes[i];
        if (!node.cluster) continue;
        node.area = 0;
        node.lo = {1e300, 1e300, 1e300};
        node.hi = {-1e300, -1e300, -1e300};
        for (uint32_t c = node.first_child; c < node.first_child + node.child_count; ++c) {
            const Node& a = nodes[c];
            node.area += a.area;
            for (int k = 0; k < 3; ++k) {
                node.lo[k] = std::min(node.lo[k], a.lo[k]);
                node.hi[k] = std::max(node.hi[k], a.hi[k]);
            }
        }
    }
    built_nodes = static_cast<uint32_t>(nodes.size());  // keyed by their index (key())
    root = 0;
    // The clusters' shapes for receiving (see hierarchy.h), each from its own faces.
    cluster_slot.assign(nodes.size(), kNoNode);
    std::vector<uint32_t> clusters;
    for (uint32_t i = 0; i < nodes.size(); ++i)
        if (nodes[i].cluster) {
            cluster_slot[i] = static_cast<uint32_t>(clusters.size());
            clusters.push_back(i);
        }
    cluster_shapes.resize(clusters.size());
    tbb::parallel_for(size_t(0), clusters.size(), [&](size_t k) {
        const Node& node = nodes[clusters[k]];
        ClusterShape& c = cluster_shapes[k];
        Vec3 weighted;
        for (uint32_t j = node.face_begin; j < node.face_end; ++j) {
            const uint32_t f = face_order[j];
            weighted += centroid[f] * faces.area(f);
            c.vector_area += faces.normal(f) * faces.area(f);
        }
        c.centre = node.area > 0 ? weighted / node.area : (node.lo + node.hi) * 0.5;
        for (int corner = 0; corner < 8; ++corner) {
            const Vec3 p{corner & 1 ? node.hi.x : node.lo.x, corner & 2 ? node.hi.y : node.lo.y,
                         corner & 4 ? node.hi.z : node.lo.z};
            c.radius = std::max(c.radius, length(p - c.centre));
        }
        if (!(length(c.vector_area) > 1e-12 * node.area)) return;  // faces in every direction: no cone
        const Vec3 axis = c.axis();
        c.cos_spread = 1;
        double lo = 1e300, hi = -1e300;
        for (uint32_t j = node.face_begin; j < node.face_end; ++j) {
            const uint32_t f = face_order[j];
            c.cos_spread = std::min(c.cos_spread, dot(faces.normal(f), axis));
            for (int k = 0; k < faces.nv(f); ++k) {
                lo = std::min(lo, dot(faces.corner(f, k), axis));
                hi = std::max(hi, dot(faces.corner(f, k), axis));
            }
        }
        // Layers: deeper along the axis than one surface of that spread of normals can be.
        const double sin_spread = std::sqrt(std::max(0.0, 1 - c.cos_spread * c.cos_spread));
        c.layered = hi - lo > c.radius * (sin_spread + 1e-6);
    });
    for (size_t k = 0; k < glazed.size(); ++k)
        glass.push_back({face_node[glazed[k]], face_node[ns + k]});
}

Vec3 Hierarchy::centre(uint32_t i) const {
    const uint32_t slot = slot_of(i);
    if (slot != kNoNode) return cluster_shapes[slot].centre;
    const uint32_t e = nodes[i].element;
    if (e != kNoNode && e < faces.size()) return faces.centroid(e);
    Patch scratch;
    return shape(i, scratch).centroid;
}

double Hierarchy::radius(uint32_t i) const {
    const uint32_t slot = slot_of(i);
    if (slot != kNoNode) return cluster_shapes[slot].radius;
    Patch scratch;
    const Patch& p = shape(i, scratch);
    double r = 0;
    for (int k = 0; k < p.nv; ++k) r = std::max(r, length(p.p[k] - p.centroid));
    return r;
}

Hierarchy::Facing Hierarchy::facing(uint32_t r, uint32_t s, double* direction_error) const {
    const uint32_t slot = slot_of(r);
    if (slot == kNoNode) return Facing::Mixed;
    const ClusterShape& c = cluster_shapes[slot];
    if (c.cos_spread <= 0) return Facing::Mixed;  // some faces at right angles to others, or worse
    const Vec3 axis = c.axis();
    if (c.cos_spread > kPlanarCosine) {
        // Faces of one orientation take G / A_R each whatever the direction (hierarchy.h):
        // only a source wholly behind all of them passes nothing.
        const Node& rn = nodes[r];
        const Node& sn = nodes[s];
        double r_min = 1e300, s_max = -1e300;
        for (int k = 0; k < 8; ++k) {
            const Vec3 a{k & 1 ? rn.hi.x : rn.lo.x, k & 2 ? rn.hi.y : rn.lo.y, k & 4 ? rn.hi.z : rn.lo.z};
            const Vec3 b{k & 1 ? sn.hi.x : sn.lo.x, k & 2 ? sn.hi.y : sn.lo.y, k & 4 ? sn.hi.z : sn.lo.z};
            r_min = std::min(r_min, dot(a, axis));
            s_max = std::max(s_max, dot(b, axis));
        }
        if (s_max <= r_min) return Facing::Back;
        if (direction_error) *direction_error = 0;
        return Facing::Front;
    }
    const Vec3 d = centre(s) - c.centre;
    const double dist = length(d);
    const double reach = c.radius + radius(s);
    if (!(dist > reach)) return Facing::Mixed;
    // Angles theta between the axis and d, alpha the normals' half-angle, beta the directions',
    // each by its cosine and sine, added by the addition formulas: this runs for every link to
    // a cluster, in refinement and in the solvers, and needs no inverse trigonometry.
    const double ct = std::clamp(dot(axis, d) / dist, -1.0, 1.0), st = std::sqrt(std::max(0.0, 1 - ct * ct));
    const double ca = c.cos_spread, sa = std::sqrt(std::max(0.0, 1 - ca * ca));
    const double sb = std::clamp(reach / dist, 0.0, 1.0), cb = std::sqrt(std::max(0.0, 1 - sb * sb));
    const double c1 = ct * ca - st * sa, s1 = st * ca + ct * sa;  // theta + alpha
    const double c2 = c1 * cb - s1 * sb, s2 = s1 * cb + c1 * sb;  // theta + alpha + beta, in [0, 2 pi)
    // theta + alpha + beta < acos(kFrontCosine), below 90 degrees: its cosine above
    // kFrontCosine and its sine not negative.
    if (s2 >= 0 && c2 > kFrontCosine) {
        if (direction_error) *direction_error = s1 / c1 * c.radius / dist;  // tan(theta + alpha) r_R / |d|
        return Facing::Front;
    }
    // theta - (alpha + beta) > 90 degrees: its cosine negative and its sine not.
    const double cg = ca * cb - sa * sb, sg = sa * cb + ca * sb;  // alpha + beta
    const double c3 = ct * cg + st * sg, s3 = st * cg - ct * sg;
    if (s3 >= 0 && c3 < 0) return Facing::Back;
    return Facing::Mixed;
}

Reception Hierarchy::reception(uint32_t r, uint32_t s) const {
    const ClusterShape& c = cluster_shapes[cluster_slot[r]];
    const Vec3& a = c.vector_area;
    if (c.cos_spread > kPlanarCosine) return {a / dot(a, a), 0.0};  // a / A_R: each face G / A_R
    if (facing(r, s) == Facing::Front) {
        const Vec3 u = normalize(centre(s) - c.centre);
        return {u / dot(a, u), 0.0};
    }
    return {Vec3{}, 1 / nodes[r].area};  // evenly (Mixed: kept only while it carries little)
}

double Hierarchy::misplaced(uint32_t r, uint32_t s) const {
    double direction_error = 0;
    const Facing f = facing(r, s, &direction_error);
    if (f == Facing::Back) return 0.0;
    // Faces over faces may shade each other, which no sharing knows of.
    if (f == Facing::Mixed || cluster_shapes[cluster_slot[r]].layered) return 1.0;
    return direction_error;
}

namespace {

// Room for `more` items, the capacity grown by an eighth rather than doubled: a round's few
// thousand splits of a 10M-face hierarchy would otherwise leave up to its ~2 GB of nodes
// allocated and unused for the rest of the bake (and three times them in use while it moves).
template <typename T>
void grow_by_an_eighth(std::vector<T>& v, size_t more) {
    if (v.size() + more > v.capacity()) v.reserve(v.size() + std::max(more, v.size() / 8 + 64));
}

}  // namespace

bool Hierarchy::can_subdivide(uint32_t i, double min_area) const {
    const Node& node = nodes[i];
    if (node.cluster) return true;
    return node.child_count > 0 || node.area / 4 >= min_area;
}

void Hierarchy::set_light(uint32_t node, const RGB& direct, const RGB& emission) {
    const uint32_t e = nodes[node].element;
    if (e == kNoNode) throw std::invalid_argument("set_light: node " + std::to_string(node) + " is a cluster");
    if (e < faces.size()) {
        faces.set_light(e, direct, emission);
    } else {
        pieces[e - faces.size()].direct = direct;
        pieces[e - faces.size()].emission = emission;
    }
}

void Hierarchy::subdivide(uint32_t i) {
    if (nodes[i].child_count > 0 || nodes[i].cluster) return;
    Patch kids[4];
    split_in_four(shape(i), kids);
    const uint32_t first = static_cast<uint32_t>(nodes.size());
    const uint64_t parent_key = key(i);
    grow_by_an_eighth(nodes, 4);
    grow_by_an_eighth(pieces, 4);
    grow_by_an_eighth(made_keys, 4);
    for (int k = 0; k < 4; ++k) {
        Node child;
        finish_shape(kids[k]);
        child.element = static_cast<uint32_t>(faces.size() + pieces.size());
        pieces.push_back(kids[k]);
        child.area = kids[k].area;
        child.parent = i;
        child.face_begin = nodes[i].face_begin;  // its face's place in face_order
        child.face_end = nodes[i].face_end;
        bound_shape(child, kids[k]);
        nodes.push_back(child);
        made_keys.push_back(hash_pair(parent_key, uint64_t(k) + 1, 0xC41Dull));
    }
    nodes[i].first_child = first;
    nodes[i].child_count = 4;
    subdivided.push_back(i);
}

void Hierarchy::replay(const std::vector<uint32_t>& log) {
    const size_t own = subdivided.size();
    if (own > 0 && (log.size() < own || !std::equal(subdivided.begin(), subdivided.end(), log.begin())))
        throw std::runtime_error("hierarchy log: it does not start with this hierarchy's own " + std::to_string(own) +
                                 " subdivisions (other luminaires or geometry)");
    for (size_t k = own; k < log.size(); ++k) {
        const uint32_t i = log[k];
        if (i >= nodes.size() || nodes[i].cluster || !nodes[i].leaf())
            throw std::runtime_error("hierarchy log entry " + std::to_string(k) + ": node " + std::to_string(i) +
                                     " is not a leaf element of the hierarchy");
        subdivide(i);
    }
}

void Hierarchy::sample(uint32_t i, double pick, double s, double t, Vec3& point, Vec3& normal) const {
    const Node& node = nodes[i];
    if (!node.cluster) {
        if (node.element < faces.size()) {  // a face: read from the table, not made whole
            point = faces.point(node.element, s, t);
            normal = faces.normal(node.element);
            return;
        }
        const Patch& p = pieces[node.element - faces.size()];
        point = p.point(s, t);
        normal = p.normal;
        return;
    }
    const double lo = area_prefix[node.face_begin], hi = area_prefix[node.face_end];
    const double target = lo + pick * (hi - lo);
    auto it = std::upper_bound(area_prefix.begin() + node.face_begin + 1, area_prefix.begin() + node.face_end + 1, target);
    uint32_t k = static_cast<uint32_t>(it - area_prefix.begin()) - 1;
    k = std::min(std::max(k, node.face_begin), node.face_end - 1);
    point = faces.point(face_order[k], s, t);
    normal = faces.normal(face_order[k]);
}

uint32_t Hierarchy::leaf_at(uint32_t i, double s, double t) const {
    return descend_to_leaf(
        [this](uint32_t k) {
            const Node& n = nodes[k];
            return DescentStep{n.first_child, n.child_count, static_cast<uint8_t>(nv(k))};
        },
        i, s, t);
}

std::vector<uint32_t> Hierarchy::leaves() const {
    std::vector<uint32_t> out;
    if (nodes.empty()) return out;
    std::vector<uint32_t> stack{root};
    while (!stack.empty()) {
        uint32_t i = stack.back();
        stack.pop_back();
        const Node& node = nodes[i];
        if (node.leaf()) {
            if (!node.cluster) out.push_back(i);
            continue;
        }
        for (int k = node.child_count; k-- > 0;) stack.push_back(node.first_child + k);
    }
    return out;
}

uint64_t Hierarchy::balance() {
    uint64_t split = 0;
    for (;;) {
        const std::vector<uint32_t> leaf = leaves();
        // The leaves' corners by mesh (about 40 bytes a corner: a set of string keys took about
        // 130, and on a 615k-face floor was the largest thing a bake made after its solve).
        MeshPoints corners;
        Patch scratch;
        for (uint32_t i : leaf) {
            const Patch& s = shape(i, scratch);
            for (int k = 0; k < s.nv; ++k) corners.index(s.mesh, s.p[k]);
        }
        std::vector<uint32_t> marked;
        for (uint32_t i : leaf) {
            const Patch& s = shape(i, scratch);
            for (int k = 0; k < s.nv; ++k) {
                const Vec3& a = s.p[k];
                const Vec3& b = s.p[(k + 1) % s.nv];
                const Vec3 m = mid(a, b);
                if (corners.find(s.mesh, m) < 0) continue;
                if (corners.find(s.mesh, mid(a, m)) >= 0 || corners.find(s.mesh, mid(m, b)) >= 0) {
                    marked.push_back(i);
                    break;
                }
            }
        }
        if (marked.empty()) return split;
        for (uint32_t i : marked) subdivide(i);
        split += marked.size();
    }
}

namespace {
// Where a ray of the open share or the closure leaves element `s` for its point (s0, t0): lifted
// off it by `lift` (Visibility::ray_offset) and moved as far towards its centroid (at most
// half way), so that a point drawn on an edge does not start within float precision of the
// surface meeting it there (a floor's point 1.3e-7 m from the wall standing on its edge met
// the wall at t = 0 on a ray leaving it, and the closed room's closure read 63/64).
Vec3 ray_start(const Patch& s, double s0, double t0, double lift) {
    Vec3 x = s.point(s0, t0);
    const Vec3 in = s.centroid - x;
    const double l = length(in);
    if (l > 0) x += in * (std::min(lift, 0.5 * l) / l);
    return x + s.normal * lift;
}

// The share of the cosine-weighted hemisphere above 8 x 8 stratified points of `s` that meets
// the front of a surface (Hierarchy::closure); over the whole element, points inside geometry
// (whose rays meet backs) included.
double measure_closure(const Visibility& vis, const FaceTable& faces, const Patch& s, Rng& rng,
                       double lift) {
    const Vec3 n = s.normal;
    const Vec3 a = std::fabs(n.x) < 0.6 ? Vec3{1, 0, 0} : Vec3{0, 1, 0};
    const Vec3 t = normalize(cross(n, a)), b = cross(n, t);
    constexpr int g = 8;
    // The directions' strata are the points' strata shuffled, so that neither follows the other.
    int order[g * g];
    for (int k = 0; k < g * g; ++k) order[k] = k;
    for (int k = g * g - 1; k > 0; --k) std::swap(order[k], order[std::min(k, int(rng.uniform() * (k + 1)))]);
    std::vector<RayHit> panes;
    double sum = 0;
    for (int k = 0; k < g * g; ++k) {
        const double s0 = (k % g + rng.uniform()) / g, t0 = (k / g + rng.uniform()) / g;
        const Vec3 x = ray_start(s, s0, t0, lift);
        // Malley: uniform on the disk, lifted to the hemisphere.
        const int m = order[k];
        const double r = std::sqrt((m % g + rng.uniform()) / g), phi = 2 * kPi * (m / g + rng.uniform()) / g;
        const Vec3 d = normalize(t * (r * std::cos(phi)) + b * (r * std::sin(phi)) + n * std::sqrt(std::max(0.0, 1 - r * r)));
        double pass = 1;
        const RayHit hit = vis.intersect_through_glass(x, d, 0, 1e30, &panes, &pass);
        double before = 1;
        for (const RayHit& p : panes) {  // a pane is an element on either side
            sum += before;
            before *= vis.glass_transmittance(p.patch, std::fabs(dot(faces.normal(size_t(p.patch)), d)));
        }
        if (hit.patch >= 0 && dot(faces.normal(size_t(hit.patch)), d) < 0) sum += pass;
    }
    return sum / (g * g);
}
}  // namespace

void Hierarchy::measure_open(const Visibility& vis) {
    const size_t first = open.size();
    if (first >= nodes.size()) return;
    open.resize(nodes.size(), 1.0f);
    closure.resize(nodes.size(), -1.0f);
    const double lift = vis.ray_offset();
    tbb::parallel_for(first, nodes.size(), [&](size_t i) {
        const Node& node = nodes[i];
        if (node.cluster) return;
        const Patch& s = shape(static_cast<uint32_t>(i));
        const Vec3 n = s.normal;
        // a tangent frame: the four slanted directions at 60 degrees from n
        const Vec3 a = std::fabs(n.x) < 0.6 ? Vec3{1, 0, 0} : Vec3{0, 1, 0};
        const Vec3 t = normalize(cross(n, a)), b = cross(n, t);
        const double c = 0.5, si = std::sqrt(0.75);
        const Vec3 dirs[5] = {n, n * c + t * si, n * c - t * si, n * c + b * si, n * c - b * si};
        Rng rng(key(static_cast<uint32_t>(i)) ^ 0x09E4ull);
        // Share of g x g stratified points inside geometry.
        auto inside_share = [&](int g) {
            int inside = 0;
            for (int k = 0; k < g * g; ++k) {
                const double s0 = (k % g + rng.uniform()) / g, t0 = (k / g + rng.uniform()) / g;
                const Vec3 x = ray_start(s, s0, t0, lift);
                bool enclosed = true;
                for (const Vec3& d : dirs) {
                    // (glass encloses nothing: seen through, the backs behind it count)
                    const RayHit hit = vis.intersect_through_glass(x, d);
                    if (hit.patch < 0 || dot(faces.normal(static_cast<size_t>(hit.patch)), d) < 0) {
                        enclosed = false;
                        break;
                    }
                }
                inside += enclosed;
            }
            return double(inside) / (g * g);
        };
        // 8 x 8 points; where they disagree (the element straddles a foot) 24 x 24, since the
        // share then scales the element's light: a thin open strip counted 11 points of 64
        // where 12.8 were due would brighten the strip by 16 %.
        double hidden = inside_share(8);
        if (hidden > 0 && hidden < 1) hidden = inside_share(24);
        open[i] = static_cast<float>(1.0 - hidden);
        const RGB& rho = s.reflectance;
        if (std::max({rho.x, rho.y, rho.z}) >= closure_reflectance && hidden < 1)
            closure[i] = static_cast<float>(measure_closure(vis, faces, s, rng, lift) / (1.0 - hidden));
    });
}

}  // namespace hirad
