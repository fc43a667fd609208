// What every binding file shares: numpy <-> engine conversions, and running a long engine call
// on a worker thread while the calling thread (holding the GIL) reports progress and lets
// Ctrl-C through. No algorithm lives here or anywhere under pipeline/bindings/.
#pragma once
#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>

#include <array>
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <mutex>
#include <optional>
#include <stdexcept>
#include <exception>
#include <string>
#include <thread>
#include <vector>

#include "pipeline/core/vecmath.h"
#include "pipeline/engine/ray_scene.h"  // LiftResult (lift_samples_of)

namespace hirad::py {

namespace nb = nanobind;

template <typename T>
using In = nb::ndarray<const T, nb::c_contig, nb::device::cpu>;
template <typename T>
using Array = nb::ndarray<nb::numpy, T>;

// Property getters return arrays that own a copy of the values (not views into the struct),
// which nanobind's default policy for properties (reference_internal) cannot wrap.
constexpr auto kOwned = nb::rv_policy::automatic;

// A numpy array owning `v`.
template <typename T>
Array<T> to_numpy(std::vector<T> v, std::initializer_list<size_t> shape) {
    auto* data = new std::vector<T>(std::move(v));
    nb::capsule owner(data, [](void* p) noexcept { delete static_cast<std::vector<T>*>(p); });
    return Array<T>(data->data(), shape.size(), shape.begin(), owner);
}

// (n, 3) float64 from RGB or Vec3 rows.
inline Array<double> rows3(const std::vector<Vec3>& v) {
    std::vector<double> flat(v.size() * 3);
    for (size_t i = 0; i < v.size(); ++i)
        for (int c = 0; c < 3; ++c) flat[3 * i + c] = v[i][c];
    return to_numpy(std::move(flat), {v.size(), 3});
}

// Property getters of a struct's vectors (each returns an owned copy, with kOwned): a vector
// as a 1-d array, Vec3s as (n, 3) rows, fixed four-element arrays as (n, 4) rows of T.
template <class C, class T>
auto arr(std::vector<T> C::*p) {
    return [p](const C& c) { return to_numpy(c.*p, {(c.*p).size()}); };
}
template <class C>
auto vec3s(std::vector<Vec3> C::*p) {
    return [p](const C& c) { return rows3(c.*p); };
}
template <class T, class C, class U>
auto quads(std::vector<std::array<U, 4>> C::*p) {
    return [p](const C& c) {
        const auto& v = c.*p;
        std::vector<T> flat(v.size() * 4);
        for (size_t i = 0; i < v.size(); ++i)
            for (int k = 0; k < 4; ++k) flat[4 * i + k] = static_cast<T>(v[i][k]);
        return to_numpy(std::move(flat), {v.size(), 4});
    };
}

// Checks a numpy array's shape, naming it: `shape` entries < 0 are free.
template <typename T>
void require_shape(const In<T>& a, std::initializer_list<long> shape, const char* what) {
    bool ok = a.ndim() == shape.size();
    size_t k = 0;
    for (long s : shape) {
        if (ok && s >= 0 && a.shape(k) != size_t(s)) ok = false;
        ++k;
    }
    if (!ok) {
        std::string want = "(";
        k = 0;
        for (long s : shape) want += (k++ ? ", " : "") + (s < 0 ? std::string("n") : std::to_string(s));
        std::string got = "(";
        for (size_t d = 0; d < a.ndim(); ++d) got += (d ? ", " : "") + std::to_string(a.shape(d));
        throw std::invalid_argument(std::string(what) + ": expected shape " + want + "), got " + got + ")");
    }
}

// Rows of an (n, 3) array; `n` checked when given.
inline std::vector<Vec3> vec3_rows(const In<double>& a, const char* what, long n = -1) {
    require_shape(a, {n, 3}, what);
    std::vector<Vec3> v(a.shape(0));
    for (size_t i = 0; i < v.size(); ++i) v[i] = {a.data()[3 * i], a.data()[3 * i + 1], a.data()[3 * i + 2]};
    return v;
}

// (points, directions) float32 of `source.direct_transmittance` (Engine, RayScene): the
// arrays checked, the work done without the GIL.
template <typename Source>
Array<float> direct_transmittance_of(const Source& source, const In<double>& p, const In<double>& n,
                                     const In<double>& d) {
    auto pts = vec3_rows(p, "points");
    auto nrm = vec3_rows(n, "normals", long(pts.size()));
    auto dirs = vec3_rows(d, "directions");
    std::vector<float> out;
    {
        nb::gil_scoped_release release;
        out = source.direct_transmittance(pts, nrm, dirs);
    }
    return to_numpy(std::move(out), {pts.size(), dirs.size()});
}

// `source.lift_samples` (Engine, RayScene): the arrays checked, the work done without the GIL.
template <typename Source>
auto lift_samples_of(const Source& source, const In<double>& p, const In<double>& n, double epsilon, double reach,
                     const std::optional<In<double>>& a) {
    auto pts = vec3_rows(p, "points");
    auto nrm = vec3_rows(n, "normals", long(pts.size()));
    std::vector<Vec3> anc;
    if (a) anc = vec3_rows(*a, "anchors", long(pts.size()));
    nb::gil_scoped_release release;
    return source.lift_samples(std::move(pts), nrm, epsilon, reach, a ? &anc : nullptr);
}

// `source.ray_cast` (Engine, RayScene): first hits of rays (origins, directions: (n, 3)).
template <typename Source>
RayCastResult ray_cast_of(const Source& source, const In<double>& o, const In<double>& d) {
    auto org = vec3_rows(o, "origins");
    auto dir = vec3_rows(d, "directions", long(org.size()));
    nb::gil_scoped_release release;
    return source.ray_cast(org, dir);
}

// Runs `work` on a worker thread; meanwhile calls `tick()` (with the GIL) every 100 ms and
// checks for Ctrl-C. Exceptions from the work are rethrown here.
template <typename Work, typename Tick>
void run_reporting(Work&& work, Tick&& tick) {
    std::exception_ptr error;
    std::atomic<bool> finished{false};
    std::thread worker([&] {
        try { work(); } catch (...) { error = std::current_exception(); }
        finished = true;
    });
    while (!finished) {
        {
            nb::gil_scoped_release release;
            for (int k = 0; k < 10 && !finished; ++k) std::this_thread::sleep_for(std::chrono::milliseconds(10));
        }
        try {
            tick();
            if (PyErr_CheckSignals() != 0) throw nb::python_error();
        } catch (...) {
            // The engine can't be interrupted mid-stage: wait for it, then report.
            nb::gil_scoped_release release;
            worker.join();
            throw;
        }
    }
    worker.join();
    if (error) std::rethrow_exception(error);
    tick();
}

// A call from the engine's worker thread into Python (distributed refinement's dispatch): the
// worker posts it and waits; the calling thread, which holds the GIL, serves it at its next
// tick. A Python error fails the worker's call (so the engine unwinds) and is raised here.
struct RemoteCall {
    std::mutex m;
    std::condition_variable cv;
    bool pending = false, done = false;
    int round = 0;
    uint32_t groups = 0;
    std::string error;

    void run(int r, uint32_t g) {  // on the engine's worker thread
        std::unique_lock<std::mutex> lock(m);
        round = r;
        groups = g;
        pending = true;
        done = false;
        error.clear();
        cv.wait(lock, [&] { return done; });
        if (!error.empty()) throw std::runtime_error(error);
    }
    void serve(const nb::object& fn) {  // with the GIL
        int r = 0;
        uint32_t g = 0;
        {
            std::lock_guard<std::mutex> lock(m);
            if (!pending) return;
            r = round;
            g = groups;
        }
        try {
            fn(r, g);
        } catch (const std::exception& e) {
            finish(std::string("distributed refinement of round ") + std::to_string(r) + ": " + e.what());
            throw;
        }
        finish({});
    }
    void finish(std::string failure) {
        {
            std::lock_guard<std::mutex> lock(m);
            pending = false;
            done = true;
            error = failure.empty() ? std::string() : std::move(failure);
        }
        cv.notify_all();
    }
};

template <typename Work>
void run_released(Work&& work) {
    run_reporting(std::forward<Work>(work), [] {});
}

void bind_options(nb::module_& m);
void bind_engine(nb::module_& m);
void bind_display(nb::module_& m);
void bind_results(nb::module_& m);
void bind_fields(nb::module_& m);
void bind_formats(nb::module_& m);
void bind_formfactors(nb::module_& m);
void bind_luminaires(nb::module_& m);

}  // namespace hirad::py
