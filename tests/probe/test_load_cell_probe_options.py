import pytest

from tapcell.host.config import ConfigError
from tapcell.host.gcode import GCodeError
from tapcell.extras.load_cell_probe.options import (
    ANALYSIS_OPTION_SPECS,
    TAP_OPTION_SPECS,
    TapOptions,
    default_pullback_speed_mm_s,
    force_beyond_safety_limit_g,
    read_tap_options,
    replace_tap_options,
    tap_analysis_options,
    tap_options_with_overrides,
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
    analysis = opts.analysis
    assert (analysis.tap_classifier, analysis.min_tap_quality, analysis.decompression_angle) == ("tap_quality", 40.0, None)
    assert (analysis.max_approach_force, analysis.max_departure_force,
            analysis.max_baseline_force_delta, analysis.max_dwell_force_drop) == (50.0, 25.0, 25.0, 75.0)
    assert (analysis.contact_model, analysis.contact_onset_um) == ("toe", None)


def test_config_values_and_ranges(make_section):
    opts = read(make_section, "trigger_force: 120\ndrift_filter_cutoff_frequency: 0.8\n"
                              "notch_filter_frequencies: 50, 60\ndecompression_angle: 80.5\ntap_classifier: empty")
    assert opts.trigger_force_g == 120.0 and opts.drift_filter_cutoff_frequency == 0.8
    assert opts.notch_filter_frequencies == (50.0, 60.0) and opts.analysis.decompression_angle == 80.5
    assert opts.analysis.tap_classifier == "empty"
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
    assert read(make_section, "tap_classifier_module: empty").analysis.tap_classifier == "empty"
    with pytest.raises(ConfigError, match=r"\[load_cell_probe\] tap_classifier_module = empty: the same option as "
                                          r"tap_classifier \(the guide's name for it\): give one of them"):
        read(make_section, "tap_classifier: empty\ntap_classifier_module: empty")


def test_gcode_overrides_including_filters(make_section, make_gcmd):
    base = read(make_section, "drift_filter_cutoff_frequency: 0.8")
    opts = tap_options_with_overrides(base, make_gcmd(
        "PROBE TRIGGER_FORCE=100 DRIFT_FILTER_CUTOFF_FREQUENCY=2.5 NOTCH_FILTER_FREQUENCIES=50 "
        "PULLBACK_SPEED=0.16 MIN_TAP_QUALITY=60 TAP_CLASSIFIER=empty CONTACT_ONSET_UM=12.5"))
    assert (opts.trigger_force_g, opts.drift_filter_cutoff_frequency, opts.notch_filter_frequencies) == (100.0, 2.5, (50.0,))
    assert (opts.pullback_speed_mm_s, opts.analysis.min_tap_quality, opts.analysis.tap_classifier) == (0.16, 60.0, "empty")
    assert opts.analysis.contact_onset_um == 12.5
    # What the taps are analysed with: the command's trigger force and the notch's hum.
    analysed = tap_analysis_options(opts)
    assert (analysed.trigger_force_g, analysed.mains_hz, analysed.min_tap_quality) == (100.0, (50.0,), 60.0)
    assert tap_options_with_overrides(base, make_gcmd("PROBE")) is base
    with pytest.raises(GCodeError, match="MIN_TAP_QUALITY must have maximum of 100"):
        tap_options_with_overrides(base, make_gcmd("PROBE MIN_TAP_QUALITY=101"))
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


def test_analysis_options_are_one_table_with_tapcell_analyze_set(make_section):
    # [load_cell_probe] reads the analysis's own options, with its defaults and its ranges: the config, a
    # probing command and `tapcell analyze --set` allow the same values.
    from tapcell.tap.cli import options_from_settings
    from tapcell.tap.model import ANALYSIS_RANGES, CONFIG_OPTIONS, AnalysisOptions

    assert [spec.option for spec in ANALYSIS_OPTION_SPECS] == list(CONFIG_OPTIONS)
    for spec in ANALYSIS_OPTION_SPECS:
        assert spec.option == spec.field and spec.default == getattr(AnalysisOptions(), spec.field)
        allowed = ANALYSIS_RANGES.get(spec.field)
        if allowed is not None:
            ends = (spec.above, spec.below) if allowed.exclusive else (spec.minval, spec.maxval)
            assert ends == (allowed.low, allowed.high)
    assert read(make_section, "").analysis == AnalysisOptions()
    config = read(make_section, "min_tap_quality: 70\ncontact_model: sharp\ncontact_onset_um: 12.5\n"
                                "max_dwell_force_drop: 60").analysis
    assert config == options_from_settings(["min_tap_quality=70", "contact_model=sharp", "contact_onset_um=12.5",
                                            "max_dwell_force_drop=60"])
    # Out of range: refused by both, each naming the option, the value and what is allowed.
    with pytest.raises(ConfigError, match=r"printer.cfg: \[load_cell_probe\] max_approach_force = 101: must be "
                                          r"at most 100"):
        read(make_section, "max_approach_force: 101")
    with pytest.raises(ValueError, match=r"option 'max_approach_force' = '101': must be between 0 and 100"):
        options_from_settings(["max_approach_force=101"])
    with pytest.raises(ConfigError, match=r"\[load_cell_probe\] contact_model = hertz: must be one of: sharp, toe"):
        read(make_section, "contact_model: hertz")
    with pytest.raises(ValueError, match=r"option 'contact_model' = 'hertz': one of sharp, toe"):
        options_from_settings(["contact_model=hertz"])


def test_calibrated_fields_reach_the_analysis():
    options = replace_tap_options(TapOptions(), contact_onset_um=14.0, pullback_distance_mm=0.1)
    assert (options.analysis.contact_onset_um, options.pullback_distance_mm) == (14.0, 0.1)
    assert tap_analysis_options(options).contact_onset_um == 14.0
    assert not tap_analysis_options(options).uses_toe_model
    assert TapOptions().analysis.uses_toe_model


@pytest.mark.parametrize("misspelt", ["min_tap_qualty: 60", "contact_onset: 12"])
def test_a_misspelt_option_is_refused_naming_section_and_option(tmp_path, misspelt):
    from probe_vprinter import make_printer

    option = misspelt.split(":")[0]
    with pytest.raises(ConfigError, match=rf"\.cfg: \[load_cell_probe\] {option} = .*: Option '{option}' is not "
                                          r"valid in section 'load_cell_probe'"):
        make_printer(tmp_path, probe_options=misspelt, home=False)


@pytest.mark.parametrize("setting", ["pullback_distance_mm=5", "pullback_speed_mm_s=1"])
def test_tapcell_analyze_refuses_the_pullback_with_the_allowed_list(capsys, setting):
    # The pullback is the probe's (pullback_distance, pullback_speed in [load_cell_probe]), not the analysis's.
    from tapcell.tap.cli import main

    assert main(["--set", setting, "no-such-file.json"]) == 2
    key = setting.split("=")[0]
    allowed = capsys.readouterr().err.strip().split("; allowed: ")
    assert allowed[0] == f"tapcell analyze: unknown option '{key}'"
    names = allowed[1].split(", ")
    assert {"min_tap_quality", "contact_model", "contact_onset_um", "max_dwell_force_drop"} <= set(names)
    assert not any(name.startswith("pullback") for name in names)


def test_analysis_options_on_a_probing_command(tmp_path):
    from probe_vprinter import make_printer

    printer, responses = make_printer(tmp_path)
    with pytest.raises(GCodeError, match=r"unknown parameter MIN_TAP_QUALTY \(did you mean MIN_TAP_QUALITY\?\) for "
                                         r"PROBE; nothing was moved"):
        printer.gcode.run_script("PROBE MIN_TAP_QUALTY=50")
    with pytest.raises(GCodeError, match=r"CONTACT_ONSET_UM must have maximum of 100 \(allowed: 0 to 100\)"):
        printer.gcode.run_script("PROBE CONTACT_ONSET_UM=200")
    # No tap scores 100: the command's option refuses it (and the config's 40 accepts the same bed).
    with pytest.raises(GCodeError, match=r"deemed bad quality: LOW_TAP_QUALITY - tap quality \d+\.\d% is below "
                                         r"min_tap_quality 100%"):
        printer.gcode.run_script("PROBE MIN_TAP_QUALITY=100 BAD_PROBE_STRATEGY=fail")
    printer.gcode.run_script("G1 Z0.4\nPROBE")
    assert printer.lookup_object("load_cell_probe").last_taps[-1].valid
