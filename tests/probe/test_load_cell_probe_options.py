import pytest

from tapcell.host.config import ConfigError
from tapcell.host.gcode import GCodeError
from tapcell.extras.load_cell_probe.options import (
    TAP_OPTION_SPECS,
    TapOptions,
    default_pullback_speed_mm_s,
    force_beyond_safety_limit_g,
    read_tap_options,
    tare_sample_count,
    too_fast_for_analysis,
)
from tapcell.extras.probe.options import with_overrides


def read(make_section, text):
    return read_tap_options(make_section(text))


def test_defaults(make_section):
    opts = read(make_section, "")
    assert opts == TapOptions()
    assert (opts.trigger_force_g, opts.force_safety_limit_g, opts.drift_safety_limit_g) == (75.0, 2000.0, 1000.0)
    assert opts.tare_time_s == pytest.approx(0.0667, abs=1e-4)
    assert (opts.pullback_distance_mm, opts.pullback_speed_mm_s) == (0.2, None)
    assert (opts.tap_classifier, opts.min_tap_quality, opts.decompression_angle) == ("tap_quality", 40.0, None)
    assert (opts.max_approach_force, opts.max_departure_force,
            opts.max_baseline_force_delta, opts.max_dwell_force_drop) == (50.0, 25.0, 25.0, 75.0)


def test_config_values_and_ranges(make_section):
    opts = read(make_section, "trigger_force: 120\ndrift_filter_cutoff_frequency: 0.8\n"
                              "notch_filter_frequencies: 50, 60\ndecompression_angle: 80.5\ntap_classifier: empty")
    assert opts.trigger_force_g == 120.0 and opts.drift_filter_cutoff_frequency == 0.8
    assert opts.notch_filter_frequencies == (50.0, 60.0) and opts.decompression_angle == 80.5
    assert opts.tap_classifier == "empty"
    with pytest.raises(ConfigError, match=r"\[load_cell_probe\] trigger_force = 300: must be at most 250"):
        read(make_section, "trigger_force: 300")
    with pytest.raises(ConfigError, match=r"trigger_force = 5: must be at least 10"):
        read(make_section, "trigger_force: 5")
    with pytest.raises(ConfigError, match=r"decompression_angle = 90"):
        read(make_section, "decompression_angle: 90")
    with pytest.raises(ConfigError, match=r"pullback_distance = 3"):
        read(make_section, "pullback_distance: 3")
    assert read(make_section, "force_safety_limit: 0").force_safety_limit_g == 0.0  # 0 disables
    # notch_filter_quality: "Minimum value is 0.5 and maximum is 3.0" (the config reference).
    assert read(make_section, "notch_filter_quality: 3").notch_filter_quality == 3.0
    with pytest.raises(ConfigError, match=r"\[load_cell_probe\] notch_filter_quality = 3.5: must be at most 3"):
        read(make_section, "notch_filter_quality: 3.5")
    with pytest.raises(ConfigError, match=r"notch_filter_quality = 0.4: must be at least 0.5"):
        read(make_section, "notch_filter_quality: 0.4")


def test_the_guides_name_for_the_classifier_option(make_section):
    # The load-cell guide calls it tap_classifier_module; Kalico (and our reference) tap_classifier.
    assert read(make_section, "tap_classifier_module: empty").tap_classifier == "empty"
    with pytest.raises(ConfigError, match=r"\[load_cell_probe\] tap_classifier_module = empty: the same option as "
                                          r"tap_classifier \(the guide's name for it\): give one of them"):
        read(make_section, "tap_classifier: empty\ntap_classifier_module: empty")


def test_gcode_overrides_including_filters(make_section, make_gcmd):
    base = read(make_section, "drift_filter_cutoff_frequency: 0.8")
    opts = with_overrides(base, TAP_OPTION_SPECS, make_gcmd(
        "PROBE TRIGGER_FORCE=100 DRIFT_FILTER_CUTOFF_FREQUENCY=2.5 NOTCH_FILTER_FREQUENCIES=50 "
        "PULLBACK_SPEED=0.16 MIN_TAP_QUALITY=60 TAP_CLASSIFIER=empty"))
    assert (opts.trigger_force_g, opts.drift_filter_cutoff_frequency, opts.notch_filter_frequencies) == (100.0, 2.5, (50.0,))
    assert (opts.pullback_speed_mm_s, opts.min_tap_quality, opts.tap_classifier) == (0.16, 60.0, "empty")
    off = with_overrides(base, TAP_OPTION_SPECS, make_gcmd("PROBE DRIFT_FILTER_CUTOFF_FREQUENCY=none"))
    assert off.drift_filter_cutoff_frequency is None
    with pytest.raises(GCodeError, match="TRIGGER_FORCE must have maximum of 250"):
        with_overrides(base, TAP_OPTION_SPECS, make_gcmd("PROBE TRIGGER_FORCE=400"))
    with pytest.raises(GCodeError, match=r"^Error on 'PROBE NOTCH_FILTER_FREQUENCIES=fifty': unable to parse 'fifty' in "
                                         r"NOTCH_FILTER_FREQUENCIES \(expected comma-separated numbers\)$"):
        with_overrides(base, TAP_OPTION_SPECS, make_gcmd("PROBE NOTCH_FILTER_FREQUENCIES=fifty"))


def test_pure_rules():
    assert default_pullback_speed_mm_s(320) == pytest.approx(0.32)
    assert default_pullback_speed_mm_s(80) == pytest.approx(0.08)
    assert tare_sample_count(4 / 60, 320) == 22
    assert tare_sample_count(4 / 60, 80) == 6
    assert tare_sample_count(0.01, 10) == 2
    # 3 kg preload at 100 counts/g against a 2 kg limit -> refused, reports the force
    assert force_beyond_safety_limit_g(50_000 + 300_000, 50_000, 100.0, 2000.0) == pytest.approx(3000.0)
    assert force_beyond_safety_limit_g(50_000 - 300_000, 50_000, 100.0, 2000.0) == pytest.approx(-3000.0)
    assert force_beyond_safety_limit_g(50_000 + 150_000, 50_000, 100.0, 2000.0) is None
    assert force_beyond_safety_limit_g(50_000 + 300_000, 50_000, 100.0, 0.0) is None  # 0 disables


def test_too_fast_for_analysis_explains_with_the_physics():
    # HX711 at 8 mm/s: 100 um per sample on a 3.25 g/um bed; the force jumped 50 -> 350 g.
    why = too_fast_for_analysis(50.0, 350.0, 520.0, 75.0, 8.0, 80.0, 0.15, stiffness_g_um=3.25)
    assert why == ("probing too fast for this sensor: at 8 mm/s and 80 samples/s the nozzle moves 100.0 um per "
                   "sample, but on this bed (about 3.2 g/um) the force reaches the 75g trigger 23 um after first "
                   "contact: it jumped from 50g to 350g within one sample, so no sample shows the compression and "
                   "the tap cannot be analysed; the nozzle stopped about 160 um past first contact, pressing 520g, "
                   "more than 3/4 of the 0.15 mm pullback, so it leaves the bed late in the pullback or not at all; "
                   "probe at 1.8 mm/s or slower (or use a faster sensor)")
    # Unknown bed: estimated from the jump (300 g per 100 um); a shallow halt says nothing of the pullback.
    why = too_fast_for_analysis(0.0, 300.0, 300.0, 75.0, 8.0, 80.0, 0.2)
    assert "(about 3.0 g/um)" in why and "pressing 300g; probe at 2.0 mm/s" in why and "pullback" not in why
    # A force that built up over more than one sample is not the speed's fault.
    assert too_fast_for_analysis(30.0, 90.0, 150.0, 75.0, 2.0, 80.0, 0.15, stiffness_g_um=3.25) is None
