"""The analysis's compiled kernels (src/tapcell/tap/c/, built by setup.py when a C compiler is there).

Each kernel does one hot loop of the analysis in C and has a numpy twin next to its call site:
the twin is the reference (tests/tap/test_native.py runs both on the same data) and what runs
when the kernel was not built, so the analysis installs and runs with numpy alone. They agree bit
for bit where the kernel repeats the twin's arithmetic, and to rounding where it sums in another
order (docs/tap-analysis.md, "Compiled kernels").

TAPCELL_NATIVE: unset or 1, use the kernels that were built; 0, never (the numpy twins run);
required, a kernel that is not there is an ImportError (`make test`: a failed build must not pass
quietly as a slower analysis).
"""

from __future__ import annotations

import importlib
import os
from types import ModuleType

ENV = "TAPCELL_NATIVE"


def required() -> bool:
    """Whether a kernel that is not there is an error (TAPCELL_NATIVE=required)."""
    return os.environ.get(ENV, "1") == "required"


def load(name: str) -> ModuleType | None:
    """The compiled kernel module `tapcell.tap._c_<name>`, or None (not built, or TAPCELL_NATIVE=0)."""
    if os.environ.get(ENV, "1") == "0":
        return None
    try:
        return importlib.import_module(f"tapcell.tap._c_{name}")
    except ImportError:
        if required():
            raise
        return None
