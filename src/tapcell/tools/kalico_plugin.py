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
import os
import sys
import tempfile
from pathlib import Path

from tapcell import __version__
from tapcell.tools.cli import install_source

PLUGIN_FILE = "tapcell_classifier.py"
TEMPLATE = Path(__file__).with_name("kalico_plugin.template")
MARKER = "# tapcell as Kalico's tap classifier."  # the first line: the file is ours to replace or remove


class PluginError(Exception):
    """The plug-in cannot be installed or removed here; the message says why."""


def plugin_text() -> str:
    return TEMPLATE.read_text(encoding="utf-8").replace("@TAPCELL_VERSION@", __version__)


def _plugins_dir(klippy_dir: Path) -> Path:
    plugins = klippy_dir / "plugins"
    if not (klippy_dir / "printer.py").is_file() or not plugins.is_dir():
        raise PluginError(f"{klippy_dir} is not Kalico's klippy folder (it needs printer.py and a plugins/ folder; "
                          "Klipper has no plug-ins)")
    return plugins


def _ours(path: Path) -> bool:
    with path.open(encoding="utf-8", errors="replace") as handle:
        return handle.readline().rstrip("\n") == MARKER


def install(klippy_dir: Path) -> Path:
    """Write (or update) the plug-in atomically; returns its path."""
    target = _plugins_dir(klippy_dir) / PLUGIN_FILE
    if target.exists() and not _ours(target):
        raise PluginError(f"{target} exists and was not written by tapcell: not replacing it")
    with tempfile.NamedTemporaryFile("w", encoding="utf-8", dir=target.parent, prefix=".tapcell-",
                                     suffix=".tmp", delete=False) as handle:
        handle.write(plugin_text())
    os.replace(handle.name, target)
    return target


def uninstall(klippy_dir: Path) -> Path | None:
    """Remove the plug-in; returns its path, or None when it was not installed."""
    target = _plugins_dir(klippy_dir) / PLUGIN_FILE
    if not target.exists():
        return None
    if not _ours(target):
        raise PluginError(f"{target} was not written by tapcell: not removing it")
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
