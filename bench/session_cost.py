"""Cost per tap over a long probing session: does the tenth hundred taps cost what the first did?

PROBE_ACCURACY on the example printer (clean scenario), block after block;
each block's CPU per tap and the process's peak memory, with the ratio to the first block as
the anchor. The virtual printer keeps 600 s of motion and samples (sim.motion.HISTORY_KEEP_S),
about 830 taps, so the default runs past that. Goal: the last block within 15 % of the first
(it was +76 % CPU and +38 MB after 2,000 taps when everything was kept and scanned).
"""

from __future__ import annotations

import argparse
import resource
import sys
import tempfile
import time
from pathlib import Path

from rich.console import Console
from rich.table import Table

from bench.probe_session import make_printer

GOAL_RATIO = 1.15


def peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="bench/session_cost.py", description=__doc__)
    parser.add_argument("--blocks", type=int, default=10, help="blocks of taps (default 10: past the 600 s horizon)")
    parser.add_argument("--taps", type=int, default=100, help="taps per block (default 100)")
    args = parser.parse_args(argv)
    console = Console()
    with tempfile.TemporaryDirectory(prefix="tapcell-session-cost-") as workdir:
        printer = make_printer("clean", Path(workdir))
        printer.gcode.run_script("PROBE HOME=Z\nG1 Z0.4")
        printer.gcode.set_response_sink(None)
        table = Table(title=f"cost per tap over a session ({args.blocks} x {args.taps} taps; goal: last block "
                            f"<= {GOAL_RATIO:.2f} x the first)")
        for column in ("taps", "simulated s", "CPU ms/tap", "vs block 1", "peak RSS MB", "+MB since block 1"):
            table.add_column(column, justify="right")
        first = None
        for block in range(1, args.blocks + 1):
            cpu_start = time.process_time()
            printer.gcode.run_script(f"PROBE_ACCURACY SAMPLES={args.taps} SAMPLE_RETRACT_DIST=0.4")
            cpu_ms = (time.process_time() - cpu_start) * 1000.0 / args.taps
            rss_mb = peak_rss_mb()
            first = first or (cpu_ms, rss_mb)
            row = (f"{block * args.taps}", f"{printer.get_time():.0f}", f"{cpu_ms:.1f}", f"{cpu_ms / first[0]:.2f}",
                   f"{rss_mb:.1f}", f"{rss_mb - first[1]:+.1f}")
            table.add_row(*row)
            print(f"  block {block}/{args.blocks}: {row[0]} taps, {row[2]} ms/tap ({row[3]}x)", flush=True)
    console.print(table)
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
