"""The virtual printer's emergency stop: asked for from anywhere while time runs under a command,
the steppers stop where the next sample to be produced starts, and nothing moves after it."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import armed_trigger
from tapcell.host.backend import EmergencyStopError
from tapcell.sim import VirtualPrinter


def ask_for_the_stop_during(vp: VirtualPrinter, ask_at_s: float) -> dict:
    """Ask for the emergency stop as the machine produces the sample of `ask_at_s` (a second API
    connection does it from another thread at some wall time; here it lands at a known sample).
    Returns {"next_sample_s": where the first sample made after the request starts}."""
    compute = vp._compute
    asked: dict = {}

    def compute_then_ask(k0: int, k1: int):
        chunk = compute(k0, k1)
        if not asked and vp._timing.window_start_s(k1) > ask_at_s:
            vp.emergency_stop()
            asked["next_sample_s"] = vp._timing.window_start_s(k1)
        return chunk

    vp._compute = compute_then_ask
    return asked


def test_a_long_move_stops_at_the_next_sample_and_nothing_moves_after():
    vp = VirtualPrinter.from_scenario("clean")
    vp.move_to(x=10.0, y=10.0, z=5.0, speed_mm_s=100.0)
    start_s = vp.now_s
    asked = ask_for_the_stop_during(vp, start_s + 4.0)
    with pytest.raises(EmergencyStopError, match=r"emergency stop: the steppers stopped at"):
        vp.move_to(x=200.0, speed_mm_s=5.0)  # 38 s of motion
    halt_s = vp.halted_at_s
    assert halt_s == pytest.approx(asked["next_sample_s"])
    assert 4.0 < halt_s - start_s < 4.0 + 256 / vp.params.sample_rate_sps
    # Time ends at the halt; the steppers rest where the move was then (5 mm/s since start_s).
    assert vp.now_s == pytest.approx(halt_s)
    x_mm = vp.position[0]
    assert x_mm == pytest.approx(10.0 + 5.0 * (halt_s - start_s), abs=0.01)
    later = vp._motion.positions_at(np.array([halt_s, halt_s + 1.0, halt_s + 100.0]))
    assert np.ptp(later[:, 0]) == 0.0
    # Every command that lets time run fails at once; sampling goes on.
    for command in (lambda: vp.move_to(x=100.0), lambda: vp.dwell(1.0), lambda: vp.home_xy()):
        with pytest.raises(EmergencyStopError):
            command()
        assert vp.now_s == pytest.approx(halt_s) and vp.position[0] == x_mm
    assert vp.take_samples().t_s.size > 0
    vp.release_emergency_stop()
    vp.move_to(x=100.0, speed_mm_s=100.0)
    assert vp.position[0] == pytest.approx(100.0, abs=0.01)


def test_a_probing_move_stops_at_the_next_sample_above_the_bed():
    vp = VirtualPrinter.from_scenario("clean")
    contact_z = float(vp.truth.contact_z_at(*vp.position[:2]))
    vp.move_to(z=contact_z + 3.0, speed_mm_s=10.0)
    trigger = armed_trigger(vp)
    start_s = vp.now_s
    asked = ask_for_the_stop_during(vp, start_s + 0.2)  # 1 mm into the 3 mm descent at 5 mm/s
    with pytest.raises(EmergencyStopError):
        vp.probing_move(contact_z - 0.5, 5.0, trigger)
    assert vp.halted_at_s == pytest.approx(asked["next_sample_s"])
    assert vp.halted_at_s - start_s < 0.2 + 0.05 + 1.0 / vp.params.sample_rate_sps  # within one probing chunk
    assert vp.position[2] > contact_z + 1.5
    assert vp.truth.take_peak_force_g() < 1.0


def test_a_dwell_ends_at_the_stop():
    vp = VirtualPrinter.from_scenario("clean")
    start_s = vp.now_s
    ask_for_the_stop_during(vp, start_s + 2.0)
    with pytest.raises(EmergencyStopError):
        vp.dwell(3600.0)
    assert vp.now_s - start_s < 2.0 + 256 / vp.params.sample_rate_sps
