"""Labelled taps from the virtual printer, recorded the way the probe records them.

For benchmarks and tests of the analysis on realistic taps (`tapcell.sim` physics:
hysteresis, stress relaxation, a gradual onset, an integrating ADC, drift, ooze) rather than
the synthetic generator. Each tap: a fresh virtual printer (scenario + seed), the nozzle
`clearance_mm` above the bed, a tare over `tare_samples`, the real firmware trigger (with the
drift filter when asked), a halt, a dwell of `dwell_samples`, the pullback at 1 µm per sample;
samples from the start of the probing move to the end of the pullback, as
`load_cell_probe` collects them. `truth` holds `z_contact` (commanded Z of first touch, mm)
and `label` (`fouled` when an ooze film > 1 µm was on the nozzle, else `clean`).

This module reads simulator truth, so it sits at the tools layer beside `sim_commands` and
`demo`, outside the analysis package: tests, benchmarks and labelled tap sets use it, never the probe.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from tapcell.filters import FilterOptions, design_firmware_filter
from tapcell.mcu.trigger import FirmwareTrigger, TriggerParams
from tapcell.scale import counts_to_grams
from tapcell.sim import VirtualPrinter
from tapcell.tap.model import Move, TapData


@dataclass(frozen=True)
class SimTapSpec:
    scenario: str = "clean"
    speed_mm_s: float = 5.0
    seed: int = 1
    trigger_force_g: float = 75.0
    pullback_distance_mm: float = 0.2
    clearance_mm: float = 0.4
    x_mm: float = 110.0
    y_mm: float = 110.0
    drift_filter_hz: float | None = None  # the firmware's drift high-pass (bowden-drift needs it)
    dwell_samples: int = 4
    tare_samples: int = 32
    overrides: dict = field(default_factory=dict)  # any SimParams name


def record_sim_tap(spec: SimTapSpec, printer: VirtualPrinter | None = None) -> TapData:
    """One tap on `printer` (default: a fresh one from the spec's scenario and seed)."""
    vp = printer or VirtualPrinter.from_scenario(spec.scenario, seed=spec.seed, **spec.overrides)
    sps = vp.params.sample_rate_sps
    contact_mm = float(vp.truth.contact_z_at(spec.x_mm, spec.y_mm))
    vp.move_to(x=spec.x_mm, y=spec.y_mm, z=contact_mm + spec.clearance_mm, speed_mm_s=50.0)
    vp.dwell(spec.tare_samples / sps)
    counts = vp.take_samples().counts
    tare = int(round(np.median(counts[-spec.tare_samples:])))
    counts_per_gram = vp.truth.counts_per_gram
    sos = (design_firmware_filter(FilterOptions(sps, drift_filter_cutoff_frequency=spec.drift_filter_hz))
           if spec.drift_filter_hz else None)
    trigger = FirmwareTrigger(TriggerParams(counts_per_gram=abs(counts_per_gram), reference_tare_counts=tare,
                                            trigger_force_g=spec.trigger_force_g, sample_rate_sps=sps,
                                            inverted=counts_per_gram < 0, sos=sos))
    t_start = vp.now_s
    trigger.arm(tare, t_start)
    z_contact_start = float(vp.truth.contact_z_at(spec.x_mm, spec.y_mm, t_start))
    film_um = vp.truth.film_um
    result = vp.probing_move(max(contact_mm - 1.5, vp.limits["z"][0]), spec.speed_mm_s, trigger)
    vp.dwell(spec.dwell_samples / sps)
    pullback_speed = sps * 0.001  # 1 µm per sample
    vp.move_to(z=result.halt_z_mm + spec.pullback_distance_mm, speed_mm_s=pullback_speed)
    t_end = vp.now_s
    vp.dwell(2.0 / sps)  # the conversion holding the pullback's end is read
    batch = vp.take_samples()
    inside = (batch.t_s >= t_start) & (batch.t_s <= t_end)
    t = batch.t_s[inside]
    moves = [Move.from_record(m) for m in vp.recorded_moves(t_start, t_end) if m["print_time"] >= t_start - 1e-9]
    return TapData(
        time_s=t, force_g=counts_to_grams(batch.counts[inside], tare, counts_per_gram), moves=moves,
        sample_rate_sps=sps,
        probe={"x": spec.x_mm, "y": spec.y_mm, "speed": spec.speed_mm_s,
               "pullback_distance": spec.pullback_distance_mm, "pullback_speed": pullback_speed,
               "trigger_force": spec.trigger_force_g},
        truth={"z_contact": z_contact_start, "label": "fouled" if film_um > 1.0 else "clean",
               "film_um": film_um, "triggered": bool(result.triggered)},
        meta={"scenario": spec.scenario, "seed": spec.seed, "source": "tapcell.sim", "sensor_type": vp.params.chip},
    )

