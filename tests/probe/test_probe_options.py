import pytest

from tapcell.host.config import ConfigError
from tapcell.host.gcode import GCodeError
from tapcell.extras.probe.options import PROBE_OPTION_SPECS, read_probe_options, with_overrides
from tapcell.host.templates import compile_template


def test_probe_option_defaults(make_section):
    opts = read_probe_options(make_section("z_offset: 0.0"), {})
    assert opts.z_offset_mm == 0.0
    assert (opts.speed_mm_s, opts.samples, opts.sample_retract_dist_mm) == (5.0, 1, 2.0)
    assert (opts.samples_result, opts.samples_tolerance_mm, opts.samples_tolerance_retries) == ("average", 0.1, 0)
    assert (opts.bad_probe_strategy, opts.bad_probe_retries, opts.pattern_spacing_mm) == ("retry", 6, 2.0)
    assert opts.effective_lift_speed_mm_s == 5.0 and opts.effective_retry_speed_mm_s == 5.0
    assert opts.scrubbing_frequency == 0


def test_probe_options_from_config(make_section):
    opts = read_probe_options(make_section(
        "z_offset: -0.02\nspeed: 3\nlift_speed: 10\nsamples: 3\nsamples_result: median\n"
        "bad_probe_strategy: circle\nbad_probe_retries: 18\nretry_speed: 2\npattern_spacing: 1.5"), {})
    assert opts.z_offset_mm == -0.02
    assert (opts.effective_lift_speed_mm_s, opts.effective_retry_speed_mm_s) == (10.0, 2.0)
    assert (opts.samples, opts.samples_result, opts.bad_probe_strategy) == (3, "median", "circle")


def test_probe_option_errors_name_file_section_option_value(make_section):
    with pytest.raises(ConfigError, match=r"\[load_cell_probe\] z_offset: must be specified"):
        read_probe_options(make_section("speed: 5"), {})
    with pytest.raises(ConfigError, match=r"printer.cfg: \[load_cell_probe\] samples_result = mode: must be one of"):
        read_probe_options(make_section("z_offset: 0\nsamples_result: mode"), {})
    with pytest.raises(ConfigError, match=r"speed = 0: "):
        read_probe_options(make_section("z_offset: 0\nspeed: 0"), {})
    with pytest.raises(ConfigError, match=r"bad_probe_retries = 19: must be at most 18 with bad_probe_strategy circle"):
        read_probe_options(make_section("z_offset: 0\nbad_probe_strategy: circle\nbad_probe_retries: 19"), {})


def test_gcode_overrides(make_section, make_gcmd):
    base = read_probe_options(make_section("z_offset: 0"), {})
    opts = with_overrides(base, PROBE_OPTION_SPECS,
                          make_gcmd("PROBE PROBE_SPEED=2 SAMPLES=5 BAD_PROBE_STRATEGY=CIRCLE SAMPLES_RESULT=median"))
    assert (opts.speed_mm_s, opts.samples, opts.bad_probe_strategy, opts.samples_result) == (2.0, 5, "circle", "median")
    # lift and retry speed follow the overridden speed when the config did not set them
    assert opts.effective_lift_speed_mm_s == 2.0
    assert with_overrides(base, PROBE_OPTION_SPECS, make_gcmd("PROBE SPEED=7")).speed_mm_s == 7.0
    assert with_overrides(base, PROBE_OPTION_SPECS, make_gcmd("PROBE")) is base
    with pytest.raises(GCodeError, match="BAD_PROBE_STRATEGY must be one of fail, ignore, retry, circle, not 'sometimes'"):
        with_overrides(base, PROBE_OPTION_SPECS, make_gcmd("PROBE BAD_PROBE_STRATEGY=sometimes"))
    with pytest.raises(GCodeError, match="SAMPLES must have minimum of 1"):
        with_overrides(base, PROBE_OPTION_SPECS, make_gcmd("PROBE SAMPLES=0"))
    # The guide spells it `BED_MESH STRATEGY=CIRCLE`: the same option (was silently ignored).
    assert with_overrides(base, PROBE_OPTION_SPECS,
                          make_gcmd("BED_MESH_CALIBRATE STRATEGY=CIRCLE")).bad_probe_strategy == "circle"
    with pytest.raises(GCodeError, match="STRATEGY must be one of fail, ignore, retry, circle, not 'spiral'"):
        with_overrides(base, PROBE_OPTION_SPECS, make_gcmd("BED_MESH_CALIBRATE STRATEGY=spiral"))


def test_probe_templates_use_the_macro_environment(make_section):
    # Klipper's delimiters: `{expr}` renders (a bare jinja2.Template would leave it as text).
    section = make_section("z_offset: 0.0\nactivate_gcode: G1 Z{params.LIFT}\n"
                           "deactivate_gcode:\n  {% for n in range(2) %}M400\n  {% endfor %}")
    activate = compile_template(section, "activate_gcode", "[load_cell_probe] activate_gcode")
    assert activate.render({"params": {"LIFT": "5"}}) == "G1 Z5"
    deactivate = compile_template(section, "deactivate_gcode", "[load_cell_probe] deactivate_gcode")
    assert deactivate.render({}).split() == ["M400", "M400"]
    with pytest.raises(GCodeError, match=r"^Error in \[load_cell_probe\] activate_gcode: 'dict object' has no "
                                         r"attribute 'LIFT'$"):
        activate.render({"params": {}})


def test_a_template_syntax_error_is_a_config_error_at_load(make_section):
    section = make_section("z_offset: 0.0\nnozzle_scrubber_gcode: G1 Z{params.LIFT\n")
    with pytest.raises(ConfigError, match=r"\[load_cell_probe\] nozzle_scrubber_gcode = G1 Z\{params.LIFT: template "
                                          r"error on line 1 of the template: "):
        compile_template(section, "nozzle_scrubber_gcode", "scrubber")
