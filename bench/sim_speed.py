"""Virtual printer speed: simulated seconds per wall-clock second for a 10-minute probing session.

The session is what a bed mesh does: travel to a point, tare, probe with the real firmware
trigger, dwell, pull back slowly, lift, repeat, until 600 simulated seconds have passed.
Goal: at least 50x real time.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from rich.console import Console
from rich.table import Table

from tapcell.mcu.trigger import FirmwareTrigger, TriggerParams
from tapcell.sim import VirtualPrinter

GOAL_X_REAL_TIME = 50.0


def probing_session(scenario: str, session_s: float, seed: int = 1) -> tuple[float, int, int]:
    """Run taps until session_s of simulated time; returns (wall seconds, taps, samples)."""
    vp = VirtualPrinter.from_scenario(scenario, seed=seed)
    rng = np.random.default_rng(seed)
    rate = vp.sensor_info["sample_rate_sps"]
    cpg = vp.truth.counts_per_gram
    taps = samples = 0
    start = time.perf_counter()
    vp.home_xy()
    while vp.now_s < session_s:
        x, y = rng.uniform(20.0, 215.0, 2)
        contact = vp.truth.contact_z_at(x, y)           # the bench plays a host that knows roughly where the bed is
        vp.move_to(x=x, y=y, z=contact + 2.0, speed_mm_s=150.0)
        vp.move_to(z=contact + 0.5, speed_mm_s=10.0)
        vp.dwell(4.0 / 60.0)
        batch = vp.take_samples()
        samples += batch.t_s.size
        tare = int(round(float(np.mean(batch.counts[-20:])))) if batch.counts.size else 0
        trigger = FirmwareTrigger(TriggerParams(counts_per_gram=abs(cpg), reference_tare_counts=tare,
                                                trigger_force_g=75.0, sample_rate_sps=rate, inverted=cpg < 0))
        trigger.arm(tare, vp.now_s)
        result = vp.probing_move(contact - 1.0, 3.0, trigger)
        vp.dwell(0.1)
        vp.move_to(z=result.halt_z_mm + 0.2, speed_mm_s=0.32)
        vp.dwell(0.05)
        samples += vp.take_samples().t_s.size
        taps += 1
    return time.perf_counter() - start, taps, samples


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="bench/sim_speed.py", description=__doc__)
    parser.add_argument("--session-s", type=float, default=600.0, help="simulated session length")
    parser.add_argument("--scenarios", nargs="*", default=["clean", "fast-adc", "slow-adc", "oozy", "noisy-mains"])
    args = parser.parse_args(argv)
    table = Table(title=f"virtual printer: {args.session_s:.0f} s probing session (goal >= {GOAL_X_REAL_TIME:.0f}x)")
    for column in ("scenario", "sample rate", "taps", "samples", "wall s", "x real time", "vs goal"):
        table.add_column(column, justify="right")
    for name in args.scenarios:
        wall_s, taps, samples = probing_session(name, args.session_s)
        ratio = args.session_s / wall_s
        rate = VirtualPrinter.from_scenario(name).sensor_info["sample_rate_sps"]
        table.add_row(name, f"{rate:g} sps", str(taps), str(samples), f"{wall_s:.2f}", f"{ratio:.0f}x",
                      f"{ratio / GOAL_X_REAL_TIME:.1f}")
    Console().print(table)
    return 0


if __name__ == "__main__":
    import sys

    raise SystemExit(main(sys.argv[1:]))
