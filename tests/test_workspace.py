"""`tapcell console` never rewrites a file git tracks (tapcell.tools.workspace): it works on a
copy in the user's folder, where SAVE_CONFIG writes; `--scenario NAME`."""

from __future__ import annotations

import io
import subprocess

import pytest

from tapcell.tools import cli, frontend, workspace
from tapcell.tools.workspace import ScenarioError, copy_path, is_tracked, with_scenario

CALIBRATE = ["LOAD_CELL_CALIBRATE\n", "TARE\n", "SIM_PLACE_WEIGHT GRAMS=1000\n", "CALIBRATE GRAMS=1000\n",
             "ACCEPT\n", "SAVE_CONFIG\n"]


def console(monkeypatch, capsys, lines, *args) -> tuple[int, str]:
    monkeypatch.setattr("sys.stdin", io.StringIO("".join(lines)))  # not a terminal, like a pipe
    status = cli.main(["console", *map(str, args)])
    return status, capsys.readouterr().out


def test_save_config_in_the_console_writes_a_copy_not_the_tracked_example(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("TAPCELL_HOME", str(tmp_path / "home"))
    example = frontend.DEFAULT_CONFIG
    assert is_tracked(example)
    before = example.read_bytes()
    status, out = console(monkeypatch, capsys, CALIBRATE)
    copy = copy_path(example)
    assert copy.parent == tmp_path / "home" and copy.name.startswith("virtual-printer-")
    assert status == 0 and example.read_bytes() == before
    assert out.splitlines()[0] == (f"// Working on a copy of {example} (git tracks it, so it is never rewritten): "
                                   f"{copy}; SAVE_CONFIG writes there")
    assert f"// Config saved to {copy}; restarting" in out
    assert "counts_per_gram" in copy.read_text()
    # The next session goes on from the saved calibration; --fresh starts over.
    status, out = console(monkeypatch, capsys, ["LOAD_CELL_READ\n"])
    assert out.splitlines()[0].startswith(f"// Working on your copy {copy} (of {example}, which git tracks)")
    assert "Load Cell Probe Error" not in out and "not calibrated" not in out
    console(monkeypatch, capsys, [], "--fresh")
    assert copy.read_bytes() == before


def test_an_untracked_config_is_used_in_place_and_scenario_is_written_there(tmp_path, monkeypatch, capsys):
    config = tmp_path / "mine.cfg"
    config.write_text("[virtual_printer]\nscenario: clean\nseed: 3\n")
    status, out = console(monkeypatch, capsys, ["SIM_TRUTH\n"], "--config", config, "--scenario", "warped-bed")
    assert status == 0
    assert out.splitlines()[0] == f"// Working on {config} (SAVE_CONFIG writes there); scenario warped-bed"
    assert config.read_text() == "[virtual_printer]\nscenario: warped-bed\nseed: 3\n"
    status, out = console(monkeypatch, capsys, [], "--config", config, "--scenario", "lava")
    assert status == 2 and config.read_text().count("warped-bed") == 1


def test_with_scenario_edits_only_the_virtual_printer_section():
    text = "[printer]\nscenario_note: x\n\n[virtual_printer]\nseed: 1\n\n[bed_mesh]\nspeed: 5\n"
    assert with_scenario(text, "oozy") == ("[printer]\nscenario_note: x\n\n[virtual_printer]\nscenario: oozy\n"
                                           "seed: 1\n\n[bed_mesh]\nspeed: 5\n")
    assert with_scenario("[virtual_printer]\nscenario = clean\n", "oozy") == "[virtual_printer]\nscenario: oozy\n"
    assert with_scenario("[printer]\n", "oozy") == "[virtual_printer]\nscenario: oozy\n\n[printer]\n"
    with pytest.raises(ScenarioError, match=r"unknown scenario 'lava'; one of: clean, "):
        with_scenario("", "lava")


def test_scenario_through_a_symlinked_config_rewrites_its_target(tmp_path, monkeypatch, capsys):
    """A printer.cfg linked to one kept elsewhere stays a link (the config's own atomic write)."""
    target = tmp_path / "kept" / "printer.cfg"
    target.parent.mkdir()
    target.write_text("[virtual_printer]\nscenario: clean\nseed: 3\n")
    link = tmp_path / "printer.cfg"
    link.symlink_to(target)
    status, _ = console(monkeypatch, capsys, [], "--config", link, "--scenario", "oozy")
    assert status == 0 and link.is_symlink()
    assert target.read_text() == "[virtual_printer]\nscenario: oozy\nseed: 3\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["kept", "printer.cfg"]  # no temp file left


def git_tracked_config(folder, text: str):
    """A printer.cfg that git tracks, in a repository of its own at `folder`."""
    folder.mkdir(parents=True)
    config = folder / "printer.cfg"
    config.write_text(text)
    subprocess.run(["git", "init", "-q", str(folder)], check=True, timeout=30)
    subprocess.run(["git", "-C", str(folder), "add", "printer.cfg"], check=True, timeout=30)
    assert is_tracked(config)
    return config


def test_two_tracked_printer_cfgs_get_two_copies(tmp_path, monkeypatch, capsys):
    """The issue's case: printer B silently ran printer A's config, both named printer.cfg."""
    monkeypatch.setenv("TAPCELL_HOME", str(tmp_path / "home"))
    first = git_tracked_config(tmp_path / "a", '[gcode_macro WHO]\ngcode:\n  {action_respond_info("printer A")}\n')
    second = git_tracked_config(tmp_path / "b", '[gcode_macro WHO]\ngcode:\n  {action_respond_info("printer B")}\n')
    assert copy_path(first) != copy_path(second)
    assert console(monkeypatch, capsys, ["WHO\n"], "--config", first)[1].count("// printer A") == 1
    status, out = console(monkeypatch, capsys, ["WHO\n"], "--config", second)
    assert status == 0 and "// printer B" in out and "printer A" not in out
    assert sorted(p.read_text().count("printer ") for p in (tmp_path / "home").iterdir()) == [1, 1]


def test_run_works_on_the_console_s_copy_so_its_calibration_holds(tmp_path, monkeypatch, capsys):
    """The README's line: calibrate in the console, then `tapcell run` homes with that calibration."""
    monkeypatch.setenv("TAPCELL_HOME", str(tmp_path / "home"))
    script = tmp_path / "home-and-probe.gcode"
    script.write_text("G28\nPROBE\n")
    example = str(frontend.DEFAULT_CONFIG)
    status = cli.main(["run", "--config", example, str(script)])
    out, err = capsys.readouterr()
    assert status == 1 and "not calibrated" in out  # a first run: nothing calibrated yet
    assert err.splitlines()[0].startswith(f"// Working on a copy of {example} (git tracks it")
    assert console(monkeypatch, capsys, CALIBRATE)[0] == 0
    status = cli.main(["run", "--config", example, str(script)])
    out, err = capsys.readouterr()
    assert status == 0, out
    assert "// probe at 117.500,117.500 is z=" in out
    assert err.splitlines()[0] == (f"// Working on your copy {copy_path(example)} (of {example}, which git tracks); "
                                   "SAVE_CONFIG writes there; --fresh starts again from the original")


def test_an_installed_example_is_never_rewritten(tmp_path, monkeypatch):
    """Installed, the examples are package files (not tracked by git): still worked on as a copy."""
    monkeypatch.setenv("TAPCELL_HOME", str(tmp_path / "home"))
    package = tmp_path / "site-packages" / "tapcell"
    (package / "examples").mkdir(parents=True)
    example = package / "examples" / "virtual-printer.cfg"
    example.write_text("[printer]\n")
    monkeypatch.setattr(workspace, "PACKAGE_DIR", package)
    path, where = workspace.working_config(example)
    assert path == copy_path(example) and path.read_text() == "[printer]\n"
    assert where == (f"Working on a copy of {example} (it is installed with tapcell, so it is never rewritten): "
                     f"{path}; SAVE_CONFIG writes there")


def test_serve_works_on_the_copy_of_a_tracked_config(tmp_path, monkeypatch):
    """SAVE_CONFIG from Mainsail must not rewrite the tracked example either."""
    from tapcell.tools.serve import served_argv

    monkeypatch.setenv("TAPCELL_HOME", str(tmp_path / "home"))
    example = str(frontend.DEFAULT_CONFIG)
    argv, where = served_argv(["--config", example, "--socket", "k.sock"])
    assert argv == ["--config", str(copy_path(example)), "--socket", "k.sock"]
    assert where.startswith(f"Working on a copy of {example} (git tracks it")
    assert served_argv([f"--config={example}", "--socket", "k.sock"])[0][0] == f"--config={copy_path(example)}"
    mine = tmp_path / "printer.cfg"
    mine.write_text("[printer]\n")
    assert served_argv(["--socket", "k.sock", "--config", str(mine)]) == (["--socket", "k.sock", "--config", str(mine)],
                                                                          None)
    assert served_argv(["--help"]) == (["--help"], None)
