"""Trapezoids, limits, step quantization, the probing move's recorded segments."""

from __future__ import annotations

import pytest

from conftest import tap
from tapcell.sim import MoveError, VirtualPrinter
from tapcell.sim.motion import Segment, move_limits, plan_trapezoid, quantize_to_steps


def test_trapezoid_accelerates_cruises_and_decelerates_over_the_exact_distance():
    segs = plan_trapezoid((0, 0, 0), (100, 0, 0), 2.0, 100.0, 1000.0)
    assert [s.accel for s in segs] == [1000.0, 0.0, -1000.0]
    assert [s.move_t for s in segs] == pytest.approx([0.1, 0.9, 0.1])
    assert segs[0].print_time == 2.0 and segs[-1].end_time == pytest.approx(3.1)
    assert segs[-1].end == pytest.approx((100.0, 0.0, 0.0))


def test_short_move_is_a_triangle():
    segs = plan_trapezoid((0, 0, 0), (0, 0, 1.0), 0.0, 100.0, 100.0)
    assert len(segs) == 2 and segs[0].move_t == pytest.approx(0.1)
    assert segs[1].start_v == pytest.approx(10.0)


def test_z_limits_cap_a_mostly_vertical_move():
    speed, accel = move_limits((0.6, 0.0, 0.8), 300.0, 3000.0, 15.0, 200.0, 100.0)
    assert speed == pytest.approx(15.0 / 0.8) and accel == pytest.approx(250.0)


def test_positions_are_step_quantized():
    assert quantize_to_steps([10.0012, 0.0, 1.0013], [0.0125, 0.0125, 0.0025]).tolist() == pytest.approx(
        [10.0, 0.0, 1.0025])
    vp = VirtualPrinter.from_scenario("clean")
    vp.move_to(x=10.003, z=1.0013, speed_mm_s=50.0)
    assert vp.position == pytest.approx((10.0, vp.position[1], 1.0025))


def test_move_time_and_out_of_range_errors():
    vp = VirtualPrinter.from_scenario("clean")
    t0 = vp.now_s
    vp.move_to(x=vp.position[0] + 30.0, speed_mm_s=300.0)    # reaches 300 mm/s exactly at mid-move
    assert vp.now_s - t0 == pytest.approx(2.0 * (30.0 / 3000.0) ** 0.5)
    with pytest.raises(MoveError, match=r"move out of range: x=300.000 \(allowed 0.000 .. 235.000\)"):
        vp.move_to(x=300.0)
    with pytest.raises(MoveError, match=r"move out of range: z=-2.500 \(allowed -2.000 .. 250.000\)"):
        vp.move_to(z=-2.5)
    with pytest.raises(MoveError, match="dwell time must not be negative, got -1"):
        vp.dwell(-1)


def test_home_xy_goes_to_the_endstops():
    vp = VirtualPrinter.from_scenario("clean")
    vp.home_xy()
    assert vp.position[:2] == (0.0, 0.0)


def test_probing_move_records_accel_cruise_and_halt_marker_then_pullback():
    vp = VirtualPrinter.from_scenario("clean", seed=2)
    t0, result = tap(vp, speed_mm_s=3.0)
    kinds = [(m["accel"] > 0, m["accel"] == 0 and m["move_t"] > 0, m["move_t"] == 0) for m in result.moves]
    assert kinds == [(True, False, False), (False, True, False), (False, False, True)]
    accel, cruise, marker = result.moves
    assert accel["z_r"] == cruise["z_r"] == -1 and cruise["start_v"] == pytest.approx(3.0)
    assert cruise["print_time"] + cruise["move_t"] == pytest.approx(result.halt_time_s)
    assert marker["start_z"] == pytest.approx(result.halt_z_mm) and marker["print_time"] == result.halt_time_s
    # the halt is a whole Z step (8 mm / 3200 steps)
    assert result.halt_z_mm / 0.0025 == pytest.approx(round(result.halt_z_mm / 0.0025), abs=1e-6)
    moves = vp.recorded_moves(t0, vp.now_s)
    assert moves[:3] == result.moves
    assert [m["z_r"] for m in moves[3:]] == [1, 1, 1]          # pullback: accel, cruise, decel
    # every segment's end matches the next one's start (tap-format position formula)
    for a, b in zip(moves, moves[1:]):
        end = a["start_z"] + a["z_r"] * (a["start_v"] + a["accel"] * a["move_t"] / 2) * a["move_t"]
        assert end == pytest.approx(b["start_z"], abs=0.0025)


def test_probing_move_reaches_a_negative_target_without_trigger():
    vp = VirtualPrinter.from_scenario("clean")
    vp.move_to(z=1.0, speed_mm_s=10.0)

    class NeverTriggers:
        def feed(self, t, c):
            from tapcell.mcu.trigger import FeedResult, TriggerError
            return FeedResult(None, None, None, None, TriggerError.NONE, None, 0, t.size, None)

        def check_watchdog(self, now):
            from tapcell.mcu.trigger import TriggerError
            return TriggerError.NONE

    result = vp.probing_move(-1.5, 5.0, NeverTriggers())
    # nothing stops it: the nozzle crushes the bed down to the target (the host's safety would not allow it)
    assert not result.triggered and result.halt_z_mm == pytest.approx(-1.5)
    assert result.moves[-1]["accel"] < 0                          # a normal decelerating end
    with pytest.raises(MoveError, match="probing move target z=-3.000 must be between position_min -2.000"):
        vp.probing_move(-3.0, 5.0, NeverTriggers())


def test_segment_truncation_keeps_the_start_and_stops_at_the_halt():
    seg = Segment(1.0, 1.0, 2.0, 0.0, (0.0, 0.0, 5.0), (0.0, 0.0, -1.0))
    cut = seg.truncated(1.25)
    assert cut.move_t == 0.25 and cut.end == pytest.approx((0.0, 0.0, 4.5))
