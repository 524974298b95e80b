"""Errors raised by the mesh math.

They carry the pieces a user needs (section, option, value, what is allowed) as attributes
so the config and G-code layers can re-raise them in their own error types unchanged.
"""

from __future__ import annotations


class MeshError(ValueError):
    """Bad mesh input; the message names what was wrong and what is allowed."""


class MeshOptionError(MeshError):
    """A config option (or the G-code parameter of the same name) has a value that is not allowed."""

    def __init__(self, section: str, option: str, value: object, allowed: str) -> None:
        self.section = section
        self.option = option
        self.value = value
        self.allowed = allowed
        super().__init__(f"[{section}] {option} = {value}: {allowed}")
