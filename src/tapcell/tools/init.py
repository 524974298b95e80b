"""`tapcell init [DIR]`: a starter printer folder, laid out as Moonraker's data folder.

    DIR/config/printer.cfg      one of the example configs (the virtual printer by default)
    DIR/config/moonraker.conf   the minimal Moonraker config that talks to `tapcell serve`
    DIR/gcodes/ DIR/logs/ DIR/comms/

then the commands to go on with. It never overwrites a file that is there (`--force` does).
It needs nothing but the package, so it is how an installed tapcell starts outside a checkout.
"""

from __future__ import annotations

import argparse
import os
import shlex
import sys
from pathlib import Path

from tapcell.package_files import example_config, example_names

DEFAULT_DIR = "printer_data"
SUBFOLDERS = ("config", "gcodes", "logs", "comms")


def moonraker_conf(data_dir: Path) -> str:
    """A minimal moonraker.conf for `tapcell serve` on this folder: local clients trusted, and no
    check of a Klipper service or install that a virtual printer does not have."""
    return (f"# Moonraker for tapcell's virtual printer: start 'tapcell serve' first (see printer.cfg's folder).\n"
            f"[server]\nhost: 127.0.0.1\nklippy_uds_address: {data_dir / 'comms' / 'klippy.sock'}\n\n"
            f"[authorization]\ntrusted_clients:\n  127.0.0.0/8\n\n"
            f"[machine]\nprovider: none\nvalidate_service: False\nvalidate_config: False\n")


def next_commands(data_dir: Path) -> list[str]:
    """The commands that use the folder, with its paths quoted for a shell."""
    config = shlex.quote(str(data_dir / "config" / "printer.cfg"))
    return [
        f"tapcell console --config {config}",
        f"tapcell serve --config {config} --socket {shlex.quote(str(data_dir / 'comms' / 'klippy.sock'))} "
        f"--gcodes-dir {shlex.quote(str(data_dir / 'gcodes'))} "
        f"--log-file {shlex.quote(str(data_dir / 'logs' / 'klippy.log'))}",
        f"moonraker -d {shlex.quote(str(data_dir))}",
    ]


def main(argv: list[str]) -> int:
    names = example_names()
    parser = argparse.ArgumentParser(prog="tapcell init", description="Write a starter printer folder (Moonraker's "
                                     "data folder layout: config/printer.cfg, gcodes/, logs/, comms/) and print "
                                     "the commands to go on with.")
    parser.add_argument("dir", nargs="?", default=DEFAULT_DIR, help="the folder (default: %(default)s)")
    parser.add_argument("--example", choices=names, default="virtual-printer.cfg",
                        help="the example config printer.cfg starts from (default: %(default)s)")
    parser.add_argument("--force", action="store_true", help="overwrite printer.cfg and moonraker.conf")
    args = parser.parse_args(argv)
    data_dir = Path(os.path.abspath(args.dir))
    files = {data_dir / "config" / "printer.cfg": example_config(args.example).read_text(encoding="utf-8"),
             data_dir / "config" / "moonraker.conf": moonraker_conf(data_dir)}
    there = [path for path in files if path.exists()]
    if there and not args.force:
        print(f"tapcell init: {', '.join(map(str, there))} already there (--force overwrites)", file=sys.stderr)
        return 1
    try:
        for name in SUBFOLDERS:
            (data_dir / name).mkdir(parents=True, exist_ok=True)
        for path, text in files.items():
            path.write_text(text, encoding="utf-8")
    except OSError as exc:
        print(f"tapcell init: cannot write {args.dir}: {exc}", file=sys.stderr)
        return 1
    print(f"Wrote {data_dir}: config/printer.cfg (from {args.example}), config/moonraker.conf, "
          f"gcodes/, logs/, comms/.")
    console, serve, moonraker = next_commands(data_dir)
    print("Next, calibrate the load cell and home in the console:")
    print(f"    {console}")
    print("Or serve it to Moonraker (and Mainsail or Fluidd), then start Moonraker on the same folder:")
    print(f"    {serve}")
    print(f"    {moonraker}")
    return 0
