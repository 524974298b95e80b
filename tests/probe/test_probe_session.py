"""The probe session logic (samples, tolerance, bad-probe strategies) with a scripted tapper.

The tapper and motion here are test doubles: they replay a list of tap outcomes so that each
strategy's decisions can be checked exactly. The real tap on the virtual printer is tested in
test_load_cell_probe.py.
"""

from __future__ import annotations

import contextlib

import numpy as np
import pytest

from tapcell.host.gcode import GCodeDispatch
from tapcell.extras.probe.session import Probe, ProbeError, TapOutcome
from tapcell.extras.probe.options import ProbeOptions


class ScriptedTapper:
    def __init__(self, motion, outcomes):
        self.motion = motion
        self.outcomes = list(outcomes)
        self.tapped_at = []

    def command_settings(self, gcmd):
        return None

    def tap(self, settings, z_min_mm, speed_mm_s):
        x, y, _ = self.motion.get_position()
        self.tapped_at.append((round(x, 6), round(y, 6), speed_mm_s))
        z, valid, code = self.outcomes.pop(0)
        self.motion.z = z + 0.2  # where the pullback leaves the nozzle
        return TapOutcome(z_mm=z, valid=valid, error_code=code, message="bad" if code else "")

    def home_tap(self, settings, z_min_mm, speed_mm_s):
        self.motion.z = 3.0
        return 3.0

    def guarded(self):
        return contextlib.nullcontext()  # the lift after an error is the load cell probe's (test_probing_safety)

    def pooled_z_shifts_mm(self, analyses):
        return None  # a probe without tap analysis: each tap's own Z


class Motion:
    def __init__(self):
        self.x, self.y, self.z = 50.0, 60.0, 0.4
        self.moves = []

    def get_position(self):
        return (self.x, self.y, self.z)

    def move_to(self, x=None, y=None, z=None, speed_mm_s=None):
        self.moves.append((x, y, z, speed_mm_s))
        self.x = self.x if x is None else x
        self.y = self.y if y is None else y
        self.z = self.z if z is None else z

    def z_position_min(self):
        return -2.0

    def z_travel_mm(self):
        return 200.0

    def set_z_position(self, z_mm):
        self.z = z_mm

    def is_z_homed(self):
        return True


def make_probe(outcomes, **options):
    motion = Motion()
    responses = []
    gcode = GCodeDispatch(responses)
    probe = Probe("probe", ProbeOptions(**{"z_offset_mm": 0.0, **options}), ScriptedTapper(motion, outcomes), motion, gcode)
    probe.register_commands()
    return probe, motion, gcode, responses


def test_samples_average_and_median():
    probe, *_ = make_probe([(0.010, True, None), (0.012, True, None), (0.020, True, None)], samples=3)
    result = probe.probe_point(50.0, 60.0)
    assert result.z_mm == pytest.approx(0.014)
    assert result.samples_z_mm == (0.010, 0.012, 0.020) and result.attempts == 3 and result.valid
    probe, *_ = make_probe([(0.010, True, None), (0.012, True, None), (0.020, True, None)], samples=3,
                           samples_result="median", z_offset_mm=0.002)
    assert probe.probe_point(50.0, 60.0).z_mm == pytest.approx(0.010)


def test_samples_tolerance_retry_then_fail():
    outcomes = [(0.0, True, None), (0.2, True, None), (0.0, True, None), (0.01, True, None)]
    probe, _, _, responses = make_probe(outcomes, samples=2, samples_tolerance_retries=1)
    assert probe.probe_point(50, 60).z_mm == pytest.approx(0.005)
    assert "// Probe samples exceed tolerance. Retrying..." in responses
    probe, *_ = make_probe([(0.0, True, None), (0.2, True, None)], samples=2)
    with pytest.raises(ProbeError, match="Probe samples exceed samples_tolerance"):
        probe.probe_point(50, 60)


def test_retry_strategy_taps_in_place_and_gives_up():
    probe, motion, _, responses = make_probe([(0.3, False, "TAP_SHAPE_INVALID"), (0.01, True, None)],
                                             retry_speed_mm_s=2.0)
    result = probe.probe_point(50, 60)
    assert result.z_mm == pytest.approx(0.01) and result.attempts == 2
    assert probe.tapper.tapped_at == [(50, 60, 5.0), (50, 60, 2.0)]
    # The first failure carries the likely cause and the fix (issue 20: only the last one did).
    assert ("// Bad probe detected: TAP_SHAPE_INVALID - bad. Retrying (1/6)... Likely cause: plastic on the nozzle "
            "(ooze) distorts the tap so much that it no longer looks like a tap. Fix: clean the nozzle") in \
        "\n".join(responses)
    # retracted sample_retract_dist above the bad tap's contact between the two taps
    assert (None, None, pytest.approx(2.3), 5.0) in motion.moves
    probe, _, _, responses = make_probe([(0.3, False, "LOW_TAP_QUALITY")] * 3, bad_probe_retries=2)
    with pytest.raises(ProbeError, match=r"Probing failed after 3 bad probes \(last: LOW_TAP_QUALITY - bad\)"):
        probe.probe_point(50, 60)
    retries = [line for line in responses if line.startswith("// Bad probe detected")]
    assert [("Likely cause" in line) for line in retries] == [True, False]  # once per code, not every retry


def test_fail_and_ignore_strategies():
    probe, *_ = make_probe([(0.3, False, "TAP_CHRONOLOGY")], bad_probe_strategy="fail")
    with pytest.raises(ProbeError, match="Probe failed because it was deemed bad quality: TAP_CHRONOLOGY"):
        probe.probe_point(50, 60)
    probe, _, _, responses = make_probe([(0.3, False, "TAP_CHRONOLOGY")], bad_probe_strategy="ignore")
    result = probe.probe_point(50, 60)
    assert (result.valid, result.z_mm) == (False, 0.3)
    assert any("Bad probe ignored" in r for r in responses)


def test_circle_moves_to_clean_spots_and_remembers_fouled_places():
    outcomes = [(0.3, False, "TAP_SHAPE_INVALID"), (0.3, False, "TAP_SHAPE_INVALID"), (0.01, True, None),
                (0.3, False, "LOW_TAP_QUALITY"), (0.02, True, None)]
    probe, motion, _, _ = make_probe(outcomes, bad_probe_strategy="circle")
    with probe.session() as session:
        first = session.probe_point(50.0, 60.0)
        assert (first.x_mm, first.y_mm) == (50.0, 60.0)
        assert (first.tapped_x_mm, first.tapped_y_mm) == pytest.approx((51.0, 60.0 + 3 ** 0.5))
        # a neighbouring point 0.5 mm away: its own spot is near a fouled place -> skipped
        second = session.probe_point(50.5, 60.0)
    tapped = [(x, y) for x, y, _ in probe.tapper.tapped_at]
    assert tapped[:3] == [(50.0, 60.0), (52.0, 60.0), pytest.approx((51.0, 61.732051))]
    # (50.5, 60) is 0.5 mm from the fouled (50, 60) and (52.5, 60) 0.5 mm from the fouled (52, 60)
    assert tapped[3] == pytest.approx((51.5, 61.732051))
    assert second.attempts == 2 and second.z_mm == pytest.approx(0.02)


def test_scrubber_runs_every_n_bad_taps():
    ran = []
    probe, *_ = make_probe([(0.3, False, "X"), (0.3, False, "X"), (0.3, False, "X"), (0.0, True, None)],
                           scrubbing_frequency=2, templates={"nozzle_scrubber_gcode": "SCRUB"})
    probe.template_runner = lambda option, template, params: ran.append((option, params))
    probe.probe_point(50, 60)
    assert ran == [("nozzle_scrubber_gcode", {"ATTEMPT": 2, "RETRIES": 6})]


def test_probe_command_and_home_z():
    probe, motion, gcode, responses = make_probe([(0.25, True, None)])
    gcode.run_script("PROBE HOME=Z")
    assert "// Result is z=0.250000" in responses
    assert motion.z == pytest.approx(0.45 - 0.25)  # the nozzle sat 0.2 above contact -> now Z 0.2
    assert probe.get_status()["last_z_result"] == pytest.approx(0.25)
    z = probe.home_z()
    assert z == pytest.approx(2.0)  # trigger at Z=z_offset=0, then lift sample_retract_dist


def test_probe_accuracy_command():
    outcomes = [(0.010, True, None), (0.012, True, None), (0.008, True, None), (0.014, True, None)]
    probe, motion, gcode, responses = make_probe(outcomes)
    gcode.run_script("PROBE_ACCURACY SAMPLES=4 SAMPLE_RETRACT_DIST=0.4")
    assert responses[0] == "// PROBE_ACCURACY at X:50.000 Y:60.000 Z:0.400 (samples=4 retract=0.400 speed=5.0 lift_speed=5.0)"
    assert responses[-1] == ("// probe accuracy results: maximum 0.014000, minimum 0.008000, range 0.006000, "
                             "average 0.011000, median 0.011000, standard deviation 0.002236, average delta 0.004000")
    probe, motion, gcode, responses = make_probe([(0.0, True, None), (0.3, False, "TAP_SHAPE_INVALID")])
    with pytest.raises(ProbeError, match="deemed bad quality: TAP_SHAPE_INVALID"):
        gcode.run_script("PROBE_ACCURACY SAMPLES=3")


class PoolingTapper(ScriptedTapper):
    """Pools its taps by moving each to the taps' mean (a stand-in for tapcell.tap.pool)."""

    def __init__(self, motion, outcomes):
        super().__init__(motion, outcomes)
        self.pooled = []

    def tap(self, settings, z_min_mm, speed_mm_s):
        outcome = super().tap(settings, z_min_mm, speed_mm_s)
        outcome.analysis = outcome.z_mm  # the tap's own Z stands for its analysis
        return outcome

    def pooled_z_shifts_mm(self, analyses):
        self.pooled.append(list(analyses))
        return [0.5 * (np.mean(analyses) - z) for z in analyses]  # half-way to the mean


def make_pooling_probe(outcomes, **options):
    probe, motion, gcode, responses = make_probe([], **options)
    probe.tapper = PoolingTapper(motion, outcomes)
    return probe, motion, gcode, responses


def test_probe_accuracy_prints_the_pooled_zs_in_klippers_line_and_the_single_taps_before_it():
    outcomes = [(0.010, True, None), (0.012, True, None), (0.008, True, None), (0.014, True, None)]
    probe, motion, gcode, responses = make_pooling_probe(outcomes)
    gcode.run_script("PROBE_ACCURACY SAMPLES=4 SAMPLE_RETRACT_DIST=0.4")
    assert probe.tapper.pooled == [[0.010, 0.012, 0.008, 0.014]]
    # Pooled: 0.0105, 0.0115, 0.0095, 0.0125 (half-way to the mean 0.011).
    assert responses[-2:] == [
        "// single-tap results (each tap analysed alone; the results below pool the 4 taps): maximum 0.014000, "
        "minimum 0.008000, range 0.006000, average 0.011000, median 0.011000, standard deviation 0.002236, "
        "average delta 0.004000",
        "// probe accuracy results: maximum 0.012500, minimum 0.009500, range 0.003000, "
        "average 0.011000, median 0.011000, standard deviation 0.001118, average delta 0.002000"]
    assert probe.last_accuracy_pooled and probe.get_status()["last_z_result"] == pytest.approx(0.011)


def test_samples_combine_the_pooled_zs_of_taps_at_one_spot():
    probe, *_ = make_pooling_probe([(0.010, True, None), (0.012, True, None), (0.020, True, None)], samples=3,
                                   samples_result="median", z_offset_mm=0.002)
    result = probe.probe_point(50.0, 60.0)
    assert result.pooled and result.single_z_mm == (0.010, 0.012, 0.020)
    assert result.samples_z_mm == pytest.approx((0.012, 0.013, 0.017))  # half-way to the mean 0.014
    assert result.z_mm == pytest.approx(0.013 - 0.002)
    # One sample: nothing to pool.
    probe, *_ = make_pooling_probe([(0.010, True, None)])
    assert not probe.probe_point(50.0, 60.0).pooled and probe.tapper.pooled == []


def test_samples_at_two_spots_are_not_pooled():
    # CIRCLE moved the second sample away from the fouled spot: the taps do not share one spot.
    outcomes = [(0.010, True, None), (0.3, False, "TAP_SHAPE_INVALID"), (0.012, True, None)]
    probe, *_ = make_pooling_probe(outcomes, samples=2, bad_probe_strategy="circle")
    result = probe.probe_point(50.0, 60.0)
    assert not result.pooled and result.samples_z_mm == (0.010, 0.012) and probe.tapper.pooled == []
    assert result.z_mm == pytest.approx(0.011)
    outcomes = [(0.010, True, None), (0.3, False, "TAP_SHAPE_INVALID"), (0.012, True, None), (0.014, True, None)]
    probe, motion, gcode, responses = make_pooling_probe(outcomes)
    gcode.run_script("PROBE_ACCURACY SAMPLES=3 SAMPLE_RETRACT_DIST=0.4 BAD_PROBE_STRATEGY=circle")
    assert not probe.last_accuracy_pooled and probe.tapper.pooled == []
    assert responses[-1].startswith("// probe accuracy results: maximum 0.014000, minimum 0.010000,")
    assert not any(line.startswith("// single-tap") for line in responses)


def test_query_probe_always_open():
    probe, motion, gcode, responses = make_probe([])
    gcode.run_script("QUERY_PROBE")
    assert responses == ["// probe: open"] and probe.get_status()["last_query"] is False
