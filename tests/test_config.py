"""tapcell.host.config: the Klipper-format reader, typed getters, unused options, SAVE_CONFIG."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from tapcell.host import config as config_module
from tapcell.host.config import SAVE_CONFIG_MARKER, ConfigError, ConfigFile


# For reading values back in tests: every numeric getter must be given a range.
ANY = {"minval": -1e9, "maxval": 1e9}


def write(path: Path, text: str) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def read(tmp_path: Path, text: str, name: str = "printer.cfg") -> ConfigFile:
    return ConfigFile.read(write(tmp_path / name, text))


def error_of(func, *args, **kwargs) -> str:
    with pytest.raises(ConfigError) as info:
        func(*args, **kwargs)
    return str(info.value)


# -- syntax --------------------------------------------------------------------


def test_sections_options_separators_and_comments(tmp_path):
    cfg = read(tmp_path, """\
# a comment
; another
[printer]
kinematics: cartesian   # inline comment
max_velocity = 300 ; inline too
pin: ^PA1#not-a-comment

[load_cell  probe]
Sensor_Type: hx717
""")
    assert cfg.sections() == ["printer", "load_cell probe"]
    printer = cfg.getsection("printer")
    assert printer.get("kinematics") == "cartesian"
    assert printer.getfloat("max_velocity", **ANY) == 300.0
    assert printer.get("pin") == "^PA1#not-a-comment"
    probe = cfg.getsection("load_cell probe")
    assert probe.get("sensor_type") == "hx717"  # option names are case-insensitive
    assert probe.get_name() == "load_cell probe"
    assert probe.get_prefix() == "load_cell"
    assert probe.get_instance_name() == "probe"
    assert cfg.getsection("printer").get_instance_name() is None


def test_multiline_values_keep_lines_and_skip_comments(tmp_path):
    cfg = read(tmp_path, """\
[gcode_macro PARK]
gcode:
    G90
    # a comment line inside the value

    G1 X10 Y{ y }  ; inline comment
description: Park it
""")
    section = cfg.getsection("gcode_macro PARK")
    assert section.get("gcode") == "G90\nG1 X10 Y{ y }"
    assert section.get("description") == "Park it"


def test_duplicate_sections_merge_and_later_values_win(tmp_path):
    cfg = read(tmp_path, "[printer]\na: 1\nb: 2\n[bed_mesh]\n[printer]\nb: 3\n")
    assert cfg.sections() == ["printer", "bed_mesh"]
    assert cfg.getsection("printer").getint("a", **ANY) == 1
    assert cfg.getsection("printer").getint("b", **ANY) == 3


@pytest.mark.parametrize("text, message", [
    ("a: 1\n", "printer.cfg:1: option 'a: 1' is outside of any section"),
    ("[printer]\njunk line\n", "printer.cfg:2: expected 'option: value' or 'option = value', got 'junk line'"),
    ("  indented: 1\n", "printer.cfg:1: indented line 'indented: 1' does not continue an option"),
    ("[printer\n", "printer.cfg:1: malformed section header '[printer' (expected '[name]')"),
    ("[]\n", "printer.cfg:1: empty section name '[]'"),
    ("[printer]\n: 5\n", "printer.cfg:2: expected 'option: value' or 'option = value', got ': 5'"),
])
def test_syntax_errors_name_file_and_line(tmp_path, text, message):
    path = write(tmp_path / "printer.cfg", text)
    assert error_of(ConfigFile.read, path) == message.replace("printer.cfg", str(path))


def test_missing_file_and_bad_encoding(tmp_path):
    missing = tmp_path / "nope.cfg"
    assert error_of(ConfigFile.read, missing) == f"{missing}: config file does not exist"
    binary = tmp_path / "bin.cfg"
    binary.write_bytes(b"[printer]\na: \xff\xfe\n")
    assert error_of(ConfigFile.read, binary).startswith(f"{binary}: unable to read config file:")


# -- includes ------------------------------------------------------------------


def test_include_globs_relative_to_including_file_in_order(tmp_path):
    write(tmp_path / "conf" / "macros" / "b.cfg", "[gcode_macro B]\ngcode: B\n")
    write(tmp_path / "conf" / "macros" / "a.cfg", "[gcode_macro A]\ngcode: A\n[printer]\nx: from_a\n")
    write(tmp_path / "conf" / "hardware.cfg", "[include macros/*.cfg]\n[bed_mesh]\n")
    main = write(tmp_path / "printer.cfg", "[printer]\nx: main\ny: 1\n[include conf/hardware.cfg]\n[load_cell]\n")
    cfg = ConfigFile.read(main)
    assert cfg.sections() == ["printer", "gcode_macro A", "gcode_macro B", "bed_mesh", "load_cell"]
    # The include came after [printer] in the main file, so its value wins.
    assert cfg.getsection("printer").get("x") == "from_a"
    cfg.getsection("printer").get("y")
    # An unused option is reported in the file that holds it.
    assert error_of(cfg.check_unused_options) == (
        f"{tmp_path}/conf/macros/a.cfg: [gcode_macro A] gcode = A: "
        "Option 'gcode' is not valid in section 'gcode_macro A'")


def test_include_errors(tmp_path):
    main = write(tmp_path / "printer.cfg", "[include missing.cfg]\n")
    assert error_of(ConfigFile.read, main) == (
        f"{main}:1: include file '{tmp_path}/missing.cfg' does not exist")
    # A glob that matches nothing is fine (an empty directory of macros).
    write(tmp_path / "printer.cfg", "[include extra/*.cfg]\n[printer]\n")
    assert ConfigFile.read(main).sections() == ["printer"]
    write(tmp_path / "printer.cfg", "[include]\n")
    assert "[include] needs a file name or glob" in error_of(ConfigFile.read, main)


def test_include_cycle_is_an_error(tmp_path):
    write(tmp_path / "a.cfg", "[include b.cfg]\n")
    write(tmp_path / "b.cfg", "[include a.cfg]\n")
    main = write(tmp_path / "printer.cfg", "[include a.cfg]\n")
    assert error_of(ConfigFile.read, main) == f"{tmp_path}/a.cfg: include cycle: printer.cfg -> a.cfg -> b.cfg -> a.cfg"


def test_include_chain_deeper_than_the_limit_names_the_file(tmp_path):
    depth = config_module.MAX_INCLUDE_DEPTH
    for level in range(1, 300):
        write(tmp_path / f"level{level}.cfg", f"[include level{level + 1}.cfg]\n")
    main = write(tmp_path / "printer.cfg", "[include level1.cfg]\n")
    assert error_of(ConfigFile.read, main) == (
        f"{tmp_path}/level{depth + 1}.cfg: includes are nested more than {depth} deep "
        f"(included from {tmp_path}/level{depth}.cfg)")


def test_include_diamond_stops_at_the_file_count_limit(tmp_path):
    # Each file includes the next one twice: 2**16 reads without a limit, within the depth limit.
    for level in range(16):
        write(tmp_path / f"d{level}.cfg", f"[include d{level + 1}.cfg]\n[include d{level + 1}.cfg]\n")
    write(tmp_path / "d16.cfg", "[printer]\n")
    main = write(tmp_path / "printer.cfg", "[include d0.cfg]\n")
    assert error_of(ConfigFile.read, main).endswith(
        f".cfg: more than {config_module.MAX_CONFIG_FILES} config files read through [include]")


@pytest.mark.parametrize("include, problem", [
    ("/dev/zero", "printer.cfg:1: include file /dev/zero: is a character device, not a config file"),
    ("big.cfg", "printer.cfg:1: include file {tmp}/big.cfg: is larger than 1,024 bytes, not a config file"),
])
def test_include_of_a_device_or_a_huge_file_is_refused(tmp_path, monkeypatch, include, problem):
    monkeypatch.setattr(config_module, "MAX_CONFIG_FILE_BYTES", 1024)
    write(tmp_path / "big.cfg", "# padding\n" * 200)
    main = write(tmp_path / "printer.cfg", f"[include {include}]\n")
    assert error_of(ConfigFile.read, main).endswith(problem.format(tmp=tmp_path))


# -- typed getters ---------------------------------------------------------------


GETTER_CFG = """\
[load_cell_probe]
trigger_force: 300
low: 5
count: 10.5
word: abc
flag: Yes
bad_flag: maybe
gain: A-128
bad_gain: A-12
ads_gain: 64
points: 1.5, 2 ,3,
steps: 1, x, 3
lines:
  one
  two
infinite: inf
"""


@pytest.fixture
def probe_section(tmp_path):
    return read(tmp_path, GETTER_CFG).getsection("load_cell_probe"), str(tmp_path / "printer.cfg")


def test_getters_return_typed_values_and_defaults(probe_section):
    section, _ = probe_section
    assert section.getfloat("trigger_force", minval=10, maxval=500) == 300.0
    assert section.getint("low", minval=1, maxval=10) == 5
    assert section.getboolean("flag") is True
    assert section.getchoice("gain", ["A-128", "B-64"]) == "A-128"
    assert section.getchoice("gain", {"A-128": 128, "B-64": 64}) == 128
    assert section.getchoice("ads_gain", {1: "x1", 64: "x64"}) == "x64"
    assert section.getfloatlist("points", **ANY) == [1.5, 2.0, 3.0]
    assert section.getlist("lines", sep="\n") == ["one", "two"]
    assert section.getfloat("absent", 75.0, **ANY) == 75.0
    assert section.getint("absent", None, **ANY) is None
    assert section.getfloatlist("absent", [50.0, 60.0], count=2, **ANY) == [50.0, 60.0]
    assert section.has_option("TRIGGER_FORCE") and not section.has_option("absent")


@pytest.mark.parametrize("call, problem", [
    (lambda s: s.getfloat("trigger_force", minval=10, maxval=250),
     "trigger_force = 300: must be at most 250 (allowed: 10 to 250)"),
    (lambda s: s.getfloat("low", minval=10.0, maxval=20), "low = 5: must be at least 10 (allowed: 10 to 20)"),
    (lambda s: s.getfloat("low", above=5, maxval=20), "low = 5: must be above 5 (allowed: above 5 and at most 20)"),
    (lambda s: s.getfloat("low", minval=0, below=5), "low = 5: must be below 5 (allowed: at least 0 and below 5)"),
    (lambda s: s.getfloat("low", above=0, maxval=0.5), "low = 5: must be at most 0.5 (allowed: above 0 and at most 0.5)"),
    (lambda s: s.getint("count", minval=1, maxval=20), "count = 10.5: expected an integer, 1 to 20"),
    (lambda s: s.getfloat("word", minval=0.1, maxval=20), "word = abc: expected a number, 0.1 to 20"),
    (lambda s: s.getfloat("infinite", **ANY), "infinite = inf: must be a finite number"),
    (lambda s: s.getboolean("bad_flag"), "bad_flag = maybe: expected True or False"),
    (lambda s: s.getchoice("bad_gain", ["A-128", "B-64"]), "bad_gain = A-12: must be one of: A-128, B-64"),
    (lambda s: s.getchoice("word", {1: 1, 2: 2}), "word = abc: must be one of: 1, 2"),
    (lambda s: s.getintlist("steps", minval=0, maxval=9),
     "steps = 1, x, 3: item 'x' is not valid (expected a list of integers separated by ',', each 0 to 9)"),
    (lambda s: s.getfloatlist("points", count=2, **ANY), "points = 1.5, 2 ,3,: has 3 items, expected exactly 2"),
    (lambda s: s.getfloatlist("points", minval=0, maxval=2.5),
     "points = 1.5, 2 ,3,: item '3' must be at most 2.5 (allowed: 0 to 2.5)"),
    (lambda s: s.getchoice("sensor_type", ["hx711", "hx717", "ads1220"]),
     "sensor_type: must be specified (one of: hx711, hx717, ads1220)"),
    (lambda s: s.getfloat("z_offset", minval=-5, maxval=5), "z_offset: must be specified (a number, -5 to 5)"),
    (lambda s: s.get("pin"), "pin: must be specified (a value)"),
])
def test_getter_errors_name_file_section_option_value_and_allowed(probe_section, call, problem):
    section, path = probe_section
    assert error_of(call, section) == f"{path}: [load_cell_probe] {problem}"


@pytest.mark.parametrize("call", [
    lambda s: s.getfloat("trigger_force"),
    lambda s: s.getfloat("trigger_force", 1.0, minval=0),
    lambda s: s.getint("low", maxval=10),
    lambda s: s.getfloatlist("points", above=0),
    lambda s: s.getintlist("absent", None, minval=0),
])
def test_a_numeric_getter_without_a_range_is_a_programming_error(probe_section, call):
    section, _ = probe_section
    with pytest.raises(TypeError, match="must declare its range"):
        call(section)


def test_error_carries_structured_fields(probe_section):
    section, path = probe_section
    with pytest.raises(ConfigError) as info:
        section.getfloat("trigger_force", minval=10, maxval=250)
    assert (info.value.file, info.value.section, info.value.option, info.value.value) == (
        path, "load_cell_probe", "trigger_force", "300")


def test_module_raised_error_uses_same_format(probe_section):
    section, path = probe_section
    assert str(section.error("gain", "REF1 cannot be used with AIN0")) == (
        f"{path}: [load_cell_probe] gain = A-128: REF1 cannot be used with AIN0")


# -- unused options -----------------------------------------------------------


def test_unread_option_is_an_error_and_read_ones_are_not(tmp_path):
    cfg = read(tmp_path, "[printer]\nkinematics: cartesian\nmax_velocty: 300\n")
    cfg.getsection("printer").get("kinematics")
    assert error_of(cfg.check_unused_options) == (
        f"{tmp_path}/printer.cfg: [printer] max_velocty = 300: Option 'max_velocty' is not valid in section 'printer'")
    cfg.getsection("printer").getfloat("max_velocty", **ANY)
    cfg.check_unused_options()


def test_reading_with_a_default_still_counts_as_read(tmp_path):
    cfg = read(tmp_path, "[printer]\nspeed: 5\n")
    assert cfg.getsection("printer").getfloat("speed", 1.0, **ANY) == 5.0
    cfg.check_unused_options()


def test_mark_section_read_accepts_every_option(tmp_path):
    cfg = read(tmp_path, "[bed_mesh]\nspeed: 5\nprobe_count: 3, 3\n[bed_mesh p1]\nx_count: 3\n")
    cfg.mark_section_read("bed_mesh")
    with pytest.raises(ConfigError, match="Option 'x_count' is not valid in section 'bed_mesh p1'"):
        cfg.check_unused_options()
    assert cfg.section_options("bed_mesh p1") == {"x_count": "3"}  # reading them all counts
    cfg.check_unused_options()


def test_prefix_sections_and_lookup(tmp_path):
    cfg = read(tmp_path, f"[load_cell]\n[gcode_macro A]\n[load_cell left]\n[load_cells]\n{SAVE_CONFIG_MARKER}\n"
                         "#*# [load_cell right]\n#*# counts_per_gram = 5\n")
    assert [s.get_name() for s in cfg.get_prefix_sections("load_cell ")] == ["load_cell left", "load_cell right"]
    assert [s.get_name() for s in cfg.get_prefix_sections("load_cell")] == [
        "load_cell", "load_cell left", "load_cells", "load_cell right"]
    assert cfg.has_section("load_cell right") and not cfg.has_section("load_cell middle")
    # A missing section reads as empty: every option takes its default.
    assert cfg.getsection("load_cell middle").getfloat("counts_per_gram", 1.5, **ANY) == 1.5


# -- SAVE_CONFIG block -----------------------------------------------------------


SAVED = f"""\
[load_cell]
sensor_type: hx717
counts_per_gram: 10

{SAVE_CONFIG_MARKER}
#*# [load_cell]
#*# counts_per_gram = 87.5
#*# reference_tare_counts = -1234
#*#
#*# [bed_mesh default]
#*# points =
#*#     0.1, 0.2
#*#     0.3, 0.4
"""


def test_save_config_block_overrides_earlier_values(tmp_path):
    cfg = read(tmp_path, SAVED)
    load_cell = cfg.getsection("load_cell")
    assert load_cell.getfloat("counts_per_gram", **ANY) == 87.5
    assert load_cell.getint("reference_tare_counts", **ANY) == -1234
    assert cfg.sections() == ["load_cell", "bed_mesh default"]
    assert cfg.getsection("bed_mesh default").getlist("points", sep="\n") == ["0.1, 0.2", "0.3, 0.4"]


def test_content_after_save_config_block_is_an_error(tmp_path):
    path = write(tmp_path / "printer.cfg", SAVED + "[printer]\n")
    assert error_of(ConfigFile.read, path) == (
        f"{path}:14: line '[printer]' comes after the SAVE_CONFIG block; the block must be the end of the file")


def test_save_config_block_in_an_included_file_is_an_error(tmp_path):
    write(tmp_path / "inc.cfg", f"[printer]\n{SAVE_CONFIG_MARKER}\n#*# [printer]\n#*# a = 1\n")
    main = write(tmp_path / "printer.cfg", "[include inc.cfg]\n")
    assert error_of(ConfigFile.read, main) == (
        f"{tmp_path}/inc.cfg:3: a SAVE_CONFIG block is only allowed in the main config file")


def test_save_writes_block_keeps_body_and_backup(tmp_path):
    body = "# my printer\n[load_cell]\nsensor_type: hx717   # the chip\n"
    path = write(tmp_path / "printer.cfg", body)
    cfg = ConfigFile.read(path)
    assert not cfg.has_pending_changes()
    cfg.set("load_cell", "counts_per_gram", "%.5f" % 87.94408)
    cfg.set("load_cell", "reference_tare_counts", 1234)
    assert cfg.pending_changes() == {"load_cell": {"counts_per_gram": "87.94408", "reference_tare_counts": "1234"}}
    cfg.save()
    text = path.read_text()
    assert text.startswith(body)
    assert text[len(body):] == (
        f"\n{SAVE_CONFIG_MARKER}\n"
        "#*# # This block is rewritten by SAVE_CONFIG; its values override the ones above.\n"
        "#*#\n#*# [load_cell]\n#*# counts_per_gram = 87.94408\n#*# reference_tare_counts = 1234\n")
    assert (tmp_path / "printer.cfg.bak").read_text() == body
    assert not cfg.has_pending_changes()
    reloaded = ConfigFile.read(path).getsection("load_cell")
    assert reloaded.getfloat("counts_per_gram", **ANY) == pytest.approx(87.94408)
    assert reloaded.getint("reference_tare_counts", **ANY) == 1234


def test_save_merges_with_existing_block_and_removes_sections(tmp_path):
    path = write(tmp_path / "printer.cfg", SAVED)
    cfg = ConfigFile.read(path)
    cfg.set("load_cell", "counts_per_gram", "90.0")
    cfg.remove_section("bed_mesh default")
    cfg.set("bed_mesh other", "points", "1\n2")
    cfg.save()
    again = ConfigFile.read(path)
    assert again.sections() == ["load_cell", "bed_mesh other"]
    assert again.getsection("load_cell").get("counts_per_gram") == "90.0"
    assert again.getsection("load_cell").get("reference_tare_counts") == "-1234"
    assert again.getsection("bed_mesh other").get("points") == "1\n2"
    assert path.read_text().count(SAVE_CONFIG_MARKER) == 1
    # Removing everything removes the block.
    again.remove_section("load_cell")
    again.remove_section("bed_mesh other")
    again.save()
    assert SAVE_CONFIG_MARKER not in path.read_text()
    assert ConfigFile.read(path).getsection("load_cell").get("counts_per_gram") == "10"


def _half_writing(real_write):
    """os.write that stores half the data, then fails like a full disk."""
    def write(fd, data):
        real_write(fd, bytes(data[: len(data) // 2]))
        raise OSError(28, "No space left on device")
    return write


def _no_space(*args, **kwargs):
    raise OSError(28, "No space left on device")


def _fail_on_the_backup(real):
    def replace(path, *args):
        if path.endswith(".bak"):
            _no_space()
        return real(path, *args)
    return replace


@pytest.mark.parametrize("failing", ["write", "fsync", "fchmod", "replace", "backup"])
def test_failure_mid_save_leaves_old_file_and_backup_intact(tmp_path, monkeypatch, failing):
    path = write(tmp_path / "printer.cfg", SAVED)
    old_backup = write(tmp_path / "printer.cfg.bak", "# the previous backup\n")
    cfg = ConfigFile.read(path)
    cfg.set("load_cell", "counts_per_gram", "1.0")
    if failing == "write":
        monkeypatch.setattr(config_module.os, "write", _half_writing(config_module.os.write))
    elif failing == "backup":
        monkeypatch.setattr(config_module, "_replace_file", _fail_on_the_backup(config_module._replace_file))
    else:
        monkeypatch.setattr(config_module.os, failing, _no_space)
    message = error_of(cfg.save)
    assert message == (f"{path}: unable to write config file (old file left unchanged): "
                       "[Errno 28] No space left on device")
    monkeypatch.undo()
    assert path.read_text() == SAVED
    assert sorted(os.listdir(tmp_path)) == ["printer.cfg", "printer.cfg.bak"]  # no temp file left behind
    # The backup is either the previous one or a whole copy of the old file, never torn.
    assert old_backup.read_text() in ("# the previous backup\n", SAVED)
    # The pending change survives, so a retry can succeed.
    assert cfg.has_pending_changes()
    cfg.save()
    assert ConfigFile.read(path).getsection("load_cell").get("counts_per_gram") == "1.0"
    assert old_backup.read_text() == SAVED


def test_save_keeps_mode_and_owner_of_file_and_backup(tmp_path):
    path = write(tmp_path / "printer.cfg", SAVED)
    os.chmod(path, 0o640)
    owner = (os.getuid(), os.getgid())
    if os.getuid() == 0:  # as root, a foreign owner shows that the owner is kept, not just inherited
        owner = (1234, 2345)
        os.chown(path, *owner)
    cfg = ConfigFile.read(path)
    cfg.set("load_cell", "counts_per_gram", "2.0")
    cfg.save()
    for saved in (path, tmp_path / "printer.cfg.bak"):
        status = os.stat(saved)
        assert (oct(status.st_mode & 0o7777), status.st_uid, status.st_gid) == (oct(0o640), *owner)


def test_save_writes_through_a_symlink_to_its_target(tmp_path):
    target = write(tmp_path / "real" / "printer.cfg", SAVED)
    link = tmp_path / "printer.cfg"
    link.symlink_to(target)
    cfg = ConfigFile.read(link)
    cfg.set("load_cell", "counts_per_gram", "3.0")
    cfg.save()
    assert link.is_symlink() and os.readlink(link) == str(target)
    assert ConfigFile.read(target).getsection("load_cell").get("counts_per_gram") == "3.0"
    assert (tmp_path / "real" / "printer.cfg.bak").read_text() == SAVED  # the backup sits beside the real file
    assert sorted(os.listdir(tmp_path)) == ["printer.cfg", "real"]
    assert sorted(os.listdir(tmp_path / "real")) == ["printer.cfg", "printer.cfg.bak"]


def test_save_of_an_empty_file_keeps_the_previous_backup(tmp_path):
    path = write(tmp_path / "printer.cfg", "")
    backup = write(tmp_path / "printer.cfg.bak", SAVED)
    cfg = ConfigFile.read(path)
    cfg.set("load_cell", "counts_per_gram", "4.0")
    cfg.save()
    assert backup.read_text() == SAVED
    assert ConfigFile.read(path).getsection("load_cell").get("counts_per_gram") == "4.0"
