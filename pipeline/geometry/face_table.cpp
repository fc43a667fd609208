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

// Index of v in `values` by the bits, added if new; `slots` is an open-addressing table of
// indices + 1 (0 empty), kept at most half full.
uint32_t intern(std::vector<Vec3>& values, std::vector<uint32_t>& slots, const Vec3& v) {
    if (2 * (values.size() + 1) > slots.size()) {
        std::vector<uint32_t> grown(slots.empty() ? 1024 : 2 * slots.size(), 0u);
        const size_t mask = grown.size() - 1;
        for (size_t i = 0; i < values.size(); ++i) {
            size_t s = bits_hash(values[i]) & mask;
            while (grown[s] != 0) s = (s + 1) & mask;
            grown[s] = static_cast<uint32_t>(i + 1);
        }
        slots.swap(grown);
    }
    const size_t mask = slots.size() - 1;
    size_t s = bits_hash(v) & mask;
    while (slots[s] != 0) {
        if (same_bits(values[slots[s] - 1], v)) return slots[s] - 1;
        s = (s + 1) & mask;
    }
    values.push_back(v);
    slots[s] = static_cast<uint32_t>(values.size());
    return static_cast<uint32_t>(values.size() - 1);
}

// intern's table for Welding::ByMesh: equal when the mesh is and the positions are (-0.0 and
// +0.0 alike); the first corner's bits are the point's.
uint32_t intern_by_mesh(std::vector<Vec3>& values, std::vector<uint32_t>& meshes, std::vector<uint32_t>& slots,
                        const Vec3& v, uint32_t mesh) {
    auto hash = [](const Vec3& x, uint32_t m) {
        return bits_hash(x + Vec3{0, 0, 0}) ^ (uint64_t(m) * 0xD6E8FEB86659FD93ull);
    };
    if (2 * (values.size() + 1) > slots.size()) {
        std::vector<uint32_t> grown(slots.empty() ? 1024 : 2 * slots.size(), 0u);
        const size_t mask = grown.size() - 1;
        for (size_t i = 0; i < values.size(); ++i) {
            size_t s = hash(values[i], meshes[i]) & mask;
            while (grown[s] != 0) s = (s + 1) & mask;
            grown[s] = static_cast<uint32_t>(i + 1);
        }
        slots.swap(grown);
    }
    const size_t mask = slots.size() - 1;
    const Vec3 key = v + Vec3{0, 0, 0};
    size_t s = hash(v, mesh) & mask;
    while (slots[s] != 0) {
        const uint32_t i = slots[s] - 1;
        if (meshes[i] == mesh && same_bits(values[i] + Vec3{0, 0, 0}, key)) return i;
        s = (s + 1) & mask;
    }
    values.push_back(v);
    meshes.push_back(mesh);
    slots[s] = static_cast<uint32_t>(values.size());
    return static_cast<uint32_t>(values.size() - 1);
}

}  // namespace

uint32_t FaceTable::point_index(const Vec3& p, uint32_t mesh) {
    return welding_ == Welding::ByMesh ? intern_by_mesh(points_, point_mesh_, point_slots_, p, mesh)
                                       : intern(points_, point_slots_, p);
}
uint32_t FaceTable::reflectance_index(const RGB& r) { return intern(reflectances_, reflectance_slots_, r); }

void FaceTable::reserve(size_t n) {
    records_.reserve(n);
    area_.reserve(n);
    emission_.reserve(n);
    direct_.reserve(n);
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
    emission_.push_back(p.emission);
    direct_.push_back(p.direct);
}

void FaceTable::seal() {
    std::vector<uint32_t>().swap(point_slots_);
    std::vector<uint32_t>().swap(reflectance_slots_);
    records_.shrink_to_fit();
    points_.shrink_to_fit();
    point_mesh_.shrink_to_fit();
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
        for (int k = 0; k < r.nv; ++k) c += points_[r.corner[k]];
        return c / r.nv;
    }
    Patch p;
    get(f, p);
    return p.centroid;
}

void FaceTable::get(size_t f, Patch& p) const {
    const Record& r = records_[f];
    p.nv = r.nv;
    for (int k = 0; k < 4; ++k) p.p[k] = points_[r.corner[k]];
    if (uv_.empty()) p.uv = {};
    else p.uv = uv_[f];
    p.reflectance = reflectances_[r.reflectance];
    p.emission = emission_[f];
    p.direct = direct_[f];
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
           point_mesh_.capacity() * sizeof(uint32_t) +
           area_.capacity() * sizeof(double) +
           reflectances_.capacity() * sizeof(RGB) +
           (emission_.capacity() + direct_.capacity()) * sizeof(RGB) + uv_.capacity() * sizeof(uv_[0]) +
           (point_slots_.capacity() + reflectance_slots_.capacity()) * sizeof(uint32_t);
}

}  // namespace hirad
