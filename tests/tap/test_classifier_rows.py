"""The spec rows of the quality classifier: LOW_DECOMPRESSION_FORCE, LOW_TAP_QUALITY naming the
component over its cutoff, and tap_classifier_module given as a module path or a file."""

from __future__ import annotations

import pytest

from tapcell.tap import AnalysisOptions, analyze_tap, get_classifier
from tapcell.tap.classifiers import (DEFAULT_QUALITY_CUTOFFS, MIN_DECOMPRESSION_TO_TRIGGER, UnknownClassifierError,
                                     limiting_component)
from tapcell.extras.probe.advice import bad_tap_advice
from tapcell.tap.synth import synth_tap

PLUGIN = """
from tapcell.tap import Classification, TapRejected


class TapClassifier:
    def __init__(self, options):
        self.options = options

    def classify(self, analysis, context):
        if analysis.compression_force_g > 70:
            raise TapRejected("MY_CODE", "pressed %.0f g" % analysis.compression_force_g)
        return Classification(quality=12.5)


def Lenient(options):
    return type("Lenient", (), {"classify": lambda self, analysis, context: Classification(quality=99.0)})()
"""


def test_a_tap_whose_force_falls_away_in_the_dwell_is_low_decompression_force():
    clean = analyze_tap(synth_tap(seed=1))
    assert clean.valid
    points = clean.points
    assert abs(points[3][1] - points[4][1]) > MIN_DECOMPRESSION_TO_TRIGGER * 75.0
    # The sheet gives way: 55 % of the force is gone by the end of the dwell.
    sagging = analyze_tap(synth_tap(seed=1, relaxation_fraction=0.55, relaxation_time_s=0.05))
    assert sagging.error == "LOW_DECOMPRESSION_FORCE", (sagging.error, sagging.message)
    released = abs(sagging.points[3][1] - sagging.points[4][1])
    assert released < MIN_DECOMPRESSION_TO_TRIGGER * 75.0
    assert sagging.message == (f"decompression force {released:.1f} g is below 0.9 x the trigger force 75.0 g: "
                               "the force fell away during the dwell")
    # The quality score alone would have let it pass: no component is over its cutoff.
    assert all(ratio <= DEFAULT_QUALITY_CUTOFFS[name] / 100 for name, ratio in sagging.quality_components.items()
               if name in DEFAULT_QUALITY_CUTOFFS) if sagging.quality_components else True
    assert "sheet does not lie firmly" in bad_tap_advice("LOW_DECOMPRESSION_FORCE")


def test_low_tap_quality_names_the_component_over_its_cutoff_not_the_largest():
    components = {"dwell_drop": 0.60, "departure": 0.30, "approach": 0.05}
    assert limiting_component(components, DEFAULT_QUALITY_CUTOFFS) == "departure"  # 30 % > 25 %; 60 % < 75 %
    assert limiting_component({"dwell_drop": 0.60, "departure": 0.20}, DEFAULT_QUALITY_CUTOFFS) == "dwell_drop"
    assert "ooze pulled on the nozzle" in bad_tap_advice("LOW_TAP_QUALITY", components)
    # On a tap: a 30 g string on departure (sharp model) with a large dwell drop, under its cutoff
    # (our stiffness and misfit components switched off, so only the spec's four count).
    tap = synth_tap(seed=1, pull_force_g=30.0, relaxation_fraction=0.7, relaxation_time_s=0.05)
    result = analyze_tap(tap, AnalysisOptions(contact_model="sharp", trigger_force_g=20.0, max_model_misfit=100,
                                              max_stiffness_mismatch=100))
    assert result.error == "LOW_TAP_QUALITY", (result.error, result.message)
    ratios = result.quality_components
    largest = max(ratios, key=ratios.get)
    cutoffs = {**DEFAULT_QUALITY_CUTOFFS, "misfit": 100, "stiffness": 100}
    assert largest != "departure" and ratios[largest] < cutoffs[largest] / 100  # the largest is within its cutoff
    assert ratios["departure"] / 0.25 > ratios["baseline"] / 0.25 > 1.0
    assert f"(departure {100 * ratios['departure']:.1f}% is over its cutoff 25%)" in result.message


def test_tap_classifier_module_takes_a_module_path_or_a_file(tmp_path, monkeypatch):
    (tmp_path / "my_taps.py").write_text(PLUGIN)
    monkeypatch.syspath_prepend(str(tmp_path))
    tap = synth_tap(seed=1)
    rejected = analyze_tap(tap, AnalysisOptions(tap_classifier="my_taps"))
    assert rejected.error == "MY_CODE" and rejected.message.startswith("pressed ")
    assert analyze_tap(tap, AnalysisOptions(tap_classifier="my_taps:Lenient")).quality == 99.0
    by_file = analyze_tap(tap, AnalysisOptions(tap_classifier=str(tmp_path / "my_taps.py")))
    assert by_file.error == "MY_CODE"
    with pytest.raises(UnknownClassifierError, match="'no_such_module.taps' is not importable"):
        get_classifier("no_such_module.taps")
    with pytest.raises(UnknownClassifierError, match="has no Missing"):
        get_classifier("my_taps:Missing")
    with pytest.raises(UnknownClassifierError, match="does not exist"):
        get_classifier(str(tmp_path / "nope.py"))


def test_the_config_names_a_classifier_file_and_a_missing_one_is_a_config_error(tmp_path):
    from machines import PROBE_SECTION, machine_config
    from tapcell.host.config import ConfigError
    from tapcell.host.gcode import GCodeError
    from tapcell.host.printer import Printer

    (tmp_path / "strict.py").write_text(
        "from tapcell.tap import TapRejected\n\n\nclass TapClassifier:\n    def __init__(self, options):\n"
        "        pass\n\n    def classify(self, analysis, context):\n"
        "        raise TapRejected('TOO_STRICT', 'refused by strict.py')\n")
    probe = PROBE_SECTION.format(counts_per_gram=110, reference_tare_counts=-38000)
    config = tmp_path / "printer.cfg"
    config.write_text(machine_config() + probe + f"tap_classifier_module: {tmp_path / 'strict.py'}\n")
    printer = Printer.from_config(str(config), responses=[])
    with pytest.raises(GCodeError, match=r"last: TOO_STRICT - refused by strict.py"):
        printer.gcode.run_script("G28\nPROBE")
    config.write_text(machine_config() + probe + f"tap_classifier_module: {tmp_path / 'nope.py'}\n")
    with pytest.raises(ConfigError, match=r"\[load_cell_probe\] tap_classifier_module = .*nope.py: unknown tap "
                                          r"classifier .*does not exist"):
        Printer.from_config(str(config), responses=[])
