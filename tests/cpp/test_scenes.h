// Test scenes shared by the C++ tests. Header-only: the build compiles tests/cpp/*_test.cpp
// and nothing else.
#pragma once
#include <cmath>
#include <utility>
#include <vector>

#include "pipeline/geometry/patches.h"
#include "pipeline/geometry/scene.h"

namespace hirad::test {

inline RGB grey(double v) { return {v, v, v}; }

// The closed unit cube [0, 1]^3 as six quads facing inwards (-z, +z, -x, +x, -y, +y), every
// one reflecting rho and emitting the exitance `emission` (W/m^2).
inline Scene unit_cube(const RGB& rho = {}, const RGB& emission = {}) {
    const std::vector<std::vector<Vec3>> quads = {
        {{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0}}, {{0, 0, 1}, {0, 1, 1}, {1, 1, 1}, {1, 0, 1}},
        {{0, 0, 0}, {0, 1, 0}, {0, 1, 1}, {0, 0, 1}}, {{1, 0, 0}, {1, 0, 1}, {1, 1, 1}, {1, 1, 0}},
        {{0, 0, 0}, {0, 0, 1}, {1, 0, 1}, {1, 0, 0}}, {{0, 1, 0}, {1, 1, 0}, {1, 1, 1}, {0, 1, 1}},
    };
    Scene scene;
    for (const auto& q : quads) {
        Face f;
        f.nv = 4;
        for (int k = 0; k < 4; ++k) f.p[k] = q[k];
        f.reflectance = rho;
        f.emission = emission;
        scene.faces.push_back(f);
    }
    return scene;
}

// The same cube with each side made of per_side x per_side input faces (a scene of many small
// faces, 6 per_side^2 of them).
inline Scene tiled_cube(int per_side, const RGB& rho = {}, const RGB& emission = {}) {
    const Scene sides = unit_cube(rho, emission);
    Scene scene;
    for (const Face& side : sides.faces) {
        const Vec3 o = side.p[0], u = side.p[1] - side.p[0], v = side.p[3] - side.p[0];
        for (int i = 0; i < per_side; ++i)
            for (int j = 0; j < per_side; ++j) {
                Face f = side;
                const double a = double(i) / per_side, b = double(j) / per_side, c = 1.0 / per_side;
                f.p[0] = o + u * a + v * b;
                f.p[1] = o + u * (a + c) + v * b;
                f.p[2] = o + u * (a + c) + v * (b + c);
                f.p[3] = o + u * a + v * (b + c);
                scene.faces.push_back(f);
            }
    }
    return scene;
}

// The same cube with every face meshed into per_side x per_side patches (the edge limit a
// hair above 1 / per_side, so that rounding never makes one more).
inline std::vector<Patch> unit_cube_patches(int per_side, const RGB& rho = {}, const RGB& emission = {}) {
    return mesh_patches(unit_cube(rho, emission), {1.0, 1.0 / per_side + 1e-9}).patches;
}

// A 6 m room (4 x 4 tiles a side, inwards) lit by one ceiling tile of exitance 10, holding 4 x 4
// boxes of 0.4 m, each side cut t x t (outwards), floating 0.5 m above the floor; every face
// reflects rho. Closed: every ray from a face meets the front of another.
inline Scene cluttered_room(int t, double rho = 0.5) {
    Scene scene = tiled_cube(4, grey(rho));
    for (Face& f : scene.faces)
        for (Vec3& p : f.p) p = p * 6.0;
    for (Face& f : scene.faces)
        if (f.normal().z < -0.5 && std::abs(f.p[0].x + f.p[2].x - 6) < 1.6 && std::abs(f.p[0].y + f.p[2].y - 6) < 1.6) {
            f.emission = grey(10.0);
            break;
        }
    const Scene box = tiled_cube(t, grey(rho));
    for (int i = 0; i < 4; ++i)
        for (int j = 0; j < 4; ++j)
            for (Face f : box.faces) {
                std::swap(f.p[1], f.p[3]);
                for (Vec3& p : f.p) p = p * 0.4 + Vec3{0.9 + 1.3 * i, 0.9 + 1.3 * j, 0.5};
                scene.faces.push_back(f);
            }
    return scene;
}

}  // namespace hirad::test
