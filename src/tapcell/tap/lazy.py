"""An attribute computed on its first read and kept: functools.cached_property without its lock.

Python 3.11's cached_property takes a lock on every first read (3.12 dropped it); a tap's analysis
reads a few such attributes once each, thousands of taps a run, from one thread.
"""

from __future__ import annotations

from typing import Any, Callable


class cached_attribute:  # lower case: named like the decorator it stands in for
    """Decorate a method taking only self: its value, computed on the first read, is stored in the
    instance's __dict__ under the method's name, where later reads find it without calling here."""

    def __init__(self, compute: Callable[[Any], Any]):
        self.compute = compute
        self.name = compute.__name__
        self.__doc__ = compute.__doc__

    def __set_name__(self, owner: type, name: str) -> None:
        self.name = name

    def __get__(self, instance: Any, owner: type | None = None) -> Any:
        if instance is None:
            return self
        value = instance.__dict__[self.name] = self.compute(instance)
        return value
