"""Every bad tap's error ends with the likely cause and the fix, as the guide's tables give them."""

from __future__ import annotations

import re
from types import SimpleNamespace

import pytest

from tapcell.extras.probe.advice import ADVICE, QUALITY_ADVICE, advised, bad_tap_advice
from tapcell.host.gcode import GCodeError
from tapcell.tap import model

from probe_vprinter import make_printer


def test_every_validation_code_has_advice():
    codes = {value for name, value in vars(model).items()
             if name.isupper() and isinstance(value, str) and value == name}
    assert codes - set(ADVICE) == {"LOW_TAP_QUALITY"}  # explained by its worst component
    assert bad_tap_advice("TAP_BREAK_CONTACT_TOO_EARLY").startswith(
        "Likely cause: pullback_distance is longer than it needs to be. Fix: shorten pullback_distance")
    assert "Fix: lengthen pullback_distance" in bad_tap_advice("TAP_BREAK_CONTACT_TOO_LATE")
    assert "Fix: lengthen pullback_distance" in bad_tap_advice("TAP_PULLBACK_TOO_SHORT")
    assert "NOZZLE_CLEANUP" in bad_tap_advice("TAP_SHAPE_INVALID")
    assert "position_min" in bad_tap_advice("COASTING_MOVE_ACCELERATION")
    assert bad_tap_advice(None) == ""


def test_low_quality_is_explained_by_its_worst_component():
    assert set(QUALITY_ADVICE) == {"approach", "departure", "baseline", "dwell_drop", "angle", "stiffness", "misfit"}
    drift = bad_tap_advice("LOW_TAP_QUALITY", {"approach": 0.1, "baseline": 0.4, "departure": 0.05})
    assert "drift_filter_cutoff_frequency" in drift and drift.startswith("Likely cause: the force did not come back")
    assert "min_tap_quality may be set too strict" in bad_tap_advice("LOW_TAP_QUALITY", {})


def test_the_most_common_code_of_the_bad_taps_is_advised():
    taps = [SimpleNamespace(error_code=c, analysis=None, explained=False)
            for c in ("TAP_SHAPE_INVALID", "TAP_PULLBACK_TOO_SHORT", "TAP_PULLBACK_TOO_SHORT")]
    assert advised("Probing failed after 3 bad probes (last: x)", taps) == (
        "Probing failed after 3 bad probes (last: x). " + bad_tap_advice("TAP_PULLBACK_TOO_SHORT"))
    taps[-1].explained = True  # e.g. "(probing too fast for this sensor: ...; probe at 1.9 mm/s or slower)"
    assert advised("m", taps) == "m"


def test_a_too_short_pullback_on_the_printer_says_lengthen_it(tmp_path):
    printer, _ = make_printer(tmp_path)
    printer.gcode.run_script("PROBE HOME=Z\nG1 Z0.4")
    with pytest.raises(GCodeError) as info:
        printer.gcode.run_script("PROBE PULLBACK_DISTANCE=0.03 BAD_PROBE_STRATEGY=fail")
    message = str(info.value)
    assert message.startswith("Probe failed because it was deemed bad quality: TAP_PULLBACK_TOO_SHORT - the nozzle "
                              "still pressed the bed with ")
    assert message.endswith("Likely cause: the pullback ended before the nozzle left the bed. Fix: lengthen "
                            "pullback_distance; LOAD_CELL_PROBE_CALIBRATE CALIBRATION=PULLBACK_DISTANCE measures the "
                            "right one.")
    printer.gcode.run_script("G1 Z0.4")
    with pytest.raises(GCodeError) as info:
        printer.gcode.run_script("PROBE PULLBACK_DISTANCE=0.03 BAD_PROBE_RETRIES=1")
    assert re.fullmatch(r"Probing failed after 2 bad probes \(last: TAP_PULLBACK_TOO_SHORT - .*\)\. Likely cause: "
                        r"the pullback ended before the nozzle left the bed\. Fix: lengthen pullback_distance; .*",
                        str(info.value))
