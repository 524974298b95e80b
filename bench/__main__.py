"""Run the benchmarks.

    python -m bench                 every module in bench/, each with its defaults
    python -m bench NAME [ARGS...]  one module, with its own arguments (e.g. `tap_speed 100`)
"""

from __future__ import annotations

import importlib
import pkgutil
import sys
from pathlib import Path


def _module_names() -> list[str]:
    here = Path(__file__).parent
    return sorted(m.name for m in pkgutil.iter_modules([str(here)]) if not m.name.startswith("_"))


def main(argv: list[str]) -> int:
    names = _module_names()
    if argv:
        if argv[0] not in names:
            print(f"bench: no benchmark '{argv[0]}' (one of: {', '.join(names)})", file=sys.stderr)
            return 2
        return int(importlib.import_module(f"bench.{argv[0]}").main(argv[1:]) or 0)
    for name in names:
        print(f"\n=== bench/{name} ===", flush=True)
        importlib.import_module(f"bench.{name}").main([])
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
