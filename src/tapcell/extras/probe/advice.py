"""What a bad tap most likely means and what to do about it, in plain words.

The load-cell guide lists, for every tap validation and quality code, its common causes
("Tap Validation Error Codes", "Tap Quality Error Codes", the drift-filter tuning notes).
Every probing error that ends in a bad tap closes with this: `Likely cause: ... Fix: ...`.
A low quality score is explained by the component that sank it (over its cutoff, else the largest).
"""

from __future__ import annotations

from collections.abc import Mapping

from tapcell.tap.classifiers import DEFAULT_QUALITY_CUTOFFS, limiting_component

FOULED = "plastic on the nozzle (ooze) distorts the tap"
CLEAN_AND_COOL = ("clean the nozzle (NOZZLE_CLEANUP), probe below the ooze point (about 140 C, M109 S140) "
                  "and probe fouled places around, not again (BED_MESH_CALIBRATE STRATEGY=CIRCLE)")
CALIBRATE_PULLBACK = "LOAD_CELL_PROBE_CALIBRATE CALIBRATION=PULLBACK_DISTANCE measures the right one"

# code -> (likely cause, fix)
ADVICE: dict[str, tuple[str, str]] = {
    "TAP_CHRONOLOGY": (FOULED + " so much that it no longer looks like a tap", CLEAN_AND_COOL),
    "TAP_SHAPE_INVALID": (FOULED + " so much that it no longer looks like a tap", CLEAN_AND_COOL),
    "TAP_BREAK_CONTACT_TOO_EARLY": ("pullback_distance is longer than it needs to be",
                                    f"shorten pullback_distance; {CALIBRATE_PULLBACK}"),
    "TAP_BREAK_CONTACT_TOO_LATE": ("pullback_distance is too short for this speed and bed, or a drift filter "
                                   "set too high (drift_filter_cutoff_frequency) delays the tap",
                                   f"lengthen pullback_distance ({CALIBRATE_PULLBACK}), or lower "
                                   "drift_filter_cutoff_frequency or the probing speed"),
    "TAP_PULLBACK_TOO_SHORT": ("the pullback ended before the nozzle left the bed",
                               f"lengthen pullback_distance; {CALIBRATE_PULLBACK}"),
    "COASTING_MOVE_ACCELERATION": ("the probing move was not at its steady speed when the probe triggered: still "
                                   "speeding up (the probe started too close to the bed, or a tug on the toolhead "
                                   "from the bowden tube or cable chain triggered it in the air) or already slowing "
                                   "down at its end, [stepper_z] position_min",
                                   "give [stepper_z] a negative position_min (e.g. -5) and start the probe higher"),
    "TOO_FEW_PROBING_MOVES": ("the probing move was cut short (uncommon)",
                              "check that position_min leaves room below the bed; report it if it persists"),
    "TOO_MANY_PROBING_MOVES": ("the probing move was split into more pieces than a tap has (uncommon)",
                               "report it with the tap file (tap_log)"),
    "LOW_COMPRESSION_FORCE": ("hot plastic on the nozzle made the force rise slowly, or the probe pressed "
                              "something soft", CLEAN_AND_COOL + "; check that the sheet lies flat"),
    "LOW_DECOMPRESSION_FORCE": ("the force fell away while the nozzle pressed: the sheet does not lie firmly on the "
                                "bed (debris under it), or soft plastic flowed out from under the nozzle",
                                CLEAN_AND_COOL + "; lift the sheet and clean under it"),
    "TAP_CONTACT_MISMATCH": ("the nozzle pressed something away before it met the bed (an ooze film, debris)",
                             CLEAN_AND_COOL),
    "TAP_ADHESION": ("a thread of plastic held the nozzle as it left the bed (the force dipped below free air)",
                     CLEAN_AND_COOL),
    "TAP_TWO_STAGE_CONTACT": ("the nozzle pressed a soft layer before the bed (a magnetic sheet lifting, a sprung "
                              "bed's springs, a film of ooze): its stiff stage would read low",
                              "seat the sheet flat and clean it, check the bed's springs; " + CLEAN_AND_COOL),
    "TAP_SENSOR_SATURATED": ("the load cell's sensor reached its limit while the nozzle pressed (the force held "
                             "flat): a small load cell, a high gain, or a fast probe pressing too hard",
                             "probe slower (PROBE_SPEED=) or lower the trigger force; lower the sensor's gain or "
                             "fit a larger load cell"),
    "TAP_DATA_INSUFFICIENT": ("too few samples in part of the tap: the sensor is slow for this probing speed",
                              "probe slower (PROBE_SPEED=) or use a faster sample_rate"),
    "TAP_MOTION_INVALID": ("the recorded motion does not describe a tap (a move was interrupted)",
                           "probe again; report it with the tap file (tap_log) if it persists"),
    "CLASSIFIER_FAILED": ("the tap_classifier plug-in failed", "check the plug-in, or use tap_classifier: tap_quality"),
}

# LOW_TAP_QUALITY, by the component that sank the score (over its cutoff, else the largest;
# tapcell.tap.classifiers.limiting_component with the default cutoffs).
QUALITY_ADVICE: dict[str, tuple[str, str]] = {
    "approach": ("the force rose before the nozzle reached the bed: molten plastic under the nozzle, or "
                 "drift from the bowden tube or cable chain", CLEAN_AND_COOL + "; against drift set "
                 "drift_filter_cutoff_frequency (start at 0.5)"),
    "departure": ("ooze pulled on the nozzle as it left the bed", CLEAN_AND_COOL),
    "baseline": ("the force did not come back to where it started: ooze, or drift from the bowden tube or "
                 "cable chain", CLEAN_AND_COOL + "; against drift set drift_filter_cutoff_frequency "
                 "(start at 0.5)"),
    "dwell_drop": ("plastic flowed out from under the nozzle while it pressed, or the sheet does not lie firmly "
                   "on the bed", CLEAN_AND_COOL + "; check the sheet for debris underneath"),
    "angle": ("ooze changed how the force fell as the nozzle lifted",
              CLEAN_AND_COOL + "; after changing pullback_speed or the bed, calibrate DECOMPRESSION_ANGLE again"),
    "stiffness": ("the bed felt softer on the way up than on the way down: a film between nozzle and bed",
                  CLEAN_AND_COOL),
    "misfit": ("the pullback does not follow a clean contact: ooze or a noisy sensor",
               CLEAN_AND_COOL + "; run LOAD_CELL_DIAGNOSTIC to check the noise"),
}
QUALITY_DEFAULT = (FOULED + ": the tap's features are there but distorted",
                   CLEAN_AND_COOL + "; if clean taps are refused, min_tap_quality may be set too strict")


def coasting_fix(position_min_mm: float) -> str:
    """The COASTING fix for a printer whose [stepper_z] position_min is known: room below Z=0
    exists already when it is negative, so what is left is the start height or a tug."""
    if position_min_mm >= 0:
        return (f"give [stepper_z] a negative position_min (it is {position_min_mm:g}; e.g. -5), so the probing "
                f"move can pass Z=0, and start the probe higher")
    return (f"start the probe higher ([stepper_z] position_min is {position_min_mm:g} already); if it triggers in "
            f"the air, free the bowden tube or cable chain that pulls on the toolhead")


def bad_tap_advice(code: str | None, quality_components: Mapping[str, float] | None = None,
                   position_min_mm: float | None = None) -> str:
    """'Likely cause: ... Fix: ...' for a bad tap's code ('' for no code); `position_min_mm`
    ([stepper_z] position_min, when known) makes the COASTING fix fit the printer."""
    if not code:
        return ""
    if code == "LOW_TAP_QUALITY":
        worst = limiting_component(dict(quality_components), DEFAULT_QUALITY_CUTOFFS) if quality_components else None
        cause, fix = QUALITY_ADVICE.get(worst, QUALITY_DEFAULT)
    else:
        cause, fix = ADVICE.get(code, (FOULED, CLEAN_AND_COOL))
    if code == "COASTING_MOVE_ACCELERATION" and position_min_mm is not None:
        fix = coasting_fix(position_min_mm)
    return f"Likely cause: {cause}. Fix: {fix}."


def with_advice(message: str, code: str | None, quality_components: Mapping[str, float] | None = None,
                position_min_mm: float | None = None) -> str:
    """`message` ending with the advice for `code`."""
    advice = bad_tap_advice(code, quality_components, position_min_mm)
    return f"{message.rstrip('. ')}. {advice}" if advice else message


def advised(message: str, bad_taps, position_min_mm: float | None = None) -> str:
    """`message` ending with the likely cause and fix of the most common code among `bad_taps`
    (TapOutcome-like: error_code, analysis, explained); unchanged when the tap's own message
    already explains it (e.g. probing too fast for the sensor)."""
    codes = [tap.error_code for tap in bad_taps if tap.error_code]
    if not codes:
        return message
    code = max(codes, key=codes.count)  # the most common; the earliest among equals
    last = next(tap for tap in reversed(bad_taps) if tap.error_code == code)
    if last.explained:
        return message
    return with_advice(message, code, getattr(last.analysis, "quality_components", None), position_min_mm)
