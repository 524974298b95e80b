"""Issue 20: the Kalico plug-in file: readable by Kalico's user, never written over or removed
when it is not ours or was edited, refused at once when it is a FIFO, a directory or a link."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from tapcell.tools import kalico_plugin
from tapcell.tools.kalico_plugin import PLUGIN_FILE, PluginError, install, plugin_text, uninstall


@pytest.fixture
def klippy(tmp_path) -> Path:
    folder = tmp_path / "klippy"
    (folder / "plugins").mkdir(parents=True)
    (folder / "printer.py").write_text("# Kalico\n")
    (folder / "plugins" / "other.py").write_text("# another plug-in\n")
    return folder


def test_the_plug_in_is_written_0644_whatever_the_umask(klippy):
    old = os.umask(0o077)  # root's `sudo` with a strict umask: Kalico's user could not read a 0600 file
    try:
        target = install(klippy)
    finally:
        os.umask(old)
    assert oct(target.stat().st_mode & 0o777) == oct(0o644)
    assert target.read_text() == plugin_text()
    assert (klippy / "plugins" / "other.py").read_text() == "# another plug-in\n"


def test_uninstall_removes_an_unchanged_plug_in_also_of_another_version(klippy):
    target = install(klippy)
    target.write_text(plugin_text().replace(f"(tapcell {kalico_plugin.__version__})", "(tapcell 0.0.1)"))
    assert uninstall(klippy) == target
    assert sorted(os.listdir(klippy / "plugins")) == ["other.py"]
    assert uninstall(klippy) is None


def test_uninstall_keeps_an_edited_plug_in_and_says_what_differs(klippy):
    target = install(klippy)
    target.write_text(plugin_text() + "\n# my own tuning\nEXTRA = 1\n")
    with pytest.raises(PluginError) as kept:
        uninstall(klippy)
    message = str(kept.value)
    assert message.startswith(f"{target} was changed since tapcell wrote it: not removing it")
    lines = message.splitlines()[1:]
    assert lines[:2] == ["  --- as tapcell wrote it", "  +++ now"]
    assert lines[2].startswith("  @@ ") and lines[3:] == ["  +", "  +# my own tuning", "  +EXTRA = 1"]
    assert target.read_text().endswith("EXTRA = 1\n")


@pytest.mark.parametrize("kind", ["fifo", "directory", "link", "foreign"])
def test_what_is_not_our_file_is_refused_at_once_and_left(klippy, tmp_path, kind):
    target = klippy / "plugins" / PLUGIN_FILE
    if kind == "fifo":
        os.mkfifo(target)
        expected = "is a FIFO (named pipe), not a file tapcell wrote"
    elif kind == "directory":
        target.mkdir()
        expected = "is a directory, not a file tapcell wrote"
    elif kind == "link":
        (tmp_path / "precious.py").write_text(plugin_text())  # even a copy of ours, elsewhere
        target.symlink_to(tmp_path / "precious.py")
        expected = f"is a symbolic link (to {tmp_path / 'precious.py'}), not a file tapcell wrote"
    else:
        target.write_text("# someone else's classifier\n")
        expected = "exists and was not written by tapcell"
    before = os.lstat(target)
    for action in (install, uninstall):
        with pytest.raises(PluginError, match=f"^{target} {expected}: leaving it as it is$".replace("(", r"\(")
                           .replace(")", r"\)")):
            action(klippy)
    after = os.lstat(target)
    assert (after.st_ino, after.st_mode) == (before.st_ino, before.st_mode)


def test_temp_files_of_killed_installs_are_removed(klippy):
    plugins = klippy / "plugins"
    (plugins / f".{PLUGIN_FILE}.0a1b2c3d.tmp").write_text("half a plug-in")
    (plugins / ".other.py.0a1b2c3d.tmp").write_text("not ours")
    install(klippy)
    assert sorted(os.listdir(plugins)) == [".other.py.0a1b2c3d.tmp", "other.py", PLUGIN_FILE]
