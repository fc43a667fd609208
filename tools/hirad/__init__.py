"""hirad: hierarchical radiosity for USD scenes.

The Python API mirrors the CLI:

    import hirad
    result = hirad.bake("configs/cornell.yaml")
    result.irradiance_at(points, normals)

Heavy work runs in the C++ engine (``hirad._engine``); this package reads USD, validates
configs, orchestrates the stages and writes the outputs.
"""

__version__ = "0.1.0"


def __getattr__(name):
    # Lazy so that `hirad.config` and `hirad.usd` import without building the engine.
    if name in ("bake", "Result", "load_solution", "Solution"):
        from . import bake as _bake

        return getattr(_bake, name)
    raise AttributeError(name)
