"""Helpers for the virtual printer tests: a tare like the host's and the real firmware trigger."""

from __future__ import annotations

import numpy as np


def tare_counts(vp, settle_s: float = 0.2) -> float:
    """Rest, then average the last samples (what the host's pre-probe tare does)."""
    vp.dwell(settle_s)
    batch = vp.take_samples()
    return float(np.mean(batch.counts[-20:]))


def armed_trigger(vp, trigger_force_g: float = 75.0, drift_safety_limit_g: float = 1000.0):
    from tapcell.mcu.trigger import FirmwareTrigger, TriggerError, TriggerParams

    tare = tare_counts(vp)
    cpg = vp.truth.counts_per_gram
    trigger = FirmwareTrigger(TriggerParams(
        counts_per_gram=abs(cpg), reference_tare_counts=int(round(tare)), trigger_force_g=trigger_force_g,
        sample_rate_sps=vp.sensor_info["sample_rate_sps"], force_safety_limit_g=2000.0,
        drift_safety_limit_g=drift_safety_limit_g, release_force_g=0.0, watchdog_periods=2,
        inverted=cpg < 0, sos=None, clock_hz=1e6))
    assert trigger.arm(int(round(tare)), vp.now_s) == TriggerError.NONE
    return trigger


def tap(vp, speed_mm_s: float = 3.0, start_above_mm: float = 0.5, trigger_force_g: float = 75.0,
        pullback_mm: float = 0.2, pullback_speed_mm_s: float = 0.32, dwell_s: float = 0.1):
    """One tap at the current XY: approach from above the true contact, probe, dwell, pull back."""
    x, y, _ = vp.position
    contact_z = vp.truth.contact_z_at(x, y)
    vp.move_to(z=contact_z + start_above_mm, speed_mm_s=10.0)
    trigger = armed_trigger(vp, trigger_force_g)
    t0 = vp.now_s
    result = vp.probing_move(contact_z - 0.5, speed_mm_s, trigger)
    vp.dwell(dwell_s)
    vp.move_to(z=result.halt_z_mm + pullback_mm, speed_mm_s=pullback_speed_mm_s)
    vp.dwell(0.02)
    return t0, result
