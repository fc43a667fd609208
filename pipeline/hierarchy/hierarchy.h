// The element hierarchy of hierarchical radiosity with clustering (Hanrahan, Salzman and
// Aupperle 1991; Smits, Arvo and Greenberg 1994; Sillion 1995).
//
// Above the input faces, a tree of clusters (splits of face centroids along the longest axis,
// up to four children a cluster, kClusterFaces faces under the lowest) so that linking starts at
// the root and never enumerates pairs of faces. Every
// face is the root of a quadtree of elements (quads split at edge midpoints, triangles 4-split),
// grown on demand down to a minimum area. Nodes live in one array and refer to each other by
// index, and the children of a node are contiguous. An index depends on the order the nodes
// were made in; a node's key (Node::key) does not.
#pragma once
#include <cstdint>
#include <vector>

#include "pipeline/core/link.h"
#include "pipeline/geometry/face_table.h"
#include "pipeline/geometry/patches.h"
#include "pipeline/geometry/scene.h"

namespace hirad {

class Visibility;

constexpr uint32_t kNoNode = UINT32_MAX;

// Children of a cluster. The faces are taken in buckets of kClusterFaces along the tree: a
// cluster of one bucket has its faces as children; a larger one is cut along its longest axis
// into halves of whole buckets, and each half of more than one bucket into halves again, so a
// cluster has two to four children. Each cluster costs a node, its shape and the light it
// receives (about 360 bytes); the binary tree down to single faces this replaced had a cluster
// a face, this one a third of one: 615,054 -> 205,018 clusters, 85 MB less through the solve
// on a 615k-triangle floor (bench/README.md).
constexpr uint32_t kClusterFaces = 4;
constexpr uint32_t kClusterChildren = 4;   // the most children a cluster has

// What descending from an element to the leaf at a point reads of each node (8 bytes: the
// final gather keeps these apart from the large nodes, whose cache misses dominated it).
struct DescentStep {
    uint32_t first_child;
    uint8_t child_count;
    uint8_t nv;
};

// The leaf below element i that holds its point (s, t), over any view of the nodes (`step(k)`
// gives node k's DescentStep). Children follow Hierarchy::subdivide(): quads by parameter
// quadrant; triangles by the corner triangle holding the point, the inverted middle one (3)
// mapping (s, t) to (1-2s, 1-2t).
template <class Step>
uint32_t descend_to_leaf(const Step& step, uint32_t i, double s, double t) {
    DescentStep d = step(i);
    if (d.nv == 3 && s + t > 1) { s = 1 - s; t = 1 - t; }
    while (d.child_count != 0) {
        int k;
        if (d.nv == 4) {
            const bool right = s >= 0.5, top = t >= 0.5;
            k = right ? (top ? 2 : 1) : (top ? 3 : 0);
            s = right ? 2 * s - 1 : 2 * s;
            t = top ? 2 * t - 1 : 2 * t;
        } else if (s >= 0.5) { k = 1; s = 2 * s - 1; t = 2 * t; }
        else if (t >= 0.5) { k = 2; s = 2 * s; t = 2 * t - 1; }
        else if (s + t <= 0.5) { k = 0; s = 2 * s; t = 2 * t; }
        else { k = 3; s = 1 - 2 * s; t = 1 - 2 * t; }
        s = s < 0 ? 0 : (s > 1 ? 1 : s);
        t = t < 0 ? 0 : (t > 1 ? 1 : t);
        i = d.first_child + static_cast<uint32_t>(k);
        d = step(i);
    }
    return i;
}

struct Node {
    Vec3 lo, hi;             // bounds of everything below
    double area = 0;         // surface area of everything below
    uint32_t parent = kNoNode;
    uint32_t first_child = kNoNode;
    uint8_t child_count = 0;
    bool cluster = false;
    bool lit = false;        // elements: shape.direct computed for this element (luminaire.h)
    uint32_t face_begin = 0, face_end = 0;  // their faces in Hierarchy::face_order (an element: its face's)
    // Elements: their polygon, material and face, Hierarchy::shape (an index into the
    // hierarchy's faces for an element root, which is its face, or into its pieces); clusters
    // have none (kNoNode). Kept apart so that a cluster, half the nodes, does not carry a
    // polygon (on a 1M-face scene 2.2 M nodes were 416 bytes each, 328 of them the polygon).
    uint32_t element = kNoNode;
    bool leaf() const { return child_count == 0; }
    double diagonal() const { return length(hi - lo); }
};
// 80 bytes: 1.4 nodes a face or more, so each 8 bytes is about 11 MB on a 1M-face scene.
static_assert(sizeof(Node) == 80, "Node grew");

// What a face of unit normal n below a receiving cluster takes, per unit area, of the power
// G B_S a link brings the cluster: n . vector + uniform (Hierarchy::reception). A sum of
// these over links is again one.
struct Reception {
    Vec3 vector;
    double uniform = 0;
    double along(const Vec3& n) const { return dot(n, vector) + uniform; }
    Reception& operator+=(const Reception& o) {
        vector += o.vector;
        uniform += o.uniform;
        return *this;
    }
    Reception operator*(double k) const { return {vector * k, uniform * k}; }
};

// Light received by a cluster (see Hierarchy::reception): per colour channel an irradiance
// vector and a uniform part, so that a surface of unit normal n below the cluster receives
// H = n . E + U (per channel).
struct VectorIrradiance {
    Vec3 c[3];
    RGB uniform;
    void add(const RGB& b, const Reception& r) {
        c[0] += r.vector * b.x;
        c[1] += r.vector * b.y;
        c[2] += r.vector * b.z;
        uniform += b * r.uniform;
    }
    void add(const VectorIrradiance& o) {
        for (int k = 0; k < 3; ++k) c[k] += o.c[k];
        uniform += o.uniform;
    }
    RGB along(const Vec3& n) const { return RGB{dot(n, c[0]), dot(n, c[1]), dot(n, c[2])} + uniform; }
};

class Hierarchy {
public:
    // Builds the clusters over the scene's faces; element roots are the faces themselves.
    explicit Hierarchy(const Scene& scene);

    std::vector<Node> nodes;
    uint32_t root = 0;
    std::vector<uint32_t> face_order;   // faces in cluster order
    std::vector<uint32_t> face_node;    // element root of each face
    std::vector<double> area_prefix;    // prefix sums of face area in face_order (size faces+1)
    FaceTable faces;                    // the faces as polygons (for Embree and sampling), then the
                                        // backs of the glazed ones (Patch::back; face = the front's),
                                        // stored compactly (face_table.h)
    size_t scene_faces = 0;             // faces[0, scene_faces) are the scene's
    std::vector<Patch> pieces;          // the polygons of the elements made by subdivision

    // An element's polygon, material and face (Node::element); an empty patch for a cluster.
    // A face's is made from the FaceTable (a copy: the same bits as the patch it was made
    // from); what the solvers read of every node in their walks has accessors of its own.
    Patch shape(uint32_t node) const {
        const uint32_t e = nodes[node].element;
        return e == kNoNode ? Patch{} : (e < faces.size() ? faces[e] : pieces[e - faces.size()]);
    }
    // The same without copying a piece: a reference to it, or `scratch` made from the table.
    const Patch& shape(uint32_t node, Patch& scratch) const {
        const uint32_t e = nodes[node].element;
        if (e == kNoNode) return scratch = Patch{};
        if (e >= faces.size()) return pieces[e - faces.size()];
        faces.get(e, scratch);
        return scratch;
    }
    const RGB& reflectance(uint32_t node) const {
        const uint32_t e = nodes[node].element;
        return e == kNoNode ? kZero : (e < faces.size() ? faces.reflectance(e) : pieces[e - faces.size()].reflectance);
    }
    const RGB& emission(uint32_t node) const {
        const uint32_t e = nodes[node].element;
        return e == kNoNode ? kZero : (e < faces.size() ? faces.emission(e) : pieces[e - faces.size()].emission);
    }
    const RGB& direct(uint32_t node) const {
        const uint32_t e = nodes[node].element;
        return e == kNoNode ? kZero : (e < faces.size() ? faces.direct(e) : pieces[e - faces.size()].direct);
    }
    const Vec3& normal(uint32_t node) const {
        const uint32_t e = nodes[node].element;
        return e == kNoNode ? kZero : (e < faces.size() ? faces.normal(e) : pieces[e - faces.size()].normal);
    }
    // An element is the back of a glazed face (Patch::back); a cluster is not.
    bool back(uint32_t node) const {
        const uint32_t e = nodes[node].element;
        return e == kNoNode ? false : (e < faces.size() ? faces.back(e) : pieces[e - faces.size()].back);
    }
    int nv(uint32_t node) const {
        const uint32_t e = nodes[node].element;
        return e == kNoNode ? 0 : (e < faces.size() ? faces.nv(e) : pieces[e - faces.size()].nv);
    }
    // An element's light from luminaires (Patch::direct) and its source term with it
    // (Patch::emission).
    void set_light(uint32_t node, const RGB& direct, const RGB& emission);
    static inline const Vec3 kZero{};

    // Glazing's two sides. A glazed face (Face::transmittance tau0 > 0) is two element trees
    // back to back: the face, and its back (the polygon turned over), each receiving the light
    // in front of it and reflecting its reflectance of it: B = E + rho H. What the glass lets
    // through it does not scatter: links and the final gather see through it, each ray with
    // the factor tau0 r(cos theta) (visibility.h), so that light arrives on the other side in
    // its own direction. Only the fronts are traced.
    struct GlassPair {
        uint32_t front, back;    // element roots
    };
    std::vector<GlassPair> glass;

    // Clusters that receive (Sillion 1995; Willmott, Heckbert and Garland 1999 solved
    // million-face scenes this way). A link may end on a cluster R instead of on each of its
    // faces when every face below R sees every point of the source S from its front: the
    // normals' cone (axis a, half-angle alpha) and the cone of directions from R to S (axis d,
    // from R's centre to S's, half-angle beta with sin beta = (r_R + r_S) / |d|, r a node's
    // radius about its centre) then satisfy angle(a, d) + alpha + beta < 90 degrees (with a
    // margin: kFrontCosine). The light S sends such a cluster is a field of almost one
    // direction d, so face f (unit normal n_f, area A_f) receives H_f = n_f . E with the
    // irradiance vector E = G B_S d / (A_R . d), A_R = sum A_f n_f the cluster's vector area:
    // the power received, sum A_f H_f = G B_S, is the link's G (estimated with the faces' own
    // normals, as for every link) and nothing else changes in how a link is stored, shot or
    // balanced. reception(R, S) is that d / (A_R . d); the solvers add G B_S times it to R's
    // vector irradiance, push the vectors down the clusters and give each face root n_f . E.
    // How far that is from each face's own irradiance: a face at y, off R's centre by up to
    // r_R, sees S in a direction turned from d by up to r_R / |d| (to first order; S's own
    // extent moves the mean direction only to second order), and n_f . d / (A_R . d) then
    // errs by up to tan(theta_f) r_R / |d| relative, theta_f <= angle(a, d) + alpha. So a
    // cluster receives only where tan(angle(a, d) + alpha) r_R / |d| <= kDirectionTolerance.
    // Faces of one orientation (alpha = 0: the tiles of a floor, the quads of a box's side)
    // need neither rule: each takes G / A_R, the cluster's mean, whatever the direction,
    // exactly as an element's children do, and the source need not be in front of them all
    // (part of it may lie behind their plane, as the floor does for a box's side; G, estimated
    // with their normals, counts only the part in front). For them reception is a / A_R, and
    // they are passed over only by a source wholly behind them. Faces over faces (a table top
    // above the floor, both facing up) are not one surface: the top shades the floor, and
    // sharing G by the direction would light the floor under the table as the top. So a
    // cluster whose faces reach further along the axis than one surface of normals within
    // alpha can (r_R sin alpha: 0 for a plane) is `layered`, and may misplace all of a link's
    // light. The light's variation in magnitude across a cluster is the refiner's epsilon
    // rule, as for elements.
    // Links that carry little. A cluster that fails these rules (Mixed, layered, or Front
    // beyond the tolerance) still receives a link whose light is too little to matter, so
    // that links from dark or distant sources do not split a large receiver down to its
    // single directions: misplaced(R, S) bounds the fraction of the link's light its sharing
    // may put on the wrong faces, and the refiner keeps the link while that fraction of the
    // most it can carry stays below a small part of epsilon (refine.h). Front clusters share
    // by the direction as above; Mixed ones evenly, G B_S / A_R to each face (Sillion's
    // isotropic clusters), so a face of unit normal n takes n . vector + uniform of
    // reception(R, S).
    enum class Facing { Front, Back, Mixed };
    static constexpr double kFrontCosine = 0.05;   // cos(angle(a, d) + alpha + beta) at least this
    static constexpr double kDirectionTolerance = 0.01;  // faces' relative error from one direction
    static constexpr double kPlanarCosine = 1 - 1e-9;    // cos_spread above this: one plane
    // Per cluster: its centre (the area-weighted mean of its faces' centroids), radius about it
    // (to the farthest corner of its box), vector area, and the cone of its faces' normals
    // (axis(): the vector area's direction; cos_spread: the least n_f . axis, -1 when the vector
    // area vanishes). 72 bytes: the axis is made when asked, by the one expression the
    // constructor used (24 bytes a cluster, a third of one a face, for a division and a root).
    struct ClusterShape {
        Vec3 centre;
        double radius = 0;
        Vec3 vector_area;
        double cos_spread = -1;
        bool layered = false;   // deeper along the axis than r sin(alpha): may shade itself
        Vec3 axis() const { return vector_area / length(vector_area); }
    };
    std::vector<ClusterShape> cluster_shapes;   // per cluster slot
    std::vector<uint32_t> cluster_slot;         // per node the constructor built: its slot, or kNoNode
    uint32_t slot_of(uint32_t node) const { return node < cluster_slot.size() ? cluster_slot[node] : kNoNode; }
    Vec3 centre(uint32_t node) const;
    double radius(uint32_t node) const;
    // Whether the faces below cluster `r` all see node `s` from their front (Front), all from
    // their back (Back: nothing passes), or neither; Mixed when `r` is not a cluster. (By the
    // angles alone: a layered cluster may be Front.)
    // `direction_error`: the bound tan(angle(a, d) + alpha) r_R / |d| above (0 for a planar
    // cluster), set for Front.
    Facing facing(uint32_t r, uint32_t s, double* direction_error = nullptr) const;
    // How a link from `s` shares its light among the faces below cluster `r`: by the vector
    // d / (A_R . d) where `r` faces `s` (Front); otherwise (Mixed) evenly, uniform = 1 / A_R.
    Reception reception(uint32_t r, uint32_t s) const;
    // The most that sharing misplaces among the faces, as a fraction of the link's light:
    // the direction error for Front (0 for faces of one orientation), 1 for Mixed (shared
    // evenly, whatever the faces see) and layered clusters, 0 for Back (nothing passes). The refiner lets a
    // cluster receive where this is within kDirectionTolerance, or where this times the most
    // the link can carry is a small part of epsilon (refine.h).
    double misplaced(uint32_t r, uint32_t s) const;

    // Who a node is, whatever order the hierarchy grew in: its index for the nodes the
    // constructor built (clusters and element roots), and for an element made by subdivision
    // a hash of its parent's key and its place among the children. Refinement seeds its link
    // estimates with keys, so a group refined on another machine, whose new nodes are numbered
    // differently, draws the same samples (pipeline/engine/distributed.h). Only the made
    // elements' keys are stored (8 bytes a node less: most nodes are the constructor's).
    uint64_t key(uint32_t node) const { return node < built_nodes ? node : made_keys[node - built_nodes]; }
    uint32_t built_nodes = 0;          // nodes the constructor built
    std::vector<uint64_t> made_keys;   // per node made by subdivision, from built_nodes on
    // Elements in the order they were subdivided: replaying it on a new hierarchy of the same
    // scene rebuilds the same nodes with the same indices (what the link store refers to).
    std::vector<uint32_t> subdivided;

    // Gives an element its four children (once); false if it would go below min_area.
    bool can_subdivide(uint32_t node, double min_area) const;
    void subdivide(uint32_t node);
    // Subdivides the elements of a log in its order; throws if an entry is not a leaf element.
    // A hierarchy already subdivided (split for its luminaires) replays a log that starts
    // with its own, from where its own ends; any other log is refused.
    void replay(const std::vector<uint32_t>& log);

    // A point on the surfaces below `node` and the normal there: stratified (s, t) on an
    // element; on a cluster, a face chosen with probability proportional to its area by `pick`.
    void sample(uint32_t node, double pick, double s, double t, Vec3& point, Vec3& normal) const;

    // The leaf below element `node` that holds its point (s, t) (Patch::point's coordinates).
    uint32_t leaf_at(uint32_t node, double s, double t) const;

    // Leaf elements in depth-first order.
    std::vector<uint32_t> leaves() const;

    // 2:1 balance for display: splits leaves until no leaf edge has more than one vertex of
    // finer neighbours on it (at its midpoint). New nodes come after all existing ones; the
    // number of leaves split is returned.
    uint64_t balance();

    // The open share of each element: the fraction of its area that is not inside other
    // geometry. A floor modelled as one quad runs on under the blocks standing on it; the
    // part under a block receives nothing, and an element that straddles the block's foot
    // averages that nothing into its irradiance and radiosity. Its visible part is then shown
    // too dark, and, since a link from it sees only the visible part (G counts what the rays
    // reach) but carries the diluted mean, the light it passes on is lost: the hierarchical
    // solution's dark bias near contacts (-11 % at the foot of the Cornell box's tall block
    // at epsilon 1e-4, -1.5 % over the box). So the solution's H and B of an element are
    // those of its open part: a link's stored coupling is G / open (the estimate's G spread
    // over the open area, Refiner), the luminaires' direct light is divided by it too, and the
    // power a link takes from its source is coupling x open(receiver) (sent()).
    // A point is inside geometry when every ray it sends (its normal and four directions 60
    // degrees off it) first meets the back of a surface; a ray that escapes or meets a front
    // face finds it open (under a one-sided table top the slanted rays pass). 8 x 8 stratified
    // points per element, seeded by its key, and 24 x 24 where they disagree. Clusters: 1.
    std::vector<float> open;
    // Measures the open share and the closure of the nodes made since the last call (open.size()
    // up to nodes.size()), in parallel; `vis` must be over `faces`.
    void measure_open(const Visibility& vis);
    double open_share(uint32_t node) const { return node < open.size() ? open[node] : 1.0; }
    // The closure of each element whose reflectance is near 1: the share of its open part's
    // cosine-weighted hemisphere that meets the front of a surface, which is what its form
    // factors sum to (a pane counts on either side, since both are elements, and what lies
    // beyond it counts again at the pane's factor T(theta): behind glass the sum may pass 1).
    // A hierarchical solution's sums do not come to it leaf by leaf: a link at an ancestor
    // gives every leaf below it the ancestor's mean F, so in a closed room the leaves' sums
    // spread from 0.95 to 1.3 around an area mean of 1 (tests/cpp/cluster_receivers_test.cpp).
    // Where rho is near 1 that spread decides the light: each bounce multiplies by rho F, and
    // the gain limit (hierarchical_solver.h), which must cut rho F below 1 for the solve to
    // converge, cut the sums above 1 and left those below, so a closed room of rho 0.99 came
    // to 54 % of its light (sum A H = Phi / (1 - rho)) and the country kitchen, whose walls
    // reflect 0.999, 5 % too dark over all its surfaces. So the solvers scale what such a leaf
    // inherits from its ancestors so that its sum comes to its closure (gather_terms): rows of
    // F normalised to the share of the hemisphere they cover, as form-factor rows are
    // normalised to 1 in closed rooms. Below closure_reflectance (kClosureReflectance by
    // default; hierarchy.closure_reflectance) it is not
    // applied: on the Modern Hall (walls 0.893) normalising every leaf moved the final gather
    // from 8.7 % to 10.2 % RMS against the path tracer, while the country kitchen gained
    // (median error 7.9 -> 3.6 %; bench/README.md). 8 x 8 stratified points, each with one
    // stratified cosine-distributed ray, seeded by the node's key; -1 where not measured.
    static constexpr double kClosureReflectance = 0.95;
    // The threshold itself (hierarchy.closure_reflectance; set before the first measure_open):
    // on the country kitchen (walls 0.999, most else below 0.9) normalising every leaf (0 here)
    // took the final gather's mean error at 87 points from -3.9 % to +0.4 % and its median
    // from 4.7 % to 3.1 %, on the Modern Hall its RMS from 8.6 % to 10.2 % (bench/README.md).
    double closure_reflectance = kClosureReflectance;
    std::vector<float> closure;
    double closure_of(uint32_t node) const { return node < closure.size() ? closure[node] : -1.0; }
    // G / A_receiver of a link in the solvers: the open receiver's F. The power share it takes
    // from its source: coupling x open(receiver) / A_source (energy balance).
    double sent(const Link& l) const { return double(l.coupling) * open_share(l.receiver); }
};

}  // namespace hirad
