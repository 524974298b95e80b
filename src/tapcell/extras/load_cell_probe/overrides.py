"""What a probing command's overrides may do to the safety limits: tighten them, never loosen them.

The config decides how much a probing move may press (`force_safety_limit`, `drift_safety_limit`)
and how soon a sensor that stopped changing ends it (`stuck_sensor_samples`). A G-code override
may make a limit stricter; one that would loosen it past the config (a higher limit, a longer
stuck run, or 0, which turns a check off) is refused before anything moves. So is a parameter
spelled almost like one of these (a misspelled limit would otherwise be ignored and the move run
with the config's). The config itself may still turn a check off (the spec: 0 disables), and then
is warned about at load and at every probing command (`disabled_protections`). Any other
parameter the command did not read before its first move is refused too (`refuse_unknown_parameters`).
"""

from __future__ import annotations

import difflib

from tapcell.extras.load_cell_probe.options import TapOptions

# (G-code parameter, TapOptions field, unit) of the limits an override may only tighten.
LIMITS = (("FORCE_SAFETY_LIMIT", "force_safety_limit_g", "g"), ("DRIFT_SAFETY_LIMIT", "drift_safety_limit_g", "g"))
STUCK = "STUCK_SENSOR_SAMPLES"
SAFETY_PARAMETERS = tuple(name for name, _, _ in LIMITS) + (STUCK, "TRIGGER_FORCE")
# How alike a parameter must be to a safety parameter's name to be taken for a misspelling of it.
MISSPELLING_CUTOFF = 0.8


def refuse_misspelled_safety_parameters(gcmd) -> None:
    """A parameter not read yet that is spelled almost like a safety parameter: refused, naming it."""
    if gcmd is None:
        return
    for name in gcmd.unread_parameters():
        if name in SAFETY_PARAMETERS:
            continue
        close = difflib.get_close_matches(name, SAFETY_PARAMETERS, n=1, cutoff=MISSPELLING_CUTOFF)
        if close:
            raise gcmd.param_error(f"unknown parameter {name} (did you mean {close[0]}?); nothing was moved")


def refuse_unknown_parameters(gcmd) -> None:
    """Before a probing command first moves: every parameter it was given must have been read by
    then (its handler reads its parameters first); one it never asked for is unknown to it and
    is refused, so a misspelled option never lets the move run with the config's value."""
    if gcmd is None:
        return
    unknown = gcmd.unread_parameters()
    if not unknown:
        return
    known = gcmd.read_parameters()
    problems = []
    for name in unknown:
        gcmd.has(name)  # refused here: not "ignored" again after the command
        close = difflib.get_close_matches(name, known, n=1)
        problems.append(name + (f" (did you mean {close[0]}?)" if close else ""))
    raise gcmd.param_error(f"unknown parameter {', '.join(problems)} for {gcmd.command}; nothing was moved")


def refuse_loosening(gcmd, config: TapOptions, command: TapOptions, config_stuck_samples: int) -> None:
    """The command's options may tighten the config's safety limits, not loosen them (0 = off)."""
    for name, field, unit in LIMITS:
        allowed_g = getattr(config, field)
        asked_g = getattr(command, field)
        if allowed_g > 0 and not 0 < asked_g <= allowed_g:
            raise gcmd.param_error(f"{name}={asked_g:g} would loosen the configured {name.lower()} "
                                   f"({allowed_g:g}{unit}); a command may only tighten it: above 0 and at most "
                                   f"{allowed_g:g}")
    asked = command.stuck_sensor_samples
    if asked is not None and config_stuck_samples > 0 and not 0 < asked <= config_stuck_samples:
        raise gcmd.param_error(f"{STUCK}={asked} would loosen the stuck-sensor check ({config_stuck_samples} "
                               f"identical samples stop a move); a command may only tighten it: 2 to "
                               f"{config_stuck_samples}")


def disabled_protections(config: TapOptions) -> list[str]:
    """What the config turned off, as warnings (at load and at every probing command)."""
    warnings = []
    if config.force_safety_limit_g == 0:
        warnings.append("[load_cell_probe] force_safety_limit is 0: no force limit stops a probing move or a "
                        "watched move; only the ADC's range and the trigger do")
    if config.stuck_sensor_samples == 0:
        warnings.append("[load_cell_probe] stuck_sensor_samples is 0: a sensor that stops changing is not "
                        "detected and a move goes on pressing until something else stops it")
    return warnings
