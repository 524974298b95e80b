"""A command whose optional dependency is missing says, in one line, which extra brings it (no
ModuleNotFoundError traceback); `tapcell init` writes a starter printer folder."""

from __future__ import annotations

import json
import os
from pathlib import Path
import subprocess
import sys

import pytest

from tapcell.tap import tap_to_json_dict
from tapcell.tap.synth import synth_tap
from tapcell.tools import cli, init


CHECKOUT = Path(__file__).resolve().parents[1]
WITHOUT_MODULE = """
import importlib.abc, sys
missing = sys.argv[1]
class Refuse(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name == missing or name.startswith(missing + "."):
            raise ModuleNotFoundError(f"No module named {name!r}", name=name)
sys.meta_path.insert(0, Refuse())
from tapcell.tools import cli
sys.exit(cli.main(sys.argv[2:]))
"""


@pytest.fixture
def inputs(tmp_path):
    """A G-code script and a tap file to hand the commands."""
    script = tmp_path / "script.gcode"
    script.write_text("G28\n")
    tap = tmp_path / "tap.json"
    tap.write_text(json.dumps(tap_to_json_dict(synth_tap(seed=3))))
    return {"SCRIPT": str(script), "TAP": str(tap), "PNG": str(tmp_path / "tap.png"), "HOME": str(tmp_path / "home")}


@pytest.mark.parametrize("command, args, missing, extra", [
    ("demo", [], "rich", "tools"),
    ("console", [], "jinja2", "sim"),
    ("run", ["SCRIPT"], "scipy", "sim"),
    ("analyze", ["--plot", "PNG", "TAP"], "matplotlib", "plot"),
])
def test_a_missing_extra_is_named_in_one_line(command, args, missing, extra, inputs):
    # A fresh interpreter in which importing `missing` raises ModuleNotFoundError, as if not installed.
    done = subprocess.run([sys.executable, "-c", WITHOUT_MODULE, missing, command,
                           *(inputs.get(arg, arg) for arg in args)],
                          capture_output=True, text=True, timeout=120, env={**os.environ, "TAPCELL_HOME": inputs["HOME"]})
    assert done.returncode == 1, done.stderr
    # The pip line names what this tapcell was installed from (here the checkout, editable).
    assert done.stderr == (f"tapcell {command}: needs {missing}, which comes with tapcell's [{extra}] extra: "
                           f"pip install '{CHECKOUT}[{extra}]' (or [all])\n")


def test_an_unexpected_missing_module_is_not_hidden(monkeypatch):
    monkeypatch.setattr(cli, "SUBCOMMANDS", {**cli.SUBCOMMANDS, "broken": ("tapcell.no_such_module", "")})
    with pytest.raises(ModuleNotFoundError):
        cli.main(["broken"])


def test_every_optional_dependency_has_its_extra():
    """Each import the extras bring maps to the extra that brings it (pyproject.toml's lists)."""
    import tomllib
    from pathlib import Path

    project = tomllib.loads((Path(__file__).resolve().parents[1] / "pyproject.toml").read_text())["project"]
    extras = project["optional-dependencies"]
    import_name = {"jinja2": "jinja2", "prompt_toolkit": "prompt_toolkit"}
    for extra in ("sim", "plot", "tools"):
        for requirement in extras[extra]:
            if requirement.startswith("tapcell["):
                continue
            package = requirement.split(">")[0].split("=")[0].strip().lower()
            assert cli.extra_providing(import_name.get(package, package)) == extra, requirement


def test_init_writes_the_folder_and_never_overwrites(tmp_path, capsys):
    folder = tmp_path / "printer_data"
    assert cli.main(["init", str(folder)]) == 0
    out = capsys.readouterr().out.splitlines()
    assert sorted(p.name for p in folder.iterdir()) == ["comms", "config", "gcodes", "logs"]
    printer_cfg = folder / "config" / "printer.cfg"
    assert "[load_cell_probe]" in printer_cfg.read_text() and "[safe_z_home]" in printer_cfg.read_text()
    assert f"klippy_uds_address: {folder / 'comms' / 'klippy.sock'}" in (folder / "config" / "moonraker.conf").read_text()
    assert out[2] == f"    tapcell console --config {printer_cfg}"
    assert out[4].startswith(f"    tapcell serve --config {printer_cfg} --socket {folder / 'comms' / 'klippy.sock'}")
    printer_cfg.write_text("# mine\n")
    assert cli.main(["init", str(folder), "--example", "voron-load-cell.cfg"]) == 1
    assert "already there (--force overwrites)" in capsys.readouterr().err
    assert printer_cfg.read_text() == "# mine\n"
    assert cli.main(["init", str(folder), "--example", "voron-load-cell.cfg", "--force"]) == 0
    assert "[mcu toolboard]" in printer_cfg.read_text()
    assert init.next_commands(tmp_path / "a b")[0] == f"tapcell console --config '{tmp_path / 'a b' / 'config' / 'printer.cfg'}'"
