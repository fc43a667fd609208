"""BakeError: a bake that cannot go on, with the reason in words a user can act on."""

from __future__ import annotations





class BakeError(Exception):
    """A bake that cannot go on: the message names what and where."""
