"""The bundled Cornell configs give the same values as before the redesign.

tests/python/data/cornell_golden.json was written by `tests/python/golden.py --write` on the
commit *before* the engine's code was moved, and once more for the hierarchical configs when
the rounds' solves began to start from the emission (see golden.py's docstring): the hashes of every
primvar and hirad attribute array of the solution meshes, every EXR's pixels, the preview
PNG, the volume's grids and the report's numbers other than timings. A change of any value,
by one bit, fails here and names what changed.
"""

from __future__ import annotations

import json

import pytest

from golden import CONFIGS, GOLDEN, bake_config, fingerprint


@pytest.mark.parametrize("name", CONFIGS)
def test_bundled_config_values_unchanged_by_the_redesign(name, tmp_path):
    expected = json.loads(GOLDEN.read_text())[name]
    got = fingerprint(bake_config(name, tmp_path / "out"))
    for section in ("usd", "exr", "vdb", "report"):
        want, have = expected[section], got[section]
        missing = sorted(set(want) - set(have))
        changed = sorted(k for k in set(want) & set(have) if want[k] != have[k])
        assert not missing, f"{name}: {section} entries no longer written: {missing[:10]}"
        assert not changed, f"{name}: {section} values changed: {changed[:10]}"
