"""`tapcell kalico-plugin --install KLIPPY_DIR` / `--uninstall KLIPPY_DIR`: tapcell as Kalico's
tap classifier.

Kalico loads every module in `klippy/plugins/` and lets it register components; the
`[load_cell_probe] tap_classifier:` option picks a registered classifier by name. This writes
one small module there, `tapcell_classifier.py` (from kalico_plugin.template next to this
file), registering `tap_classifier: tapcell`. tapcell itself must be importable by Kalico's
Python: installed there without extras (from a checkout or a wheel), it needs numpy alone and
changes none of Kalico's pinned versions.
"""

from __future__ import annotations

import argparse
import difflib
import fcntl
import os
import re
import stat
import sys
from pathlib import Path

from tapcell import __version__
from tapcell.files import FileRefused, read_limited, remove_stale_temps, replace_atomically
from tapcell.tools.cli import install_source

PLUGIN_FILE = "tapcell_classifier.py"
TEMPLATE = Path(__file__).with_name("kalico_plugin.template")
MARKER = "# tapcell as Kalico's tap classifier."  # the first line: the file is ours to replace or remove
VERSION_PLACEHOLDER = "@TAPCELL_VERSION@"
PLUGIN_MODE = 0o644  # Kalico runs as its own user: it must read a plug-in a root install wrote
MAX_PLUGIN_BYTES = 1024 * 1024  # ours is a few kB; a larger file of that name is not ours
MAX_DIFF_LINES = 12  # of an edited plug-in, shown when --uninstall keeps it


class PluginError(Exception):
    """The plug-in cannot be installed or removed here; the message says why."""


def plugin_text() -> str:
    return TEMPLATE.read_text(encoding="utf-8").replace(VERSION_PLACEHOLDER, __version__)


def _plugins_dir(klippy_dir: Path) -> Path:
    plugins = klippy_dir / "plugins"
    if not (klippy_dir / "printer.py").is_file() or not plugins.is_dir():
        raise PluginError(f"{klippy_dir} is not Kalico's klippy folder (it needs printer.py and a plugins/ folder; "
                          "Klipper has no plug-ins)")
    return plugins


def _installed_text(target: Path) -> str | None:
    """The text of the file at `target` (None when there is none), read without blocking and
    without following a symbolic link; PluginError when it is not a plug-in file of ours."""
    try:
        info = os.lstat(target)
    except FileNotFoundError:
        return None
    if stat.S_ISLNK(info.st_mode):
        raise PluginError(f"{target} is a symbolic link (to {os.readlink(target)}), not a file tapcell wrote: "
                          f"leaving it as it is")
    try:
        text = read_limited(target, MAX_PLUGIN_BYTES).decode("utf-8", errors="replace")
    except FileRefused as exc:
        raise PluginError(f"{target} {exc}, not a file tapcell wrote: leaving it as it is") from None
    if text.split("\n", 1)[0] != MARKER:
        raise PluginError(f"{target} exists and was not written by tapcell: leaving it as it is")
    return text


def _is_unchanged(text: str) -> bool:
    """Whether `text` is the plug-in as some tapcell version wrote it (only the version differs)."""
    before, _, after = TEMPLATE.read_text(encoding="utf-8").partition(VERSION_PLACEHOLDER)
    return re.fullmatch(re.escape(before) + r"[^\s)]+" + re.escape(after), text) is not None


def _differences(text: str) -> str:
    """What the user changed in the plug-in, as the first lines of a unified diff."""
    expected = plugin_text().splitlines()
    diff = [line for line in difflib.unified_diff(expected, text.splitlines(), "as tapcell wrote it",
                                                  "now", n=0, lineterm="")]
    shown = diff[:MAX_DIFF_LINES] + (["..."] if len(diff) > MAX_DIFF_LINES else [])
    return "\n".join("  " + line for line in shown)


class _plugins_lock:
    """An exclusive lock on plugins/ while writing there: concurrent installs take turns, so
    the one holding it may remove temp files that killed installs left (Kalico imports every
    module in plugins/)."""

    def __init__(self, plugins: Path):
        self.fd = os.open(plugins, os.O_RDONLY | os.O_DIRECTORY)

    def __enter__(self) -> None:
        fcntl.flock(self.fd, fcntl.LOCK_EX)

    def __exit__(self, *exc_info) -> None:
        os.close(self.fd)


def _owner_for(plugins: Path) -> tuple[int, int] | None:
    """The owner of plugins/ when root installs into another user's Kalico (that user reads it)."""
    info = os.stat(plugins)
    return (info.st_uid, info.st_gid) if os.geteuid() == 0 and info.st_uid != 0 else None


def install(klippy_dir: Path) -> Path:
    """Write (or update) the plug-in atomically, mode 0644; returns its path."""
    plugins = _plugins_dir(klippy_dir)
    target = plugins / PLUGIN_FILE
    with _plugins_lock(plugins):
        _installed_text(target)  # refuses what is not ours
        remove_stale_temps(str(target))
        replace_atomically(str(target), plugin_text().encode("utf-8"), mode=PLUGIN_MODE, owner=_owner_for(plugins))
    return target


def uninstall(klippy_dir: Path) -> Path | None:
    """Remove the plug-in if it is as tapcell wrote it; returns its path, or None when it was not
    installed. An edited plug-in is kept: PluginError shows what differs."""
    plugins = _plugins_dir(klippy_dir)
    target = plugins / PLUGIN_FILE
    with _plugins_lock(plugins):
        text = _installed_text(target)
        remove_stale_temps(str(target))
        if text is None:
            return None
        if not _is_unchanged(text):
            raise PluginError(f"{target} was changed since tapcell wrote it: not removing it (remove it by hand "
                              f"if the changes can go). What differs:\n{_differences(text)}")
        target.unlink()
    return target


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="tapcell kalico-plugin", description="Install tapcell as Kalico's "
                                     "tap classifier ([load_cell_probe] tap_classifier: tapcell), or remove it.")
    action = parser.add_mutually_exclusive_group(required=True)
    action.add_argument("--install", metavar="KLIPPY_DIR", help="Kalico's klippy folder (holding plugins/)")
    action.add_argument("--uninstall", metavar="KLIPPY_DIR", help="remove the plug-in from this klippy folder")
    args = parser.parse_args(argv)
    try:
        if args.install:
            path = install(Path(args.install))
            print(f"tapcell kalico-plugin: wrote {path}\n"
                  "Set 'tap_classifier: tapcell' in [load_cell_probe] and RESTART Kalico. tapcell must be "
                  f"installed in Kalico's Python environment ('pip install {install_source()}' there, no "
                  "extras: numpy alone).")
        else:
            path = uninstall(Path(args.uninstall))
            print(f"tapcell kalico-plugin: removed {path}" if path else
                  "tapcell kalico-plugin: the plug-in was not installed")
    except (PluginError, OSError) as exc:
        print(f"tapcell kalico-plugin: {exc}", file=sys.stderr)
        return 1
    return 0
