"""Validation of a tap against the spec's codes ("Tap Validation Error Codes").

Each check raises `TapInvalid(code, message)`; the order is the spec's: moves, chronology,
shape, break-contact timing, after one of our own (the nozzle left the bed by the end of the
pullback, else TAP_PULLBACK_TOO_SHORT); then our own consistency of contact down against
break contact up.
"""

from __future__ import annotations

import math

import numpy as np

from tapcell.tap.model import (
    COASTING_MOVE_ACCELERATION,
    TAP_BREAK_CONTACT_TOO_EARLY,
    TAP_BREAK_CONTACT_TOO_LATE,
    TAP_CHRONOLOGY,
    TAP_CONTACT_MISMATCH,
    TAP_DATA_INSUFFICIENT,
    TAP_MOTION_INVALID,
    TAP_PULLBACK_TOO_SHORT,
    TAP_SHAPE_INVALID,
    TOO_FEW_PROBING_MOVES,
    TOO_MANY_PROBING_MOVES,
    Move,
)
from tapcell.tap.motion import MAX_PROBING_MOVES, MIN_PROBING_MOVES, Motion
from tapcell.tap.toe import TOE_WIDTHS_UM

# Expected signs of the four angles between consecutive lines, positive polarity:
# approach→compression turns up (-), compression→dwell down (+), dwell→decompression down (+),
# decompression→departure up (-). Negative polarity mirrors them.
POSITIVE_SHAPE = (-1, 1, 1, -1)
# A sheet's loading and unloading curves differ by a few µm of travel (hysteresis); the virtual
# printer's smooth PEI reverses over 3 µm. Contact down may read this much above break contact up.
HYSTERESIS_ALLOWANCE_UM = 5.0
# Fit sigmas the contact heights may differ by before they disagree.
CONSISTENCY_SIGMAS = 3.0
# Share of the compression force still on the bed at the end of the pullback that means the
# nozzle never left it (a tap that left reads 0 +- 1 %; ooze pulls the other way).
STILL_PRESSING_SHARE = 0.05
# ... and it must also stand this many times the departure's own scatter (noise, mains hum) above
# the free-air level: a single hum swing at the pullback's end is not a nozzle pressing (issue 21:
# 8 of 80 reference noisy-mains taps broke contact mid-pullback and read TAP_PULLBACK_TOO_SHORT).
STILL_PRESSING_SCATTERS = 4.0


class TapInvalid(Exception):
    def __init__(self, code: str, message: str):
        self.code = code
        self.message = message
        super().__init__(f"{code}: {message}")


def check_moves(moves: list[Move]) -> None:
    """Move count and the coasting check (only when moves are given).

    The move before the halt marker must be the approach's cruise. One that slows down means
    the probing move reached its end (Z position_min) before the probe triggered: the move
    list then also holds the deceleration, which is that cause and not a miscount.
    """
    if not moves:
        return
    if len(moves) < MIN_PROBING_MOVES:
        raise TapInvalid(TOO_FEW_PROBING_MOVES,
                         f"{len(moves)} moves, a tap needs {MIN_PROBING_MOVES} or {MAX_PROBING_MOVES}")
    cruise = moves[-5]
    if cruise.accel < 0:
        raise TapInvalid(COASTING_MOVE_ACCELERATION, coasting_while_slowing_message(probing_move_end_z_mm(cruise)))
    if len(moves) > MAX_PROBING_MOVES:
        raise TapInvalid(TOO_MANY_PROBING_MOVES,
                         f"{len(moves)} moves, a tap needs {MIN_PROBING_MOVES} or {MAX_PROBING_MOVES}")
    if cruise.accel != 0:
        raise TapInvalid(COASTING_MOVE_ACCELERATION,
                         f"the probing move was accelerating ({cruise.accel:g} mm/s²) when the probe triggered, "
                         f"{abs(moves[-4].start_z - moves[0].start_z):.3f} mm below where it started: it started too "
                         "close to the bed (start it higher: sample_retract_dist, horizontal_move_z), or a tug from "
                         "the bowden tube or cable chain triggered it in the air")


def probing_move_end_z_mm(slowing: Move) -> float:
    """Where a probing move that was slowing down would have stopped: the end of its deceleration
    (v²/2a further on), which is the lowest Z the probe was allowed ([stepper_z] position_min)."""
    return slowing.start_z + slowing.z_r * slowing.start_v * slowing.start_v / (2.0 * abs(slowing.accel))


def coasting_while_slowing_message(end_z_mm: float) -> str:
    """COASTING_MOVE_ACCELERATION for a probing move that ran into its end (Z `end_z_mm`): the fix
    in [stepper_z] terms, which depend on whether that end is below Z=0 already (issue 20: the
    advice said position_min -5 to printers at -2, and contradicted itself at 0)."""
    end_z_mm = round(end_z_mm, 3) + 0.0  # no "-0.000"
    found = (f"the probing move was slowing down when the probe triggered: it was about to stop at its end, "
             f"Z {end_z_mm:.3f} (the lowest Z a probe may reach: [stepper_z] position_min), before the nozzle "
             "pressed the bed to trigger_force. ")
    if end_z_mm > -0.5:
        return found + ("Taps press a little past the bed before they trigger and need room below Z=0: give "
                        "[stepper_z] a negative position_min (the guide's example: position_min: -5)")
    return found + (f"That end is {-end_z_mm:.3f} mm below Z=0 already, so the bed is lower than Z=0 says here: "
                    "home Z again (G28 Z), check z_offset and that the sheet is on the bed, or lower trigger_force")


def check_motion(motion: Motion, time_s: np.ndarray) -> None:
    if motion.home_end_s == motion.pullback_start_s < motion.pullback_end_s:
        raise TapInvalid(TAP_MOTION_INVALID,
                         f"the pullback starts at the halt ({motion.home_end_s:.6f} s): no dwell, and the "
                         "five lines need the nozzle to rest between the compression and the decompression")
    if not motion.home_end_s < motion.pullback_start_s < motion.pullback_end_s:
        raise TapInvalid(TAP_MOTION_INVALID,
                         f"phase times out of order: halt {motion.home_end_s:.6f} s, pullback "
                         f"{motion.pullback_start_s:.6f}..{motion.pullback_end_s:.6f} s")
    if motion.home_end_s < time_s[0] or motion.pullback_start_s > time_s[-1]:
        raise TapInvalid(TAP_MOTION_INVALID,
                         f"the samples ({time_s[0]:.6f}..{time_s[-1]:.6f} s) do not cover the halt "
                         f"({motion.home_end_s:.6f} s) and the pullback start ({motion.pullback_start_s:.6f} s)")


def check_left_the_bed(pressed_g: float, remaining_g: float, scatter_g: float = 0.0) -> None:
    """The nozzle must have left the bed by the end of the pullback: the force then must be back
    near the free-air level. `pressed_g`: the compression force (contact to dwell);
    `remaining_g`: the force above the free-air level at that height (the approach line carried
    up by the drift) over the last samples of the pullback; `scatter_g`: the departure's own
    scatter about its line (noise and hum), which the remaining force must also clearly exceed.

    A pullback shorter than the sheet's springback leaves the nozzle pressing (a share of the
    compression force that grows as the pullback shrinks: 8 % at 0.03 mm and 2 mm/s, 77 % at
    0.01 mm on the virtual printer). The line fit then finds a "break contact" in the middle of
    the pressing and the tap reads out of order, misshapen or TOO_EARLY, whose advice (shorten
    pullback_distance) is the opposite of the fix: this check comes first.
    """
    if pressed_g > 0 and remaining_g > max(STILL_PRESSING_SHARE * pressed_g, STILL_PRESSING_SCATTERS * scatter_g):
        raise TapInvalid(TAP_PULLBACK_TOO_SHORT,
                         f"the nozzle still pressed the bed with {remaining_g:.0f}g ({remaining_g / pressed_g:.0%} of "
                         f"the {pressed_g:.0f}g compression) when the pullback ended: it never broke contact; "
                         "lengthen pullback_distance (LOAD_CELL_PROBE_CALIBRATE CALIBRATION=PULLBACK_DISTANCE finds it)")


def in_time_order(points: list[tuple[float, float]]) -> bool:
    """The points' times are finite and strictly increasing (the spec's chronology)."""
    previous = -math.inf
    for t, _ in points:  # one plain loop: two generators over six points cost more than the test
        if not (math.isfinite(t) and t > previous):
            return False
        previous = t
    return True


def split_checks_pass(points: list[tuple[float, float]], angles_deg: list[float]) -> bool:
    """The six points in time order and the four angles' signs a tap's: exactly when check_points
    passes them (POSITIVE_SHAPE's signs, compared one by one; a NaN angle has no sign and fails)."""
    approach_turn, compression_turn, release_turn, departure_turn = angles_deg
    return in_time_order(points) and approach_turn < 0 < compression_turn and release_turn > 0 > departure_turn


def check_points(points: list[tuple[float, float]], angles_deg: list[float]) -> None:
    """Chronology of the six points, then the shape (signs of the angles), positive polarity."""
    times = [t for t, _ in points]
    if not in_time_order(points):
        listed = ", ".join(f"P{k}={t:.4f}" for k, t in enumerate(times))
        raise TapInvalid(TAP_CHRONOLOGY, f"tap points out of time order ({listed} s)")
    signs = tuple((a > 0) - (a < 0) for a in angles_deg)  # np.sign without a numpy call per angle
    if signs != POSITIVE_SHAPE:
        listed = ", ".join(f"{a:.1f}" for a in angles_deg)
        raise TapInvalid(TAP_SHAPE_INVALID, f"the lines do not form a tap shape (angles {listed} deg)")


# check_break_contact's rules hold together only when a sixth of the pullback spans the two
# samples its end needs (below that, a break in the middle two thirds reads "never broke contact").
PULLBACK_MIN_SAMPLES = 6 * 2
GUIDE_PULLBACK_STEP_UM = 1.0  # the guide's pullback scans 1 µm a sample


def check_pullback_samples(motion: Motion, sample_period_s: float) -> None:
    """A pullback too fast for its samples: fewer than PULLBACK_MIN_SAMPLES, where the guide's 1 µm
    a sample would give that many over the same distance. Such a pullback (10 mm/s at 320 sps:
    31 µm a sample) is not one that never left the bed; its fix is the speed, not the distance.
    A pullback short in distance (a few µm at 1 µm a sample) passes: it is too short."""
    samples = motion.pullback_duration_s / sample_period_s
    distance_um = (motion.z_at_time_mm(motion.pullback_end_s) - motion.z_halt_mm) * 1000.0
    if samples < PULLBACK_MIN_SAMPLES <= distance_um / GUIDE_PULLBACK_STEP_UM:
        step_um = motion.pullback_speed_mm_s * sample_period_s * 1000.0
        raise TapInvalid(TAP_DATA_INSUFFICIENT,
                         f"the pullback holds {samples:.1f} samples ({step_um:.1f} µm a sample), too few to place "
                         f"break contact in its middle two thirds (at least {PULLBACK_MIN_SAMPLES}): slow "
                         "pullback_speed (the guide scans 1 µm a sample)")


# A line needs two points: the departure's samples wholly pressed (the decompression) that the
# contact's height is read from. One, and the contact is placed between it and the next sample only
# by the model's assumed shape (issue 21's sweep, 10 mm/s at 320 sps, 31 µm a sample: the accepted
# taps' errors 0.3-4.5 µm and one 19.9 µm off, 4.2 of its sigma, its stiffness read 1.2 g/µm for 4.9).
DECOMPRESSION_MIN_SAMPLES = 2
# A sample's travel on the pullback may reach the widest onset the toe model reads (its TOE_WIDTHS_UM's
# last), no further: beyond it the contact's onset falls between two samples, and its height is the
# shape assumed. The sweep's pullbacks of 10 mm/s at 320 sps (31.2 µm a sample, "either"): the taps
# with two samples pressed that were accepted erred by 3.6 µm rms at 3.0 of their z_sigma_um (seeds
# 51-90, 81 taps, by hand) and one 60.9 µm off (seed 89 k 8); the reference's ADS1220 2000 sps taps
# averaged to 250 sps (8 µm a sample, must accept) with two or three samples pressed erred 2.8 µm at
# most, 1.5 sigma.
PULLBACK_MAX_STEP_UM = TOE_WIDTHS_UM[-1]
# Faster than this many times the guide's 1 µm a sample, a decompression short of samples is the
# speed's doing (at the guide's speed a stiff bed's few µm of over-travel hold few samples too).
FAST_PULLBACK_GUIDE_STEPS = 2.0


def decompression_may_fall_short(contact_um: float, step_um: float) -> bool:
    """Whether `check_decompression_samples` can find too few samples at all: the pullback moves more
    than FAST_PULLBACK_GUIDE_STEPS of the guide's step a sample, below a contact high enough for the
    guide's step to leave DECOMPRESSION_MIN_SAMPLES wholly pressed (the analysis counts them only then)."""
    guide_pressed = contact_um / GUIDE_PULLBACK_STEP_UM - 1.0  # less the sample that straddles contact
    return DECOMPRESSION_MIN_SAMPLES <= guide_pressed and step_um > FAST_PULLBACK_GUIDE_STEPS * GUIDE_PULLBACK_STEP_UM


def check_decompression_samples(pressed: int, contact_um: float, step_um: float) -> None:
    """A pullback too fast for the decompression, where the guide's 1 µm a sample would read it and
    the pullback moves more than FAST_PULLBACK_GUIDE_STEPS of it a sample: fewer than
    DECOMPRESSION_MIN_SAMPLES samples wholly pressed between the halt and break contact (`pressed`;
    `contact_um` above the halt, `step_um` the pullback's travel per sample), or a sample's travel
    longer than the widest onset the toe model reads (`PULLBACK_MAX_STEP_UM`). Its fix is the speed."""
    if not decompression_may_fall_short(contact_um, step_um):
        return
    if pressed < DECOMPRESSION_MIN_SAMPLES:
        raise TapInvalid(TAP_DATA_INSUFFICIENT,
                         f"the decompression holds {pressed} sample(s) wholly in contact over {contact_um:.1f} µm "
                         f"({step_um:.1f} µm a sample), too few to fit the line break contact is read from (at "
                         f"least {DECOMPRESSION_MIN_SAMPLES}): slow pullback_speed (the guide scans 1 µm a sample)")
    if step_um > PULLBACK_MAX_STEP_UM:
        raise TapInvalid(TAP_DATA_INSUFFICIENT,
                         f"the pullback moves {step_um:.1f} µm a sample, more than the widest contact onset the "
                         f"analysis reads ({PULLBACK_MAX_STEP_UM:.0f} µm): break contact falls between two samples "
                         "and only the shape assumed places it: slow pullback_speed (the guide scans 1 µm a sample)")


# The guide's one probing-speed rule: an HX711 at 80 sps probes at 2 mm/s at most, 25 µm a sample
# ("rates below 250 Hz require slower probing speeds").
GUIDE_APPROACH_STEP_UM = 25.0
# Faster than this many times the guide's step a sample, a compression short of samples is the
# speed's doing (at the guide's speed a stiff bed's few µm of over-travel hold few samples too).
FAST_APPROACH_GUIDE_STEPS = 2.0
# The compression must hold a sample: with less, no sample is read between the touch and the halt,
# and the lines through the samples either side place neither (issue 21's sweep: reference HX711 taps
# averaged to 10 sps, 106-199 µm a sample, read out of order, misshapen or a contact 231-512 µm
# above the halt on the way down).
COMPRESSION_MIN_SAMPLES = 1.0


def compression_too_fast(contact_um: float, step_um: float) -> bool:
    """Whether the approach moved the nozzle from contact (`contact_um` above the halt, as the way up
    reads it) to the halt in less than COMPRESSION_MIN_SAMPLES samples of `step_um` each, faster than
    FAST_APPROACH_GUIDE_STEPS of the guide's step a sample."""
    return (step_um > FAST_APPROACH_GUIDE_STEPS * GUIDE_APPROACH_STEP_UM
            and 0.0 < contact_um < COMPRESSION_MIN_SAMPLES * step_um)


def check_compression_samples(contact_um: float, step_um: float, speed_mm_s: float) -> None:
    """TAP_DATA_INSUFFICIENT for an approach too fast for its sensor (`compression_too_fast`): asked
    where another check rejects the tap, as the cause its lines cannot show. Its fix is the probing
    speed or the sample rate, not the nozzle."""
    if compression_too_fast(contact_um, step_um):
        raise TapInvalid(TAP_DATA_INSUFFICIENT,
                         f"the compression holds {contact_um / step_um:.2f} samples: the nozzle went from contact "
                         f"({contact_um:.0f} µm above the halt, read on the way up) to the halt in less than one "
                         f"sample ({step_um:.0f} µm a sample at {speed_mm_s:.2f} mm/s), too few to place the touch "
                         "and the halt: probe slower (PROBE_SPEED=, [load_cell_probe] speed; the guide limits an "
                         f"80 sps HX711 to 2 mm/s, {GUIDE_APPROACH_STEP_UM:.0f} µm a sample) or use a faster sample_rate")


def check_break_contact(break_time_s: float, motion: Motion, sample_period_s: float) -> None:
    """Break contact must fall in the middle two thirds of the pullback move (the spec's rule).

    In the first sixth (or before the pullback): TAP_BREAK_CONTACT_TOO_EARLY, the pullback is
    longer than it needs to be. Within two samples of the pullback's end or later: the force
    only levelled off when the motion stopped, the nozzle never left the bed
    (TAP_PULLBACK_TOO_SHORT). Otherwise in the last sixth: TAP_BREAK_CONTACT_TOO_LATE.
    """
    start, end = motion.pullback_start_s, motion.pullback_end_s
    sixth_s = (end - start) / 6.0
    early_until, late_from = start + sixth_s, end - sixth_s
    if break_time_s < early_until:
        where = ("before the pullback started" if break_time_s < start
                 else f"in the first sixth of the pullback ({start:.4f}..{early_until:.4f} s)")
        raise TapInvalid(TAP_BREAK_CONTACT_TOO_EARLY,
                         f"break contact at {break_time_s:.4f} s, {where}; it must lie in the middle two "
                         "thirds: shorten pullback_distance")
    if break_time_s > end - 2 * sample_period_s:
        raise TapInvalid(TAP_PULLBACK_TOO_SHORT,
                         f"the nozzle never broke contact during the pullback ({start:.4f}..{end:.4f} s); "
                         "increase pullback_distance")
    if break_time_s > late_from:
        raise TapInvalid(TAP_BREAK_CONTACT_TOO_LATE,
                         f"break contact at {break_time_s:.4f} s, in the last sixth of the pullback "
                         f"({late_from:.4f}..{end:.4f} s); it must lie in the middle two thirds: "
                         "increase pullback_distance")


def contact_mismatch_tolerance_um(approach_step_um: float, pullback_step_um: float, down_sigma_um: float,
                                  up_sigma_um: float) -> float:
    """How far contact on the way down may lie above break contact on the way up on a sound tap:
    hysteresis, one sample of travel on each side (a contact anywhere within the sample where it
    happened reads the same), and CONSISTENCY_SIGMAS of the two estimates' fit sigmas."""
    return (HYSTERESIS_ALLOWANCE_UM + approach_step_um + pullback_step_um
            + CONSISTENCY_SIGMAS * math.hypot(down_sigma_um, up_sigma_um))


def check_contact_consistency(down_um: float, up_um: float, tolerance_um: float) -> None:
    """Contact on the way down must not lie above break contact on the way up by more than
    `tolerance_um` (heights in µm above the halt, both read with the same sensor delay).

    A sensor delay d moves the two apart the other way (down lower by v_approach·d, up higher by
    v_pullback·d), so no delay explains a down contact above the up one. What does: something
    the nozzle met first and pushed away (an ooze film, debris), after which the bed contact the
    pullback measures is not the surface the approach found. Such taps read Z off by the film.
    """
    if not (math.isfinite(down_um) and math.isfinite(up_um)):
        return
    if down_um - up_um > tolerance_um:
        raise TapInvalid(TAP_CONTACT_MISMATCH,
                         f"contact on the way down ({down_um:.1f} um above the halt) lies {down_um - up_um:.1f} um "
                         f"above break contact on the way up ({up_um:.1f} um), more than hysteresis, one sample of "
                         f"travel each way and the fits' noise explain ({tolerance_um:.1f} um): the nozzle pressed "
                         "something away (ooze film, debris); clean the nozzle and probe again")
