#include "pipeline/geometry/face_table.h"

#include <cstring>

namespace hirad {

namespace {

// The bits of three doubles, hashed (splitmix64's finaliser over their words).
uint64_t bits_hash(const Vec3& v) {
    uint64_t w[3];
    std::memcpy(w, &v, sizeof w);
    uint64_t h = 0x9E3779B97F4A7C15ull;
    for (uint64_t x : w) {
        h ^= x + 0x9E3779B97F4A7C15ull + (h << 6) + (h >> 2);
        h = (h ^ (h >> 30)) * 0xBF58476D1CE4E5B9ull;
        h = (h ^ (h >> 27)) * 0x94D049BB133111EBull;
        h ^= h >> 31;
    }
    return h;
}

bool same_bits(const Vec3& a, const Vec3& b) { return std::memcmp(&a, &b, sizeof(Vec3)) == 0; }

// Makes `slots` (indices + 1, 0 empty) room for one more of `count` keys at most half full,
// placing the keys again by `hash_of(i)`.
template <class HashOf>
void make_room(std::vector<uint32_t>& slots, size_t count, HashOf&& hash_of) {
    if (2 * (count + 1) <= slots.size()) return;
    std::vector<uint32_t> grown(slots.empty() ? 1024 : 2 * slots.size(), 0u);
    const size_t mask = grown.size() - 1;
    for (size_t i = 0; i < count; ++i) {
        size_t s = hash_of(i) & mask;
        while (grown[s] != 0) s = (s + 1) & mask;
        grown[s] = static_cast<uint32_t>(i + 1);
    }
    slots.swap(grown);
}

// The slot of the key with hash `h` for which `same(i)` holds, or the empty slot where it goes.
template <class Same>
size_t slot_of(const std::vector<uint32_t>& slots, uint64_t h, Same&& same) {
    const size_t mask = slots.size() - 1;
    size_t s = h & mask;
    while (slots[s] != 0 && !same(slots[s] - 1)) s = (s + 1) & mask;
    return s;
}

// Index of v in `values` by the bits, added if new; `slots` is an open-addressing table of
// indices + 1 (0 empty), kept at most half full.
uint32_t intern(std::vector<Vec3>& values, std::vector<uint32_t>& slots, const Vec3& v) {
    make_room(slots, values.size(), [&](size_t i) { return bits_hash(values[i]); });
    const size_t s = slot_of(slots, bits_hash(v), [&](uint32_t i) { return same_bits(values[i], v); });
    if (slots[s] != 0) return slots[s] - 1;
    values.push_back(v);
    slots[s] = static_cast<uint32_t>(values.size());
    return static_cast<uint32_t>(values.size() - 1);
}

uint64_t mesh_hash(const Vec3& p, uint32_t mesh) {
    return bits_hash(p + Vec3{0, 0, 0}) ^ (uint64_t(mesh) * 0xD6E8FEB86659FD93ull);
}

}  // namespace

uint32_t MeshPoints::index(uint32_t mesh, const Vec3& p) {
    make_room(slots_, points.size(), [&](size_t i) { return mesh_hash(points[i], meshes[i]); });
    const size_t s = slot(mesh, p);
    if (slots_[s] != 0) return slots_[s] - 1;
    points.push_back(p);
    meshes.push_back(mesh);
    slots_[s] = static_cast<uint32_t>(points.size());
    return static_cast<uint32_t>(points.size() - 1);
}

int64_t MeshPoints::find(uint32_t mesh, const Vec3& p) const {
    if (slots_.empty()) return -1;
    const size_t s = slot(mesh, p);
    return slots_[s] == 0 ? -1 : int64_t(slots_[s]) - 1;
}

size_t MeshPoints::slot(uint32_t mesh, const Vec3& p) const {
    const Vec3 key = p + Vec3{0, 0, 0};
    return slot_of(slots_, mesh_hash(p, mesh),
                   [&](uint32_t i) { return meshes[i] == mesh && same_bits(points[i] + Vec3{0, 0, 0}, key); });
}

void MeshPoints::seal() {
    std::vector<uint32_t>().swap(slots_);
    points.shrink_to_fit();
    meshes.shrink_to_fit();
}

uint32_t FaceTable::point_index(const Vec3& p, uint32_t mesh) {
    return welding_ == Welding::ByMesh ? by_mesh_.index(mesh, p) : intern(points_, point_slots_, p);
}
uint32_t FaceTable::reflectance_index(const RGB& r) { return intern(reflectances_, reflectance_slots_, r); }

void FaceTable::reserve(size_t n) {
    records_.reserve(n);
    area_.reserve(n);
}

RGB& FaceTable::light(std::vector<RGB>& v, size_t f) {
    if (v.empty()) {  // the faces so far had none
        v.reserve(records_.capacity());
        v.resize(records_.size());
    }
    return v[f];
}

void FaceTable::push_back(const Patch& p) {
    Record r;
    for (int k = 0; k < 4; ++k) r.corner[k] = point_index(p.p[k], p.mesh);
    r.mesh = p.mesh;
    r.face = p.face;
    r.reflectance = reflectance_index(p.reflectance);
    r.nv = static_cast<uint8_t>(p.nv);
    r.back = p.back ? 1 : 0;
    r.normal = p.normal;
    const bool textured = p.uv[0].u != 0 || p.uv[0].v != 0 || p.uv[1].u != 0 || p.uv[1].v != 0 ||
                          p.uv[2].u != 0 || p.uv[2].v != 0 || p.uv[3].u != 0 || p.uv[3].v != 0;
    if (textured && uv_.empty()) uv_.resize(records_.size());  // the faces before had zeros
    if (!uv_.empty()) uv_.push_back(p.uv);
    records_.push_back(r);
    area_.push_back(p.area);
    static_assert(sizeof(RGB) == 3 * sizeof(double), "RGB is three doubles");
    for (auto [v, x] : {std::pair{&emission_, &p.emission}, std::pair{&direct_, &p.direct}}) {
        if (!v->empty()) v->push_back(*x);
        else if (std::memcmp(x, &kNoLight, sizeof(RGB)) != 0) light(*v, records_.size() - 1) = *x;  // (-0.0 kept)
    }
}

void FaceTable::seal() {
    std::vector<uint32_t>().swap(point_slots_);
    std::vector<uint32_t>().swap(reflectance_slots_);
    records_.shrink_to_fit();
    points_.shrink_to_fit();
    by_mesh_.seal();
    area_.shrink_to_fit();
    reflectances_.shrink_to_fit();
    emission_.shrink_to_fit();
    direct_.shrink_to_fit();
    uv_.shrink_to_fit();
}

Vec3 FaceTable::centroid(size_t f) const {
    const Record& r = records_[f];
    if (centroid_ == PatchCentroid::CornerMean) {  // patch_centroid's expression
        Vec3 c;
        for (int k = 0; k < r.nv; ++k) c += pts()[r.corner[k]];
        return c / r.nv;
    }
    Patch p;
    get(f, p);
    return p.centroid;
}

void FaceTable::get(size_t f, Patch& p) const {
    const Record& r = records_[f];
    p.nv = r.nv;
    for (int k = 0; k < 4; ++k) p.p[k] = pts()[r.corner[k]];
    if (uv_.empty()) p.uv = {};
    else p.uv = uv_[f];
    p.reflectance = reflectances_[r.reflectance];
    p.emission = emission(f);
    p.direct = direct(f);
    p.mesh = r.mesh;
    p.face = r.face;
    p.back = r.back != 0;
    p.vertex = {0, 0, 0, 0};
    p.normal = r.normal;
    p.area = area_[f];
    p.centroid = patch_centroid(p, centroid_);
}

size_t FaceTable::bytes() const {
    return records_.capacity() * sizeof(Record) + points_.capacity() * sizeof(Vec3) +
           by_mesh_.bytes() +
           area_.capacity() * sizeof(double) +
           reflectances_.capacity() * sizeof(RGB) +
           (emission_.capacity() + direct_.capacity()) * sizeof(RGB) + uv_.capacity() * sizeof(uv_[0]) +
           (point_slots_.capacity() + reflectance_slots_.capacity()) * sizeof(uint32_t);
}

}  // namespace hirad
