"""hirad.daylight is pure Python: its tests run whether or not the C++ engine is built.

``import hirad`` imports hirad.bake, which needs the engine extension (hirad._engine). Where
the engine is not built, the package is registered here without running its __init__, so
``hirad.daylight`` (which needs only numpy, pandas and pvlib) imports on its own.
"""

import sys
import types
from pathlib import Path

TOOLS = Path(__file__).resolve().parents[3] / "tools"
if str(TOOLS) not in sys.path:
    sys.path.insert(0, str(TOOLS))
try:
    import hirad  # noqa: F401
except ImportError:
    for name in [n for n in sys.modules if n == "hirad" or n.startswith("hirad.")]:
        del sys.modules[name]
    pkg = types.ModuleType("hirad")
    pkg.__path__ = [str(TOOLS / "hirad")]
    sys.modules["hirad"] = pkg
