// The Python face of the engine: module hirad._engine. Every file under pipeline/bindings/
// only binds; the algorithms live in pipeline/engine/ and the stages below it.
//   options.cpp      option structs (MeshOptions, FormFactorOptions, SolveOptions, ...)
//   results.cpp      result structs (Stats, PatchArrays, FlatSolveResult, HierarchicalResult, ...)
//   engine.cpp       Engine: scene -> patches -> links -> solution
//   fields.cpp       SurfaceField (one ray-tracing scene per solution)
//   display.cpp      DisplayMesh, Engine.display_arrays
//   formats.cpp      EXR and OpenVDB files
//   formfactors.cpp  closed-form form factors, set_threads
//   luminaires.cpp   Luminaire (point, spot, IES, sphere and cylinder lights)
// The generated stub tools/hirad/_engine.pyi lists every signature (make engine-stubs).
#include "pipeline/bindings/common.h"

NB_MODULE(_engine, m) {
    m.doc() = "hirad's C++ engine: meshing, form factors, solvers, hierarchy, reconstruction, rendering, files";
    hirad::py::bind_formfactors(m);
    hirad::py::bind_formats(m);
    hirad::py::bind_luminaires(m);
    hirad::py::bind_options(m);
    hirad::py::bind_results(m);
    hirad::py::bind_engine(m);
    hirad::py::bind_fields(m);
}
