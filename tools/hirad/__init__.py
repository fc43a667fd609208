"""hirad: hierarchical radiosity for USD scenes.

The Python API mirrors the CLI:

    import hirad
    result = hirad.bake("configs/cornell.yaml")
    result.irradiance_at(points, normals)

Heavy work runs in the C++ engine (``hirad._engine``); this package reads USD, validates
configs, orchestrates the stages and writes the outputs.
"""

__version__ = "0.1.0"


from .bake import BakeError, Result, SurfaceSolution, bake, load_solution  # noqa: E402
from .outputs.probes import read_probes  # noqa: E402

__all__ = ["bake", "load_solution", "Result", "SurfaceSolution", "BakeError", "read_probes", "__version__"]
