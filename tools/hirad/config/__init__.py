"""hirad's configuration: the YAML schema, its loader and its error reports.

A config file is one YAML mapping.  Only ``scene`` is required; every other
key has a default (see the field descriptions below, or ``configs/cornell.yaml``
for an annotated example).

    cfg = load_config("configs/cornell.yaml")      # raises ConfigError
    cfg.meshing.max_patch_area                     # 0.0006
    cfg.fingerprint()                              # sha256 hex of the settings
    load_config(path, ["meshing.max_patch_area=0.02"])  # `hirad bake --set`: errors name the --set
    cfg.content_key()                              # sha256 of what determines the result

Every problem is reported as a :class:`ConfigError` whose text reads
``file:line: key: problem``, with the line of the offending key in the YAML
file.  Validation is strict about types: a quoted ``"16"`` where a number is
expected is an error rather than silently converted, and unknown keys (typos)
are errors too.  Numbers may be written as ``1e-4`` (YAML 1.2 style) even
though PyYAML's YAML 1.1 rules would read that as a string.

Relative paths in a config resolve against the directory holding the config
file and are stored as absolute paths.

Reading is bounded: a config must be a regular file of at most 1 MiB (a FIFO or
``/dev/zero`` is refused, not waited on), and YAML aliases may not expand the document beyond
10,000 values.  Values the engine cannot take are refused with the same located errors
(``seed`` beyond 2^64-1, ``links.memory_budget`` beyond 1PB, ``meshing.max_patch_area`` below
1e-8 m^2...).

The default ``method`` is ``hierarchical``, the production method; ``method: flat`` is the
classic one, kept as the reference.  :meth:`Config.ignored_settings` names the sections a
config gives that its method does not read.

Modules: `errors` (ConfigError), `schema` (the pydantic models), `loader` (YAML with
located errors), `describe` (the schema as text: :func:`schema_text`).
"""

from .describe import schema_text
from .errors import DICT_SOURCE, ConfigError
from .content import content_key
from .loader import apply_overrides, config_from_dict, load_config, parse_override
from .schema import (Config, FormFactorConfig, HierarchyConfig, LightmapOutputConfig, LinksConfig, MaterialsConfig,
                     MeshingConfig, OutputsConfig, PreviewOutputConfig, ReconstructionConfig, SolverConfig,
                     VolumeOutputConfig, parse_bytes)

__all__ = [
    "Config",
    "ConfigError",
    "FormFactorConfig",
    "LightmapOutputConfig",
    "MaterialsConfig",
    "MeshingConfig",
    "OutputsConfig",
    "PreviewOutputConfig",
    "ReconstructionConfig",
    "SolverConfig",
    "VolumeOutputConfig",
    "apply_overrides",
    "config_from_dict",
    "content_key",
    "parse_override",
    "load_config",
    "schema_text",
]
