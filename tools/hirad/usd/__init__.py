"""USD input and output for hirad.

Reading (:func:`read_scene`) flattens a USD stage into the flat numpy arrays the C++ engine
consumes: world-space polygons in metres, per-face reflectance and emitted exitance, per-corner
UVs, plus the cameras of the stage.  Writing (:func:`write_solution_layer`) produces a small layer
that sublayers the input, hides the input geometry and adds one mesh per solved scene mesh under
``<defaultPrim>/HiradSolution`` carrying the radiosity as primvars.  :func:`read_solution_layer` loads such a
layer back without re-solving.

Conventions
-----------
* Lengths returned by this module are metres; the stage's ``metersPerUnit`` is applied on read
  and undone on write.
* Faces are polygons as authored (no triangulation) with counter-clockwise = front under the
  right-hand rule; left-handed meshes and mirrored transforms are flipped on read.
* ``face_emission`` is emitted exitance M = pi * L in W/m^2; radiance values written to the
  solution layer are W/(m^2 sr), irradiance W/m^2.

Modules, in the order data flows: `common` (stage, transforms, names), `materials`
(reflectance and emission), `scene` (reading), `solution` (the solution layer written and
read back).
"""

from .common import SceneError
from .scene import CameraInfo, MeshInfo, SceneArrays, read_cameras, read_scene
from .solution import SOLUTION_ROOT, PatchMeshData, SolutionData, read_solution_layer, write_solution_layer

__all__ = [
    "SceneError",
    "MeshInfo",
    "CameraInfo",
    "SceneArrays",
    "PatchMeshData",
    "SolutionData",
    "read_scene",
    "read_cameras",
    "write_solution_layer",
    "read_solution_layer",
    "SOLUTION_ROOT",
]
