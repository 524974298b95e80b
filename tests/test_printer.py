"""tapcell.host.printer: loading sections by convention ([name] -> tapcell.extras.name), status, events,
RESTART, SAVE_CONFIG."""

from __future__ import annotations

import sys
import types
from pathlib import Path

import pytest

from tapcell.host import printer as printer_module
from tapcell.host.config import ConfigError, ConfigFile
from tapcell.tools.frontend import DEFAULT_CONFIG
from tapcell.host.gcode import GCodeError
from tapcell.host.printer import Printer


class FakeBackend:
    """Stands in for the virtual printer: a clock and a record of how it was built."""

    def __init__(self, section=None, machine=None):
        self.options = {"scenario": section.get("scenario", "clean")} if section is not None else {}
        self.now_s = 42.0

    def get_status(self, eventtime):
        return {"time_s": eventtime, **self.options}


class FakeToolhead:
    """Reads [printer] and the stepper sections, like the real toolhead will."""

    def __init__(self, section, printer):
        self.max_velocity = section.getfloat("max_velocity", above=0, maxval=1000)
        self.steppers = {}
        for axis in "xyz":
            stepper = section.getsection(f"stepper_{axis}")
            if section.config.has_section(stepper.get_name()):
                self.steppers[axis] = stepper.getfloat("rotation_distance", above=0, maxval=1000)
        printer.register_event_handler("printer:ready", lambda: printer.gcode.respond_info("toolhead ready"))

    def get_status(self, eventtime):
        return {"max_velocity": self.max_velocity, "steppers": len(self.steppers)}


class FakeScale:
    """A [load_cell]-like module: a calibration value that SAVE_CONFIG persists."""

    def __init__(self, section, printer):
        self.name = section.get_name()
        self.counts_per_gram = section.getfloat("counts_per_gram", None, minval=1.0, maxval=1e6)
        self.toolhead = printer.load_object("printer")
        value = section.get_instance_name()
        printer.gcode.register_mux_command("FAKE_CALIBRATE", "LOAD_CELL", value, self.cmd_calibrate)

    def cmd_calibrate(self, gcmd):
        counts = gcmd.get_float("COUNTS", minval=1.0, maxval=1e6)
        self.printer_config.set(self.name, "counts_per_gram", "%.5f" % counts)
        gcmd.respond_info(f"counts_per_gram: {counts:.5f}")

    def get_status(self, eventtime):
        return {"counts_per_gram": self.counts_per_gram, "is_calibrated": self.counts_per_gram is not None}


@pytest.fixture
def fake_modules(monkeypatch):
    toolhead = types.ModuleType("tapcell_test_toolhead")
    toolhead.load_config = FakeToolhead
    scale = types.ModuleType("tapcell_test_scale")

    def load_scale(section, printer):
        obj = FakeScale(section, printer)
        obj.printer_config = printer.config
        return obj

    scale.load_config = load_scale
    scale.load_config_prefix = load_scale
    sim = types.ModuleType("tapcell_test_sim")
    sim.VirtualPrinter = types.SimpleNamespace(from_config=FakeBackend)
    install_extras(monkeypatch, {"load_cell": scale, "load_cell_probe": scale})
    for module in (toolhead, sim):
        monkeypatch.setitem(sys.modules, module.__name__, module)
    monkeypatch.setattr(printer_module, "TOOLHEAD_MODULE", toolhead.__name__)
    monkeypatch.setattr(printer_module, "BACKEND_MODULE", sim.__name__)


def install_extras(monkeypatch, modules: dict[str, types.ModuleType]) -> None:
    """Make `modules` the extras package: [name] sections load from modules[name]."""
    package = types.ModuleType("tapcell_test_extras")
    package.__path__ = []
    monkeypatch.setitem(sys.modules, package.__name__, package)
    for kind, module in modules.items():
        monkeypatch.setitem(sys.modules, f"{package.__name__}.{kind}", module)
    monkeypatch.setattr(printer_module, "EXTRAS_PACKAGE", package.__name__)


CONFIG = """\
[load_cell]
counts_per_gram: 10
[virtual_printer]
scenario: noisy-mains
[printer]
max_velocity: 300
[stepper_x]
rotation_distance: 40
[stepper_z]
rotation_distance: 8
[load_cell right]
"""


def build(tmp_path, text=CONFIG, **kwargs):
    path = tmp_path / "printer.cfg"
    path.write_text(text)
    responses: list[str] = []
    return Printer.from_config(str(path), responses=responses, **kwargs), responses, path


def config_error(tmp_path, text, **kwargs) -> str:
    with pytest.raises(ConfigError) as info:
        build(tmp_path, text, **kwargs)
    return str(info.value)


def test_sections_become_objects_with_status(tmp_path, fake_modules):
    printer, responses, _ = build(tmp_path)
    assert responses == ["// toolhead ready"]
    assert printer.state == "ready"
    assert isinstance(printer.backend, FakeBackend) and printer.backend.options == {"scenario": "noisy-mains"}
    toolhead = printer.lookup_object("printer")
    assert toolhead.steppers == {"x": 40.0, "z": 8.0}
    # [load_cell] asked for [printer] before it was its turn: loaded once, shared.
    assert printer.lookup_object("load_cell").toolhead is toolhead
    assert printer.get_status() == {
        "virtual_printer": {"time_s": 42.0, "scenario": "noisy-mains"},
        "printer": {"max_velocity": 300.0, "steppers": 2},
        "load_cell": {"counts_per_gram": 10.0, "is_calibrated": True},
        "load_cell right": {"counts_per_gram": None, "is_calibrated": False},
    }
    assert printer.lookup_object("nope", None) is None
    with pytest.raises(ConfigError, match="Unknown printer object 'nope'"):
        printer.lookup_object("nope")


def test_given_backend_is_used_and_its_section_not_checked(tmp_path, fake_modules):
    backend = FakeBackend()
    printer, _, _ = build(tmp_path, backend=backend)
    assert printer.backend is backend and printer.lookup_object("virtual_printer") is backend


def test_status_command(tmp_path, fake_modules):
    printer, responses, _ = build(tmp_path)
    responses.clear()
    printer.gcode.run_script("STATUS OBJECT=load_cell")
    # As JSON, as Moonraker's clients read status (no Python reprs: true, null, "text").
    assert responses == ["// counts_per_gram: 10.0", "// is_calibrated: true"]
    responses.clear()
    printer.gcode.run_script("STATUS")
    assert responses == [
        # Ready in Klipper's sense, and what is still to do before probing, with its command.
        "// Printer is ready; before probing: load_cell right is not calibrated: run LOAD_CELL_CALIBRATE "
        "LOAD_CELL=right (then SAVE_CONFIG)",
        '// virtual_printer: time_s=42.0 scenario="noisy-mains"',
        "// printer: max_velocity=300.0 steppers=2",
        "// load_cell: counts_per_gram=10.0 is_calibrated=true",
        "// load_cell right: counts_per_gram=null is_calibrated=false",
    ]
    with pytest.raises(GCodeError) as info:
        printer.gcode.run_script("STATUS OBJECT=bed_mesh")
    assert str(info.value) == ("Error on 'STATUS OBJECT=bed_mesh': no status object 'bed_mesh' "
                               "(one of: load_cell, load_cell right, printer, virtual_printer)")


def test_unknown_sections_name_the_closest_modules_of_extras(tmp_path):
    # The real tapcell.extras (every module with a loader) and the accepted hardware sections are
    # too many to list: the closest names are given.
    assert config_error(tmp_path, CONFIG + "[fann]\nspeed: 1\n") == (
        f"{tmp_path}/printer.cfg: [fann]: Section 'fann' is not a valid config section (did you mean fan?)")
    assert config_error(tmp_path, "[probe]\n", backend=FakeBackend()) == (
        f"{tmp_path}/printer.cfg: [probe]: Section 'probe' is not a valid config section "
        "(tapcell.extras.probe does not support [probe])")
    assert config_error(tmp_path, CONFIG + "[bed_mesh.two_pass]\n") == (
        f"{tmp_path}/printer.cfg: [bed_mesh.two_pass]: Section 'bed_mesh.two_pass' is not a valid config section "
        "(did you mean bed_mesh or endstop_phase?)")
    assert set(printer_module.section_kinds()) >= {"fan", "heater_bed", "safe_z_home", "exclude_object", "extruder"}


@pytest.mark.parametrize("extra, problem", [
    ("[widget]\n", "[widget]: Section 'widget' is not a valid config section"),
    ("[printer extra]\n", "[printer extra]: Section 'printer extra' is not a valid config section "
                          "(tapcell_test_toolhead does not support [printer NAME])"),
    ("[stepper_y]\nrotation_distance: 40\nstep_pinn: PA1\n",
     "[stepper_y] step_pinn = PA1: Option 'step_pinn' is not valid in section 'stepper_y'"),
    ("[load_cell]\ncounts_per_gram: 0.5\n", "[load_cell] counts_per_gram = 0.5: must be at least 1 (allowed: 1 to 1000000)"),
    ("[load_cell]\nsensor: hx717\n", "[load_cell] sensor = hx717: Option 'sensor' is not valid in section 'load_cell'"),
    ("[load_cell left]\n[load_cell  left]\n", None),  # the same section twice merges: no duplicate command
])
def test_config_errors_name_file_and_section(tmp_path, fake_modules, extra, problem):
    text = CONFIG + extra
    if problem is None:
        build(tmp_path, text)
        return
    assert config_error(tmp_path, text) == f"{tmp_path}/printer.cfg: {problem}"


def test_stepper_section_needs_its_reader(tmp_path, fake_modules):
    assert config_error(tmp_path, "[stepper_x]\nrotation_distance: 4\n") == (
        f"{tmp_path}/printer.cfg: [stepper_x]: this section is read by [printer], which is missing")


def test_duplicate_mux_registration_is_a_config_error(tmp_path, fake_modules):
    assert config_error(tmp_path, CONFIG + "[load_cell_probe]\n") == (
        f"{tmp_path}/printer.cfg: [load_cell_probe]: Command 'FAKE_CALIBRATE' without LOAD_CELL= is already registered")


def test_a_section_module_is_found_by_its_name_alone(tmp_path, fake_modules, monkeypatch):
    # A new config section is a new module in extras/: nothing to register.
    spool = types.ModuleType("tapcell_test_spool_scale")
    spool.load_config = lambda section, printer: FakeBackend(section)  # any object with a status
    install_extras(monkeypatch, {"load_cell": sys.modules["tapcell_test_extras.load_cell"], "spool_scale": spool})
    printer, _, _ = build(tmp_path, CONFIG + "[spool_scale]\nscenario: kitchen\n")
    assert printer.get_status(7.0)["spool_scale"] == {"time_s": 7.0, "scenario": "kitchen"}


def test_a_broken_import_inside_a_module_is_not_hidden(tmp_path, monkeypatch):
    package = tmp_path / "tapcell_test_broken_extras"
    package.mkdir()
    (package / "__init__.py").write_text("")
    (package / "bed_mesh.py").write_text("import tapcell_test_dependency_that_is_missing\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setattr(printer_module, "EXTRAS_PACKAGE", package.name)
    with pytest.raises(ModuleNotFoundError, match="tapcell_test_dependency_that_is_missing"):
        build(tmp_path, "[bed_mesh]\n", backend=FakeBackend())


def test_events(tmp_path, fake_modules):
    printer, _, _ = build(tmp_path)
    seen = []
    printer.register_event_handler("load_cell:calibrate", lambda *args: seen.append(args) or len(seen))
    assert printer.send_event("load_cell:calibrate", "load_cell", 87.5) == [1]
    assert printer.send_event("nobody:listens") == []
    assert seen == [("load_cell", 87.5)]


def test_save_config_round_trip_and_restart(tmp_path, fake_modules):
    printer, responses, path = build(tmp_path)
    responses.clear()
    printer.gcode.run_script("SAVE_CONFIG")
    assert responses == ["// No pending config changes to save"]
    responses.clear()
    printer.gcode.run_script("FAKE_CALIBRATE LOAD_CELL=right COUNTS=87.944082\nSAVE_CONFIG\n"
                             "STATUS OBJECT=\"load_cell right\"")
    assert responses == [
        "// counts_per_gram: 87.94408",
        f"// Config saved to {path}; restarting",
        "// toolhead ready",
        "// Printer is ready",
        "// counts_per_gram: 87.9441",
        "// is_calibrated: true",
    ]
    assert printer.lookup_object("load_cell right").counts_per_gram == 87.94408
    assert path.read_text().startswith(CONFIG)
    assert (tmp_path / "printer.cfg.bak").read_text() == CONFIG
    # A brand-new printer from the same file sees the saved value.
    again, _, _ = build_existing(path)
    assert again.lookup_object("load_cell right").counts_per_gram == 87.94408


def build_existing(path: Path):
    responses: list[str] = []
    return Printer.from_config(str(path), responses=responses), responses, path


def test_restart_with_a_broken_config_halts_until_fixed(tmp_path, fake_modules):
    printer, responses, path = build(tmp_path)
    restart_events = []
    printer.register_event_handler("printer:restart", lambda: restart_events.append(True))
    path.write_text(CONFIG + "[load_cell]\ncounts_per_gram: -1\n")
    responses.clear()
    assert printer.gcode.run_script_reporting_errors("RESTART") is False
    assert restart_events == [True]
    assert responses == [
        f"!! {path}: [load_cell] counts_per_gram = -1: must be at least 1 (allowed: 1 to 1000000)",
        "!! The printer is halted: fix the config file, then RESTART",
    ]
    assert printer.state == "error" and printer.objects == {}
    with pytest.raises(GCodeError, match='Unknown command:"FAKE_CALIBRATE"'):
        printer.gcode.run_script("FAKE_CALIBRATE COUNTS=5")
    responses.clear()
    printer.gcode.run_script("STATUS")
    assert responses == [f"// {path}: [load_cell] counts_per_gram = -1: must be at least 1 (allowed: 1 to 1000000)"]
    path.write_text(CONFIG)
    responses.clear()
    printer.gcode.run_script("RESTART")
    assert responses == ["// toolhead ready", "// Printer is ready"]
    assert printer.state == "ready" and printer.lookup_object("load_cell").counts_per_gram == 10.0


def test_example_config_parses():
    config = ConfigFile.read(DEFAULT_CONFIG)
    assert config.sections()[:8] == ["virtual_printer", "printer", "stepper_x", "stepper_y", "stepper_z",
                                     "safe_z_home", "load_cell_probe", "bed_mesh"]
    # What Mainsail and Fluidd look for to pause, resume and cancel a print.
    assert {"pause_resume", "display_status", "gcode_macro PAUSE", "gcode_macro RESUME",
            "gcode_macro CANCEL_PRINT"} <= set(config.sections())
    probe = config.getsection("load_cell_probe")
    assert probe.get("sensor_type") == "hx717" and probe.get("sample_rate") == "320"
    assert not probe.has_option("counts_per_gram")  # shipped uncalibrated
    stepper_z = config.getsection("stepper_z")
    assert stepper_z.get("position_min") == "-2"
    assert stepper_z.get("endstop_pin") == "probe:z_virtual_endstop"
    assert config.getsection("printer").get("kinematics") == "cartesian"


def test_example_config_loads_through_the_real_modules():
    printer = Printer.from_config(str(DEFAULT_CONFIG), responses=[])
    assert printer.state == "ready"
