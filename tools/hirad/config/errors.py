"""ConfigError: every config problem as `file:line: key: problem`."""

from __future__ import annotations





DICT_SOURCE = "<dict>"


# --------------------------------------------------------------------------
# Errors
# --------------------------------------------------------------------------


class ConfigError(Exception):
    """A problem with a config, located in its file.

    Attributes:
        file: the config file as given to :func:`load_config` (``"<dict>"`` for
            :func:`config_from_dict`).
        line: 1-based line in that file; 0 when the problem concerns the file
            as a whole (missing, unreadable) or has no line (dict input).
        key: dotted key path such as ``"meshing.max_patch_area"`` or
            ``"materials.default_reflectance[1]"``; empty when no key applies.
        problem: what is wrong, in plain words.
        errors: every problem found, this one first (validation reports all
            problems at once; ``str()`` shows the first, by line).
    """

    def __init__(self, file: str, line: int, key: str, problem: str) -> None:
        self.file = file
        self.line = line
        self.key = key
        self.problem = problem
        self.errors: list[ConfigError] = [self]
        super().__init__(str(self))

    def __str__(self) -> str:
        where = f"{self.file}:{self.line}" if self.line > 0 else self.file
        if self.key:
            return f"{where}: {self.key}: {self.problem}"
        return f"{where}: {self.problem}"

    def full_report(self) -> str:
        """All problems, one per line."""
        return "\n".join(str(e) for e in self.errors)
